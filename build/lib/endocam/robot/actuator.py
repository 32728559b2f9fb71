"""What carries the camera: the carrier kinds and the one interface the episode runner calls.

Every camera carrier — the free 6-DoF camera (:class:`~endocam.robot.free_camera.FreeCamera`),
the camera on a dVRK PSM or ECM (:class:`~endocam.robot.camera_arm.CameraArm`) — implements
:class:`Actuator`: ``reset`` to a start view, then one ``step`` per control period from a
commanded camera pose to the camera pose it reaches. The runner has no carrier branches; what a
carrier did with a command is its own :class:`ActuatorStatus`, kept apart from the controller's
``TrackingState``. This module is a leaf (numpy only), so the config, the CLI and the policy
registry take the carrier choices from :class:`ArmKind` without importing any carrier.
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

from endocam.geometry import FloatArray

if TYPE_CHECKING:
    from endocam.camera import StereoCamera
    from endocam.task.config import TaskConfig


class ArmKind(enum.Enum):
    """What carries the camera: the single source of the carrier choices."""

    FREE = "free"
    """No arm: the camera moves under Cartesian limits only."""
    PSM = "psm"
    """A pickup camera held by a dVRK PSM (6 DoF)."""
    ECM = "ecm"
    """The dVRK's 4-DoF endoscope arm (straight 0° scope)."""


class ActuatorStatus(enum.Enum):
    """How a carrier treated the command of one control step."""

    EXACT = "exact"
    """The carrier heads for the command itself."""
    VIEW = "view"
    """Nearest feasible view: the view turned about its look-at point towards the port."""
    NEAREST = "nearest"
    """Even the port view is out of reach: nearest feasible configuration (least squares)."""


class GuardAction(enum.Enum):
    """What the carrier's workspace guard did with one control step's motion."""

    FREE = "free"
    """The motion towards the command keeps the camera able to stop inside: taken as planned."""
    SLID = "slid"
    """The motion towards the command could take the camera out of the workspace; the carrier
    took the admissible motion nearest to it instead (the straight joint line, or the motion
    slid along the workspace's boundary), checked like any other."""
    BRAKED = "braked"
    """No admissible motion towards the command: the carrier brakes to the stopping point it
    checked before. Repeated, the camera stands still while the command is elsewhere."""


class ActuatorStep(NamedTuple):
    """Outcome of one control step of a carrier (immutable; a named tuple: cheap per step).

    Attributes
    ----------
    T_world_cam : (4, 4) ndarray
        Camera pose after the step, world, optical frame, m (read-only).
    q : (n,) ndarray
        Measured joint positions after the step, rad / m; ``(0,)`` for the free camera.
    T_world_target : (4, 4) ndarray
        The camera pose the carrier heads for: the command, or what ``status`` put in its
        place, m.
    status : ActuatorStatus
        How the command was treated.
    position_error : float
        Distance between the command and the target camera positions, m (0 when exact).
    orientation_error : float
        Angle between the command and the target camera orientations, rad (0 when exact): the
        view direction the carrier concedes.
    reachable : bool
        Whether the carrier delivers what the policy asked of it: PSM — the command exactly;
        ECM — the command's view through the port (its missing orientation is the 4-DoF
        scope's expected residual, measured by ``orientation_error``); free — always.
    guard : GuardAction
        What the workspace guard did with the step's motion (``FREE`` without a guard).
    """

    T_world_cam: FloatArray
    q: FloatArray
    T_world_target: FloatArray
    status: ActuatorStatus
    position_error: float
    orientation_error: float
    reachable: bool
    guard: GuardAction = GuardAction.FREE


class WorkspaceBound(Protocol):
    """Where a carrier may put the camera (``workspace.region.Workspace``: cone, floor, wire)."""

    @property
    def convex(self) -> bool:
        """Whether the region is convex (a box with its corners inside is inside)."""
        ...

    def keep_out_margin(self, p_world: Sequence[float]) -> float:
        """Signed clearance of a camera position (3,), world, m, to the non-convex part alone."""
        ...

    def margin(self, p_world: Sequence[float]) -> float:
        """Signed clearance of a camera position (3,), world, m: ≥ 0 inside."""
        ...

    def all_inside(self, p_world: FloatArray) -> bool:
        """Whether every camera position (N, 3), world, m, is inside (a path, at once).

        The answer of ``all(margin(p) >= 0.0 for p in p_world)``.
        """
        ...

    @property
    def kernel_state(self) -> tuple[Any, ...]:
        """The arguments its compiled queries take first (``workspace.region.workspace_margin``).

        The free camera's compiled stop check asks the workspace through them.
        """
        ...


class Actuator(Protocol):
    """The interface of every camera carrier (free camera, PSM, ECM)."""

    kind: ArmKind
    follows_twist: bool
    """Whether :meth:`step` uses the command's velocity (``twist``); a policy need not compute
    one for a carrier that ignores it (``PolicyContext.follows_twist``)."""

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Names of the joints reported in :attr:`ActuatorStep.q` (``()`` without joints)."""
        ...

    @property
    def q(self) -> FloatArray:
        """Measured joint positions (n,), rad / m (``(0,)`` without joints)."""
        ...

    def start_view(self, task_cfg: TaskConfig, camera: StereoCamera) -> tuple[FloatArray, float]:
        """The camera pose (4, 4) this carrier starts an episode from, and its look distance (m).

        A view of the whole task of ``task_cfg`` through ``camera``: the fixed camera's view,
        and every moving camera's start.
        """
        ...

    def reset(self, T_world_cam: object, look_distance: float | None = None) -> FloatArray:
        """Start at rest as near as possible to ``T_world_cam`` (4, 4); returns the pose taken.

        ``look_distance`` (m) is the distance to the point the view looks at, the pivot of a
        conceded view.
        """
        ...

    def stall(self, joint: int | None) -> None:
        """Fault injection: joint ``joint`` (index) stops following its target; ``None``: none.

        A carrier without joints accepts only ``None``.
        """
        ...

    def step(
        self, T_world_cmd: FloatArray, look_distance: float, twist: FloatArray | None = None
    ) -> ActuatorStep:
        """One control period towards the commanded camera pose (4, 4), world, m.

        ``twist`` (6,) is the command's velocity (linear, then angular; world; m/s, rad/s), or
        ``None``; a carrier that cannot use it ignores it.
        """
        ...

"""The camera arm drawn in the MuJoCo scene: a kinematic chain of simple mocap links.

When an episode's camera is carried by a dVRK arm (:class:`~endocam.robot.actuator.ArmKind` ``PSM``
or ``ECM``), :func:`add_camera_arm` adds one mocap body per drawn link, each posed at a
modified-DH frame of the arm (:meth:`~endocam.robot.kinematics.RcmArm.frames`, placed in the
world by ``T_world_rcm``). Geoms are in group ``GROUP_LINK`` and named ``camera_arm_*``.

PSM (pickup camera grasped by ProGrasp forceps):

- ``camera_arm_port`` (frame 1, origin at the RCM): a small sphere marking the port;
- ``camera_arm_shaft`` (frame 3, insertion): the tool's back end (a box) above the RCM and the
  instrument shaft along z3 down to just short of the wrist-pitch axis (0.467 m, the roll link's
  ``D``);
- ``camera_arm_wrist`` (frame 5, wrist pitch): the wrist link along x5 to the wrist-yaw axis
  (0.0107 m, the wrist-yaw link's ``A``);
- ``camera_arm_jaws`` (tool tip): two jaw plates along the tip's z (approach) axis, either side
  of the camera body (tip y);
- the camera body ``camera_arm_camera`` on the ``stereo_camera`` mocap body itself.

ECM (straight 0° endoscope): ``camera_arm_port`` and ``camera_arm_scope`` (frame 3): the
endoscope's camera head above the RCM and its shaft down to the tip (= the optical frame).

**The camera never sees its own arm.** Everything attached near the camera lies *behind the
eyes*: the camera body spans optical-frame z from −(``CAMERA_BODY_LENGTH`` + ``EYE_CLEARANCE``)
to −``EYE_CLEARANCE``, the 8 mm jaws end 7 mm behind the optical centre with the default 15 mm
mount (``episode.tip_cam_position``), the scope ends ``EYE_CLEARANCE`` before the ECM's tip.
MuJoCo cameras only draw what lies in front of their near plane, so the eye images are
identical with and without the arm (``tests/test_sim_arm_scene.py``). The arm is visible from
other viewpoints (:meth:`~endocam.sim.render.WireChaserScene.render_view`).

Dimensions are simplified engineering values (an 8 mm instrument, a 12 mm endoscope), not CAD.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco

from endocam.camera import SCOPE_RADIUS, StereoCamera
from endocam.robot.camera_arm import ArmKind
from endocam.robot.ecm import ECM_CHAIN
from endocam.robot.psm import PSM_CHAIN
from endocam.sim.scene import (
    CAMERA_BODY,
    GROUP_LINK,
    JAW_THICKNESS,
    JAW_WIDTH,
    WRIST_RADIUS_FRACTION,
    GeomSpec,
    add_geom,
    add_mocap_link,
)
from endocam.task.config import InstrumentConfig

__all__ = [
    "ARM_PREFIX",
    "CAMERA_BODY_GEOM",
    "ArmLink",
    "add_camera_arm",
    "camera_arm_links",
    "camera_body_geom",
]

ARM_PREFIX = "camera_arm"
CAMERA_BODY_GEOM = f"{ARM_PREFIX}_camera"
EYE_CLEARANCE = 0.5e-3  # m, gap between the eyes' plane and anything drawn behind it
CAMERA_BODY_LENGTH = 10e-3  # m, pickup camera body behind the eyes (along the optical axis)
CAMERA_BODY_HALF_HEIGHT = 2.5e-3  # m, half its extent along the optical y axis (jaw grip)
CAMERA_BODY_SIDE_MARGIN = 2.0e-3  # m, body beyond each eye along the optical x axis
PORT_RADIUS = 6.0e-3  # m, sphere drawn at the RCM
TOOL_BACK_END_HALF = (0.015, 0.025, 0.03)  # m, half-extents of the PSM tool's back end (box)
PSM_ROLL_LINK_D = PSM_CHAIN.links[3].D  # m, frame 3 to the wrist-pitch axis along the shaft
PSM_WRIST_A = PSM_CHAIN.links[5].A  # m, wrist-pitch to wrist-yaw axis
SHAFT_WRIST_GAP = 3.0e-3  # m, shaft end before the wrist-pitch axis
ECM_SCOPE_RADIUS = SCOPE_RADIUS  # m, a 12 mm stereo endoscope (the controller's clearance too)
ECM_ROLL_LINK_D = ECM_CHAIN.links[3].D  # m, frame 3 to the scope tip
ECM_HEAD_HALF = (0.025, 0.025, 0.05)  # m, half-extents of the endoscope's camera head (box)
PORT_RGBA = (0.3, 0.6, 0.9, 0.6)  # port marker colour
HEAD_RGBA = (0.2, 0.2, 0.22, 1.0)  # tool back end / camera head colour
CAMERA_RGBA = (0.1, 0.1, 0.1, 1.0)  # pickup camera body colour

# index into RcmArm.frames(q) (n + 1 poses: DH frames 1..n, then the tool tip)
_PSM_FRAME = {"port": 0, "shaft": 2, "wrist": 4, "jaws": 6}
_ECM_FRAME = {"port": 0, "scope": 2}


@dataclass(frozen=True)
class ArmLink:
    """One drawn link of the camera arm.

    Attributes
    ----------
    body : str
        Mocap body name (``camera_arm_<link>``).
    frame : int
        Index of its pose in ``RcmArm.frames(q)`` / ``CameraArm.link_frames(q)``
        (``n + 1`` poses: the DH link frames, then the tool tip).
    geoms : tuple of GeomSpec
        Geometry in that frame, m.
    """

    body: str
    frame: int
    geoms: tuple[GeomSpec, ...]


def _port() -> GeomSpec:
    return GeomSpec(f"{ARM_PREFIX}_port_sphere", "sphere", (PORT_RADIUS,), rgba=PORT_RGBA)


def _psm_links(ins: InstrumentConfig) -> tuple[ArmLink, ...]:
    r = ins.shaft_radius
    shaft_end = PSM_ROLL_LINK_D - SHAFT_WRIST_GAP
    bx, by, bz = TOOL_BACK_END_HALF
    shaft = (
        GeomSpec(
            f"{ARM_PREFIX}_tool_back_end", "box", (bx, by, bz), pos=(0, 0, -bz), rgba=HEAD_RGBA
        ),
        GeomSpec(
            f"{ARM_PREFIX}_shaft_tube",
            "cylinder",
            (r,),
            fromto=(0, 0, 0, 0, 0, shaft_end),
            rgba=ins.rgba,
        ),
    )
    wrist = (
        GeomSpec(
            f"{ARM_PREFIX}_wrist_link",
            "capsule",
            (WRIST_RADIUS_FRACTION * r,),
            fromto=(0, 0, 0, PSM_WRIST_A, 0, 0),
            rgba=ins.jaw_rgba,
        ),
    )
    # jaw plates along tip z, either side (tip y) of the camera body they grip
    half_len = 0.5 * ins.jaw_length
    y_jaw = CAMERA_BODY_HALF_HEIGHT + 0.5 * JAW_THICKNESS
    jaws = tuple(
        GeomSpec(
            f"{ARM_PREFIX}_jaw_{side}",
            "box",
            (0.5 * JAW_WIDTH, 0.5 * JAW_THICKNESS, half_len),
            pos=(0.0, sign * y_jaw, half_len),
            rgba=ins.jaw_rgba,
        )
        for side, sign in (("a", 1.0), ("b", -1.0))
    )
    return (
        ArmLink(f"{ARM_PREFIX}_port", _PSM_FRAME["port"], (_port(),)),
        ArmLink(f"{ARM_PREFIX}_shaft", _PSM_FRAME["shaft"], shaft),
        ArmLink(f"{ARM_PREFIX}_wrist", _PSM_FRAME["wrist"], wrist),
        ArmLink(f"{ARM_PREFIX}_jaws", _PSM_FRAME["jaws"], jaws),
    )


def _ecm_links(ins: InstrumentConfig) -> tuple[ArmLink, ...]:
    hx, hy, hz = ECM_HEAD_HALF
    scope = (
        GeomSpec(f"{ARM_PREFIX}_head", "box", (hx, hy, hz), pos=(0, 0, -hz), rgba=HEAD_RGBA),
        GeomSpec(
            f"{ARM_PREFIX}_scope_tube",
            "cylinder",
            (ECM_SCOPE_RADIUS,),
            fromto=(0, 0, 0, 0, 0, ECM_ROLL_LINK_D - EYE_CLEARANCE),
            rgba=ins.rgba,
        ),
    )
    return (
        ArmLink(f"{ARM_PREFIX}_port", _ECM_FRAME["port"], (_port(),)),
        ArmLink(f"{ARM_PREFIX}_scope", _ECM_FRAME["scope"], scope),
    )


def camera_arm_links(kind: ArmKind, instruments: InstrumentConfig) -> tuple[ArmLink, ...]:
    """The drawn links of a camera arm (see the module docstring).

    Raises
    ------
    ValueError
        For ``ArmKind.FREE``.
    """
    if kind is ArmKind.PSM:
        return _psm_links(instruments)
    if kind is ArmKind.ECM:
        return _ecm_links(instruments)
    raise ValueError(f"kind: {kind.value!r} has no arm to draw")


def camera_body_geom(camera: StereoCamera) -> GeomSpec:
    """The pickup camera's body in the optical frame, entirely behind the eyes (m)."""
    hx = 0.5 * camera.baseline + CAMERA_BODY_SIDE_MARGIN
    hz = 0.5 * CAMERA_BODY_LENGTH
    return GeomSpec(
        CAMERA_BODY_GEOM,
        "box",
        (hx, CAMERA_BODY_HALF_HEIGHT, hz),
        pos=(0.0, 0.0, -EYE_CLEARANCE - hz),
        rgba=CAMERA_RGBA,
    )


def add_camera_arm(
    spec: mujoco.MjSpec, kind: ArmKind, instruments: InstrumentConfig, camera: StereoCamera
) -> tuple[ArmLink, ...]:
    """Add the camera arm's links (mocap bodies, group ``GROUP_LINK``) to a wire-chaser spec.

    For the PSM the pickup camera's body is added to the ``stereo_camera`` body too.

    Parameters
    ----------
    spec : mujoco.MjSpec
        From :func:`~endocam.sim.scene.build_spec`, not yet compiled.
    kind : ArmKind
        ``PSM`` or ``ECM``.
    instruments : InstrumentConfig
        Shaft radius, jaw length and colours.
    camera : StereoCamera
        The stereo rig (baseline sets the camera body's width).

    Returns
    -------
    tuple of ArmLink
        The links added; pose them with ``frames[link.frame]``.
    """
    links = camera_arm_links(kind, instruments)
    for link in links:
        add_mocap_link(spec, link.body, link.geoms, group=GROUP_LINK)
    if kind is ArmKind.PSM:
        add_geom(spec.body(CAMERA_BODY), camera_body_geom(camera), GROUP_LINK)
    return links

"""The policy registry: every camera policy by name, with the carrier it needs.

``endocam policies`` lists it, the CLI takes its choices from it, and the episode runner builds
policies through :func:`make_policy`. It sits above the policy modules (``control.policies``),
so none of them imports it back.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from endocam.control.config import ControllerConfig
from endocam.control.policies import (
    CenteringPolicy,
    EndocamPolicy,
    FixedPolicy,
    OraclePolicy,
    OrientationEcmPolicy,
    OrientationPolicy,
    VisiblePolicy,
)
from endocam.control.types import CameraPolicy
from endocam.robot.actuator import ArmKind

__all__ = ["POLICIES", "PolicyEntry", "make_policy"]


@dataclass(frozen=True)
class PolicyEntry:
    """A registry entry: how to build a policy, one line to describe it, the arm it needs.

    Attributes
    ----------
    factory : callable
        Builds the policy from a :class:`ControllerConfig`.
    summary : str
        One line for ``endocam policies``.
    arm : ArmKind or None
        The carrier the policy needs; ``None`` uses the config's ``episode.arm``.
    """

    factory: Callable[[ControllerConfig], CameraPolicy]
    summary: str
    arm: ArmKind | None = None


POLICIES: dict[str, PolicyEntry] = {
    "fixed": PolicyEntry(FixedPolicy, "condition I: fixed camera showing the whole task"),
    "centering": PolicyEntry(
        CenteringPolicy, "condition II: follows the ring centre, keeps its initial orientation"
    ),
    "orientation": PolicyEntry(
        OrientationPolicy, "condition III: on the ring normal, level horizon, way-points, safety"
    ),
    "orientation-ecm": PolicyEntry(
        OrientationEcmPolicy,
        "condition III's goal carried out by the 4-DoF dVRK ECM (always uses the ECM)",
        arm=ArmKind.ECM,
    ),
    "endocam": PolicyEntry(
        EndocamPolicy,
        "orientation goal kept on one side, orbit transfers, latency prediction, left-eye centring",
    ),
    "endocam-visible": PolicyEntry(
        VisiblePolicy,
        "endocam turned to show the touch: side and tilt (≤ 20°) where the wire and rim leave "
        "the gap in sight",
    ),
    "oracle": PolicyEntry(
        OraclePolicy,
        "non-causal reference: endocam's goal on the true, undelayed future (for experiments)",
    ),
}


def make_policy(name: str, config: ControllerConfig | None = None) -> CameraPolicy:
    """Build a registered policy by name; unknown names raise ``ValueError`` listing the choices."""
    try:
        entry = POLICIES[name]
    except KeyError:
        choices = ", ".join(POLICIES)
        raise ValueError(f"unknown policy {name!r}; choose one of: {choices}") from None
    return entry.factory(config or ControllerConfig())

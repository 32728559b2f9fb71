"""The camera policies: the paper's three conditions, the ``endocam`` tracker and the oracle.

* :mod:`.base`: what the moving policies share (the safety rules, holds, way-point lifts).
* :mod:`.paper`: ``fixed``, ``centering``, ``orientation`` and ``orientation-ecm`` (the paper's
  conditions I–III).
* :mod:`.endocam`: the ``endocam`` tracker (side keeping, orbits, prediction, left-eye centring).
* :mod:`.visible`: ``endocam-visible``, the tracker turned to where the touch is in sight.
* :mod:`.oracle`: the non-causal reference that knows the ring's future.
"""

from endocam.control.policies.base import (
    DETOUR_REASON,
    FREEZE_RELEASE_MARGIN,
    STALL_STEPS,
    WIRE_REASON,
    MovingPolicy,
)
from endocam.control.policies.endocam import EndocamPolicy
from endocam.control.policies.oracle import OracleConfig, OraclePolicy
from endocam.control.policies.paper import (
    CenteringPolicy,
    FixedPolicy,
    OrientationEcmPolicy,
    OrientationPolicy,
)
from endocam.control.policies.visible import VisiblePolicy
from endocam.control.policies.visible_config import VisibleConfig

__all__ = [
    "DETOUR_REASON",
    "FREEZE_RELEASE_MARGIN",
    "STALL_STEPS",
    "WIRE_REASON",
    "CenteringPolicy",
    "EndocamPolicy",
    "FixedPolicy",
    "MovingPolicy",
    "OracleConfig",
    "OraclePolicy",
    "OrientationEcmPolicy",
    "OrientationPolicy",
    "VisibleConfig",
    "VisiblePolicy",
]

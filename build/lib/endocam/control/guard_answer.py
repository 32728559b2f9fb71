"""The wire guard's answer on a step's plain path, asked inside the policies' compiled steps.

On the plain path (no transfer, way-point or freeze) the goal is the command unless the wire's
clearance guard turns it; the compiled steps ask the guard's two questions themselves
(``clearance.cleared_move``): is the goal clear, and does the straight move from the camera to
it need a detour. Python then uses the answer only for the very pose that was asked about.
"""

from __future__ import annotations

from typing import NamedTuple

from numba.extending import register_jitable

from endocam.control.detour import cleared_move
from endocam.kernels import Vec
from endocam.workspace.keepout import KeepOutState

__all__ = ["NOT_ASKED", "GuardAnswer", "ask_guard"]


class GuardAnswer(NamedTuple):
    """The guard's answer: the goal ``cleared``; its move's ``detour`` and way-point ``via``.

    ``via`` world, m. ``cleared`` false: not asked, or not clear.
    """

    cleared: bool
    detour: bool
    via: Vec


NOT_ASKED = GuardAnswer(False, False, (0.0, 0.0, 0.0))


@register_jitable  # also callable from compiled kernels (the same source)
def ask_guard(zone: KeepOutState, p_goal: Vec, p_pivot: Vec, p_now: Vec) -> GuardAnswer:
    """Ask the guard whether the goal at ``p_goal`` is clear, and if so its move's detour.

    ``ClearanceGuard.apply``'s check of the goal (its pivot ``p_pivot``, the ring centre) and,
    if clear, ``ClearanceGuard.detour``'s trace from the camera at ``p_now``; world, m. A goal
    not clear leaves the guard's cache as it was (Python asks again).
    """
    cleared, detour, via = cleared_move(zone, p_goal, p_pivot, p_now)
    return GuardAnswer(cleared, detour, via)

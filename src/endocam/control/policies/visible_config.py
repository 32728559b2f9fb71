"""The ``endocam-visible`` camera's parameters (:class:`VisibleConfig`).

What each one does, and how the defaults were chosen, is told with it; the policy itself is in
:mod:`endocam.control.policies.visible`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from endocam.geometry import FloatArray

__all__ = ["VisibleConfig"]


@dataclass(frozen=True)
class VisibleConfig:
    """Parameters of the ``endocam-visible`` camera, SI (the policy: ``policies.visible``).

    Attributes
    ----------
    max_tilt : float
        The largest tilt of the viewing axis off the ring normal, rad (≤ 25°: the mean
        orientation error must stay ≤ 10° with the tracker's own ~4–5°).
    tilt_steps : int
        Tilts tried: ``max_tilt · k / tilt_steps``, ``k = 1..tilt_steps``.
    azimuths : int
        Directions around the normal tried at each tilt.
    score_period : float
        Time between two scorings, s.
    rim_points : int
        Points around the rim where a touch may close (``occlusion.gap_points``).
    weight_scale : float
        How fast a rim point's weight falls with its clearance to the wire, m.
    urgency_scale : float
        How fast the score's worth falls with the rim's clearance to the wire, m: far from a
        touch no tilt is worth its orientation error (``math.inf``: always worth it).
    window : float
        Arc length of wire either side of the ring tested as an occluder, m.
    tilt_cost : float
        Utility lost per rad of tilt (score units per rad).
    tilt_margin : float
        Utility a new tilt must gain over the current target to replace it.
    tilt_rate : float
        Fastest change of the axis' offset, rad/s (small-angle: the offset is ``tan θ``).
    tilt_acceleration : float
        Largest acceleration of the axis' offset, rad/s² (ruckig moves it, per axis
        ``tilt_rate / √3`` and ``tilt_acceleration / √3``): the turned normal the tracker sees
        must stay on the track its observation gate predicts (``ring_max_angular_acceleration``
        500 rad/s²; a step of the offset's velocity by ``tilt_rate`` alone is ~1° of innovation
        in one 10 ms step). Round 18: without it, a new target that reversed the offset's motion
        made the gate refuse the ring for ~0.6 s (2 % of a PSM episode lost).
    side_margin : float
        Utility the other side must gain over this side's to be taken ...
    side_hold : float
        ... at every scoring for this long, s.
    resolved_px : float
        Pixels 0.5 mm of gap must span to count as seen.
    cone_slack : float
        Cone margin a tilted candidate's camera needs, m (the ring moves between scorings).
    wire_slack : float
        Distance beyond ``wire_clearance`` a tilted candidate's camera keeps from the wire, m
        (a camera at the clearance zone's edge detours round it on every move).
    port_angle : float
        The largest angle between a tilted candidate's optical axis and the line from the port
        (the camera arm's RCM) through the ring, rad, unless the tracker's own view is already
        farther (then no farther than it): a PSM-held camera's wrist reaches ~68° (the
        tracker's commands on the study paths; farther ones are conceded), so a tilt must not
        take the view out of its reach. The ECM's axis always passes through the port, the
        free camera has no such limit.
    lookahead : float
        How far ahead of the step the scored ring pose is predicted, s (beyond the sensing
        delay, which is always bridged): the camera should be on the good view when the gap
        closes, not a scoring period, a tilt and an arm's lag after (0: the observed pose).
    velocity_window : float
        Span of the accepted ring poses the prediction's (constant) velocity is differenced
        over, s.
    max_predicted_turn : float
        The largest turn of the ring the prediction extrapolates, rad (a faster ring is not
        followed farther).
    engage_clearance : float
        Scoring only while the predicted ring's rim comes this close to the wire, m (the
        smallest of the gap points' clearances; a threaded ring's is at most ``R − r − r_w``):
        farther, no touch is near, the axis goes back to the normal and the side is held
        (``math.inf``: always score).
    horizon_poses : int
        Ring poses predicted over the look-ahead, evenly from the step (the delay bridged) to
        ``lookahead``; the one scored is where the rim's clearance comes down to the closing
        gap ``GAP_M`` (the prediction stops at contact: between the last pose clear of it and
        the first that is not, ``closing_fraction`` and ``pose_between`` of
        :mod:`~endocam.control.policies.visible`; constant velocity carries the ring into the
        wire, the wire stops it), else the closest (1: the
        ``lookahead`` pose alone). Round 12: 0.75 s and 4 poses against 0.5 s and 1 pose, on
        seeds 7–26 paired per touch: 76 % against 73 % resolved, at 9.1° against 8.1°.
    either_eye : bool
        A candidate is worth its better eye's share (the study counts a gap seen from either
        eye); ``False``: the two eyes' mean.
    contact_arc : float
        The tilt is judged on the predicted contact's neighbourhood: ``contact_points`` gap
        points within this arc of rim (m) either side of the rim point nearest the wire
        (:func:`~endocam.control.occlusion.contact_points`), equally weighted; the side stays
        judged on the whole rim's weighted share (where the wire leans away is a property of
        the whole hole; judged on the contact alone the side flips, and every flip is an orbit)
        (0: the tilt on the whole rim's share too). Round 17, seeds 7–26 paired per touch
        against 0: 0.5, 0.7, 1.0 and 1.3 mm gave +3.1, +3.8, +6.0 and +4.3 points resolved
        at 9.0, 9.1, 9.5 and 9.7° (0: 76.2 % at 9.1°); 1 mm taken.
    contact_points : int
        Gap points in the contact's neighbourhood (``contact_arc`` > 0).
    """

    max_tilt: float = math.radians(20.0)
    tilt_steps: int = 2
    azimuths: int = 6
    score_period: float = 0.25
    rim_points: int = 12
    weight_scale: float = 1.5e-3
    urgency_scale: float = 3e-3
    window: float = 0.03
    tilt_cost: float = 0.5
    tilt_margin: float = 0.1
    tilt_rate: float = 2.0
    tilt_acceleration: float = 20.0
    side_margin: float = 0.3
    side_hold: float = 1.0
    resolved_px: float = 2.0
    cone_slack: float = 2e-3
    port_angle: float = math.radians(55.0)
    wire_slack: float = 3e-3
    lookahead: float = 0.75
    velocity_window: float = 0.1
    max_predicted_turn: float = math.radians(30.0)
    engage_clearance: float = 1.0e-3
    horizon_poses: int = 4
    either_eye: bool = True
    contact_arc: float = 1.0e-3
    contact_points: int = 7

    def __post_init__(self) -> None:
        if not 0.0 < self.max_tilt <= math.radians(25.0):
            raise ValueError(f"max_tilt must be in (0, 25°] rad, got {self.max_tilt}")
        for name in ("tilt_steps", "azimuths", "rim_points", "horizon_poses", "contact_points"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be ≥ 1, got {getattr(self, name)}")
        for name in (
            "score_period",
            "weight_scale",
            "urgency_scale",
            "window",
            "tilt_rate",
            "tilt_acceleration",
            "resolved_px",
            "velocity_window",
            "engage_clearance",
        ):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not 0.0 < self.port_angle <= math.pi:
            raise ValueError(f"port_angle must be in (0, π] rad, got {self.port_angle}")
        for name in (
            "tilt_cost",
            "tilt_margin",
            "side_margin",
            "side_hold",
            "cone_slack",
            "wire_slack",
            "lookahead",
            "max_predicted_turn",
            "contact_arc",
        ):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"{name} must be ≥ 0, got {getattr(self, name)}")

    @property
    def tilts(self) -> FloatArray:
        """(tilt_steps,) the tilts tried, rad."""
        return self.max_tilt * np.arange(1, self.tilt_steps + 1) / self.tilt_steps

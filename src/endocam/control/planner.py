"""Intermediate way-points around large goal jumps (paper Sec. III-B, Fig. 4).

When consecutive goals are farther apart than a threshold, the camera does not cut straight to
the new goal (it could sweep through the ring, the wire or the tissue). It rises by ``d_wp`` along
world up above its current position (IWP1), travels to ``d_wp`` above the goal (IWP2), then
descends to the goal: current → IWP1 → IWP2 → goal, a polyline followed with monotone progress.
At every point on the way the camera looks at the feature with a level horizon.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from endocam.geometry import FloatArray


def intermediate_waypoints(
    p_world_cam: FloatArray, p_world_goal: FloatArray, up: FloatArray, d_wp: float
) -> FloatArray:
    """The paper's four-point path: current, IWP1, IWP2, goal.

    Parameters
    ----------
    p_world_cam : (3,)
        Current camera position in world, m.
    p_world_goal : (3,)
        Goal camera position in world, m.
    up : (3,)
        Unit world up.
    d_wp : float
        Height of the intermediate way-points above their ends, m (> 0).

    Returns
    -------
    (4, 3)
        ``[p_cam, p_cam + d_wp·up, p_goal + d_wp·up, p_goal]`` in world, m.
    """
    if not d_wp > 0.0:
        raise ValueError(f"d_wp must be > 0 m, got {d_wp}")
    lift = d_wp * up
    return np.stack([p_world_cam, p_world_cam + lift, p_world_goal + lift, p_world_goal])


@dataclass(frozen=True)
class WaypointPath:
    """A polyline through way-points, parametrised by arc length.

    Attributes
    ----------
    points : (M, 3)
        Way-points in world, m (M ≥ 2).
    """

    points: FloatArray
    # Plain-float copies, computed once: the path is queried every control step.
    _pts: list[list[float]] = field(init=False, repr=False, compare=False)
    _cum: list[float] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
            raise ValueError(f"points must have shape (M ≥ 2, 3), got {pts.shape}")
        rows = pts.tolist()
        if not math.isfinite(math.fsum(v for row in rows for v in row)):
            raise ValueError("points must be finite")
        cum = [0.0]
        for a, b in itertools.pairwise(rows):
            cum.append(cum[-1] + math.dist(a, b))
        object.__setattr__(self, "_pts", rows)
        object.__setattr__(self, "_cum", cum)

    @property
    def cumulative(self) -> FloatArray:
        """(M,) arc length at each way-point, m; starts at 0."""
        return np.array(self._cum)

    @property
    def length(self) -> float:
        """Total path length, m."""
        return self._cum[-1]

    def point_at(self, s: float) -> FloatArray:
        """Position (3,) at arc length ``s`` (m), clamped to ``[0, length]``."""
        cum, pts = self._cum, self._pts
        if s <= 0.0:
            return np.array(pts[0])
        for k in range(1, len(cum)):
            if s <= cum[k]:
                seg = cum[k] - cum[k - 1]
                u = (s - cum[k - 1]) / seg if seg > 0.0 else 1.0
                a, b = pts[k - 1], pts[k]
                return np.array([a[i] + u * (b[i] - a[i]) for i in range(3)])
        return np.array(pts[-1])

    def with_goal(self, p_world_goal: FloatArray, up: FloatArray, d_wp: float) -> WaypointPath:
        """Same path with the goal (and IWP2 above it) moved to follow a moving feature."""
        pts = self.points.copy()
        pts[-1] = p_world_goal
        pts[-2] = p_world_goal + d_wp * up
        return WaypointPath(pts)


def advance(
    path: WaypointPath, s: float, p_world_cam: FloatArray, step: float, lookahead: float
) -> float:
    """Next progress along the path: monotone, by ``step``, and only while the camera keeps up.

    Parameters
    ----------
    path : WaypointPath
    s : float
        Current progress, m.
    p_world_cam : (3,)
        Where the camera actually is, m. Progress waits while the camera is farther than
        ``lookahead`` from the point at ``s``, so a slow camera still passes every way-point.
    step : float
        Progress per call, m (speed × control period).
    lookahead : float
        Largest lead of the commanded point over the camera, m.

    Returns
    -------
    float
        New progress in ``[s, length]``, m (never less than ``s``).
    """
    if math.dist(path.point_at(s).tolist(), p_world_cam.tolist()) > lookahead:
        return s
    return min(s + step, path.length)

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

import numpy as np

from endocam.geometry import FloatArray


def intermediate_waypoints(
    p_world_cam: FloatArray,
    p_world_goal: FloatArray,
    up: FloatArray,
    d_wp: float,
    d_wp_goal: float | None = None,
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
        Height of IWP1 above the camera, m (≥ 0; the paper's fixed ``d_wp``).
    d_wp_goal : float, optional
        Height of IWP2 above the goal, m (≥ 0); ``d_wp`` when omitted. The policies lower the
        heights where a way-point would leave the cone workspace.

    Returns
    -------
    (4, 3)
        ``[p_cam, p_cam + d_wp·up, p_goal + d_wp_goal·up, p_goal]`` in world, m.
    """
    lift_goal = d_wp if d_wp_goal is None else d_wp_goal
    if not (d_wp >= 0.0 and lift_goal >= 0.0):
        raise ValueError(f"d_wp must be ≥ 0 m, got {d_wp} and {lift_goal}")
    return np.stack(
        [p_world_cam, p_world_cam + d_wp * up, p_world_goal + lift_goal * up, p_world_goal]
    )


class WaypointPath:
    """A polyline through way-points, parametrised by arc length (immutable).

    Parameters
    ----------
    points : (M, 3)
        Way-points in world, m (M ≥ 2, finite).
    """

    __slots__ = ("_cum", "_pts")

    def __init__(self, points: FloatArray) -> None:
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
            raise ValueError(f"points must have shape (M ≥ 2, 3), got {pts.shape}")
        rows = pts.tolist()
        if not math.isfinite(math.fsum(v for row in rows for v in row)):
            raise ValueError("points must be finite")
        self._set(rows)

    def _set(self, rows: list[list[float]]) -> None:
        # Plain floats: the path is queried every control step.
        cum = [0.0]
        for a, b in itertools.pairwise(rows):
            cum.append(cum[-1] + math.dist(a, b))
        self._pts = rows
        self._cum = cum

    @property
    def points(self) -> FloatArray:
        """(M, 3) way-points in world, m."""
        return np.array(self._pts)

    @property
    def cumulative(self) -> FloatArray:
        """(M,) arc length at each way-point, m; starts at 0."""
        return np.array(self._cum)

    @property
    def length(self) -> float:
        """Total path length, m."""
        return self._cum[-1]

    def point_at_list(self, s: float) -> list[float]:
        """Position at arc length ``s`` (m), clamped to ``[0, length]``, as plain floats."""
        cum, pts = self._cum, self._pts
        if s <= 0.0:
            return list(pts[0])
        for k in range(1, len(cum)):
            if s <= cum[k]:
                seg = cum[k] - cum[k - 1]
                u = (s - cum[k - 1]) / seg if seg > 0.0 else 1.0
                a, b = pts[k - 1], pts[k]
                return [
                    a[0] + u * (b[0] - a[0]),
                    a[1] + u * (b[1] - a[1]),
                    a[2] + u * (b[2] - a[2]),
                ]
        return list(pts[-1])

    def point_at(self, s: float) -> FloatArray:
        """Position (3,) at arc length ``s`` (m), clamped to ``[0, length]``."""
        return np.array(self.point_at_list(s))

    def with_goal(self, p_world_goal: FloatArray, up: FloatArray, d_wp: float) -> WaypointPath:
        """Same path with the goal (and IWP2 above it) moved to follow a moving feature.

        ``p_world_goal`` (3,) and ``up`` (3,) must be finite (the control loop checked them).
        """
        g = p_world_goal.tolist()
        u = up.tolist()
        iwp2 = [g[0] + d_wp * u[0], g[1] + d_wp * u[1], g[2] + d_wp * u[2]]
        path = WaypointPath.__new__(WaypointPath)
        path._set([*self._pts[:-2], iwp2, g])
        return path


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
    if math.dist(path.point_at_list(s), p_world_cam.tolist()) > lookahead:
        return s
    return min(s + step, path.length)

"""Intermediate way-points around large goal jumps (paper Sec. III-B, Fig. 4).

When consecutive goals are farther apart than a threshold, the camera does not cut straight to
the new goal (it could sweep through the ring, the wire or the tissue). It rises by ``d_wp`` along
world up above its current position (IWP1), travels to ``d_wp`` above the goal (IWP2), then
descends to the goal: current → IWP1 → IWP2 → goal, a polyline followed with monotone progress.
At every point on the way the camera looks at the feature with a level horizon.
"""

from __future__ import annotations

from dataclasses import dataclass

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

    @property
    def cumulative(self) -> FloatArray:
        """(M,) arc length at each way-point, m; starts at 0."""
        seg = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        return np.concatenate(([0.0], np.cumsum(seg)))

    @property
    def length(self) -> float:
        """Total path length, m."""
        return float(self.cumulative[-1])

    def point_at(self, s: float) -> FloatArray:
        """Position (3,) at arc length ``s`` (m), clamped to ``[0, length]``."""
        cum = self.cumulative
        s = min(max(s, 0.0), float(cum[-1]))
        return np.array([np.interp(s, cum, self.points[:, k]) for k in range(3)])

    def project(self, p_world: FloatArray) -> float:
        """Arc length (m) of the point on the path closest to ``p_world`` (3,)."""
        cum = self.cumulative
        a = self.points[:-1]
        d = np.diff(self.points, axis=0)
        len2 = np.einsum("ij,ij->i", d, d)
        with np.errstate(invalid="ignore", divide="ignore"):
            u = np.clip(np.einsum("ij,ij->i", p_world - a, d) / len2, 0.0, 1.0)
        u = np.nan_to_num(u)  # zero-length segments
        closest = a + u[:, None] * d
        k = int(np.argmin(np.linalg.norm(closest - p_world, axis=1)))
        return float(cum[k] + u[k] * np.sqrt(len2[k]))

    def with_goal(self, p_world_goal: FloatArray, up: FloatArray, d_wp: float) -> WaypointPath:
        """Same path with the goal (and IWP2 above it) moved to follow a moving feature."""
        pts = self.points.copy()
        pts[-1] = p_world_goal
        pts[-2] = p_world_goal + d_wp * up
        return WaypointPath(pts)


def advance(
    path: WaypointPath, s: float, p_world_cam: FloatArray, step: float, lookahead: float
) -> float:
    """Next progress along the path: monotone, at most ``step`` on, at most ``lookahead`` ahead.

    Parameters
    ----------
    path : WaypointPath
    s : float
        Current progress, m.
    p_world_cam : (3,)
        Where the camera actually is, m; progress never runs more than ``lookahead`` ahead of
        its projection on the path, so a slow camera still passes through the way-points.
    step : float
        Largest progress per call, m (speed × control period).
    lookahead : float
        Largest lead over the camera's projection, m.

    Returns
    -------
    float
        New progress in ``[s, length]``, m (never less than ``s``).
    """
    s_cam = path.project(p_world_cam)
    s_new = min(s + step, max(s_cam + lookahead, s), path.length)
    return max(s_new, s)

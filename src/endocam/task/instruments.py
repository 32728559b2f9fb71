r"""Where the instrument tips are during an episode: PSM1 holds the ring, PSM2 idles near it.

PSM1's tip grips the ring's handle (:func:`endocam.task.layout.psm1_tip_in_ring`). PSM2 is the
surgeon's second instrument, idle during the wire chaser. A second instrument is not left
behind at a distant spot while the work moves along the wire: it is kept near the work site,
retracted, so that it stays in view and ready (``InstrumentConfig.psm2_idle``):

* ``follow`` (default): its tip follows the ring centre through a first-order lag of time
  constant :math:`\tau` (``psm2_follow_time``), at a fixed world offset :math:`o`
  (``psm2_offset``: in front of the wire and above the ring, clear of it),

  .. math::

      q_0 = p_0, \quad q_k = q_{k-1} + (1 - e^{-(t_k - t_{k-1})/\tau})(p_k - q_{k-1}),
      \quad p_{\mathrm{tip},k} = q_k + o;

  the lag is the assistant's slower hand: PSM2 trails the ring's wobbles rather than
  copying them.
* ``fixed``: its tip waits at ``psm2_tip`` for the whole episode.

The tool-in-view windows (paper Sec. III-C) then see a tool beside the ring, so the look
distance settles where the window rule is met instead of at ``d_max``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from endocam.geometry import FloatArray
from endocam.task.config import Psm2Idle, TaskConfig
from endocam.task.layout import psm1_tip_in_ring

__all__ = ["instrument_tips", "lagged_path"]

UNIFORM_RTOL = 1e-9  # relative spread of the time steps still counted as evenly spaced


def lagged_path(t: ArrayLike, p_world: ArrayLike, time_constant: float) -> FloatArray:
    """First-order lag of a path: ``q_0 = p_0``, ``q_k → p_k`` with ``time_constant`` (s).

    Parameters
    ----------
    t : (N,)
        Sample times, s, evenly spaced (the control grid).
    p_world : (N, 3)
        Path in world, m.
    time_constant : float
        Lag time constant, s (> 0).

    Returns
    -------
    (N, 3)
        The lagged path in world, m.
    """
    ts = np.asarray(t, dtype=float)
    p = np.asarray(p_world, dtype=float)
    if ts.ndim != 1 or p.shape != (len(ts), 3):
        raise ValueError(f"t must be (N,) and p_world (N, 3), got {ts.shape} and {p.shape}")
    if not (math.isfinite(time_constant) and time_constant > 0.0):
        raise ValueError(f"time_constant must be > 0 s, got {time_constant}")
    if np.any(np.diff(ts) < 0.0) or not np.all(np.isfinite(ts)):
        raise ValueError("t must be finite and non-decreasing")
    dts = np.diff(ts)
    if len(dts) and not np.allclose(dts, dts[0], rtol=UNIFORM_RTOL, atol=0.0):
        raise ValueError("t must be evenly spaced (a control grid)")
    if len(ts) < 2:
        return p.copy()
    a = 1.0 - math.exp(-float(dts[0]) / time_constant)
    # q_k = (1 − a) q_{k−1} + a p_k with q_0 = p_0: a one-pole IIR filter (scipy, in C);
    # imported here: scipy.signal costs ~0.4 s to import, which `endocam check`, the study app
    # and every process that runs no episode would pay
    from scipy.signal import lfilter

    zi = (1.0 - a) * p[0]  # the filter's state so that the first output equals p_0
    out, _ = lfilter([a], [1.0, a - 1.0], p, axis=0, zi=zi[None, :])
    return np.asarray(out, dtype=float)


def instrument_tips(task: TaskConfig, t: ArrayLike, T_world_ring: ArrayLike) -> FloatArray:
    """PSM1 and PSM2 tip positions over an episode.

    Parameters
    ----------
    task : TaskConfig
    t : (N,)
        Times, s, non-decreasing.
    T_world_ring : (N, 4, 4)
        True ring poses at ``t`` (ring z = face normal), m.

    Returns
    -------
    (N, 2, 3)
        ``p_world_tips``: PSM1's tip (gripping the handle) and PSM2's, world, m.
    """
    ts = np.asarray(t, dtype=float)
    T = np.asarray(T_world_ring, dtype=float)
    if T.shape != (len(ts), 4, 4):
        raise ValueError(f"T_world_ring must be ({len(ts)}, 4, 4), got {T.shape}")
    inst = task.instruments
    tip1 = T[:, :3, :3] @ psm1_tip_in_ring(task.ring, inst) + T[:, :3, 3]
    if inst.psm2_idle is Psm2Idle.FIXED:
        tip2 = np.broadcast_to(np.asarray(inst.psm2_tip, dtype=float), tip1.shape)
    else:
        tip2 = lagged_path(ts, T[:, :3, 3], inst.psm2_follow_time) + np.asarray(inst.psm2_offset)
    return np.stack([tip1, tip2], axis=1)

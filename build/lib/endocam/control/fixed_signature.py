"""A compiled step called at one signature, without numba's per-call type dispatch.

numba types every argument of every call; a step's named settings and inputs (NamedTuples,
nested, with arrays) cost ~10 µs to type per call, as much as the step itself, which at 6,000
steps an episode is a tenth of the controller's time. An episode's arguments have the same
types at every step, so :class:`FixedSignature` types them once, at the first call, and then
calls the compiled specialisation for those types directly (``Dispatcher.compile`` returns
it, compiled or loaded from the cache).

The callers keep every array argument a C-contiguous float64 array of fixed dimensions
(``checks.pose_array``, ``checks.tips_array``): the specialisation reads its arrays by that
layout.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from numba import typeof

__all__ = ["FixedSignature"]


class FixedSignature:
    """``kernel`` (an ``njit`` dispatcher) specialised for the argument types of its first call.

    Make one per episode: the settings' types (a wire model or none, the predictor's buffer)
    are fixed within one.
    """

    def __init__(self, kernel: Any) -> None:
        self.kernel = kernel
        self._entry: Callable[..., Any] | None = None

    def __call__(self, *args: Any) -> Any:
        """``kernel(*args)``; the first call fixes the signature."""
        entry = self._entry
        if entry is None:
            entry = self._entry = self.kernel.compile(tuple(typeof(a) for a in args))
        return entry(*args)

r"""Progress bars: tqdm's, drawn every 0.1 s on a terminal and every 30 s in a log.

A bar on a terminal redraws itself in place. Written to a file or a pipe (``make demo > log``),
each redraw is a ``\r`` and a new copy of the bar: tqdm's 0.1 s default filled a log with about
100 KB of copies for one demo. So every bar of endocam is made here, and one whose stream is not
a terminal redraws at most every :data:`LOG_INTERVAL_S` seconds (its first state is always
drawn; a bar with ``leave=True`` also draws its last): a log keeps the progress of a long run
and stays readable (``tr '\r' '\n' < log``).
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any, TypeVar

from tqdm import tqdm

__all__ = ["LOG_INTERVAL_S", "progress_bar"]

LOG_INTERVAL_S = 30.0
"""s, the shortest time between two redraws of a bar that does not write to a terminal."""

T = TypeVar("T")


def writes_to_terminal(stream: Any) -> bool:
    """Whether ``stream`` (a file object) is an interactive terminal (``isatty``)."""
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty()) if callable(isatty) else False
    except (ValueError, OSError):  # a closed or detached stream
        return False


def progress_bar(iterable: Iterable[T] | None = None, **kwargs: Any) -> tqdm:
    """A tqdm bar (``leave=False`` unless given) that redraws rarely outside a terminal.

    ``iterable`` and ``kwargs`` are tqdm's (``total``, ``desc``, ``unit``, ``file``, ...).
    Unless ``mininterval`` is given, a bar whose ``file`` (default ``sys.stderr``) is not a
    terminal redraws at most every :data:`LOG_INTERVAL_S` seconds (and tqdm's monitor thread,
    which redraws a bar silent for ``maxinterval`` s, waits as long).
    """
    kwargs.setdefault("leave", False)
    if not writes_to_terminal(kwargs.get("file") or sys.stderr):
        kwargs.setdefault("mininterval", LOG_INTERVAL_S)
        # tqdm's monitor thread redraws a bar silent for ``maxinterval`` (10 s by default)
        kwargs.setdefault("maxinterval", max(LOG_INTERVAL_S, kwargs["mininterval"]))
    return tqdm(iterable, **kwargs)

"""The progress bars redraw in place on a terminal and rarely in a log (``endocam.progress``)."""

from __future__ import annotations

import io
import time

import pytest

from endocam.progress import LOG_INTERVAL_S, progress_bar, writes_to_terminal

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

STEPS = 40
STEP_S = 0.01  # s between updates: 0.4 s in all, four of tqdm's 0.1 s redraw intervals


class Terminal(io.StringIO):
    """A stream that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def redraws(stream: io.StringIO) -> int:
    """How many times a bar was drawn into ``stream`` (each draw starts with ``\\r``)."""
    with progress_bar(total=STEPS, desc="test", file=stream) as bar:
        for _ in range(STEPS):
            time.sleep(STEP_S)
            bar.update(1)
    return stream.getvalue().count("\r")


def test_a_bar_in_a_log_is_not_redrawn_between_its_first_draw_and_its_close() -> None:
    log = io.StringIO()
    assert not writes_to_terminal(log)
    assert redraws(log) == 1 + 2  # the opening draw; the clearing at close (leave=False): 2
    assert f"0/{STEPS}" in log.getvalue()


def test_a_bar_on_a_terminal_redraws_as_it_goes() -> None:
    terminal = Terminal()
    assert writes_to_terminal(terminal)
    assert redraws(terminal) >= 1 + 2 + 2  # and at least two redraws between them


def test_the_log_interval_is_the_bars_and_can_be_overridden() -> None:
    with progress_bar(total=1, file=io.StringIO()) as bar:
        assert bar.mininterval == LOG_INTERVAL_S
        assert bar.maxinterval >= LOG_INTERVAL_S  # tqdm's monitor thread would redraw sooner
    with progress_bar(total=1, file=Terminal()) as bar:
        assert bar.mininterval < LOG_INTERVAL_S and bar.maxinterval < LOG_INTERVAL_S
    with progress_bar(total=1, file=io.StringIO(), mininterval=1.0) as bar:
        assert bar.mininterval == 1.0


def test_a_closed_stream_is_not_a_terminal() -> None:
    stream = io.StringIO()
    stream.close()
    assert not writes_to_terminal(stream)
    assert not writes_to_terminal(object())

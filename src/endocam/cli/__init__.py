"""The ``endocam`` command line: parses, validates and calls the library.

Every user mistake (unknown policy, bad number, unwritable folder, malformed config) ends as one
line on stderr and exit code 2, never a traceback; an ``OSError`` (a file system refusing) and a
port that cannot frame its task (``FramingError``) too.
When ``run``, ``demo``, ``sweep`` or an ``experiment`` has written its results and the safety
check of what it wrote (``endocam check``'s invariants, every run) finds a violation, the exit
code is 3 and the last line says so (``safety check: N violations (lost_hold N) in OUT — see
check.json``): the results are there to inspect, but the controller broke an invariant.
Any other exception is an internal error: one line and exit code 1, its traceback only with
``--debug``. An interrupt (Ctrl-C, or ``SIGTERM`` as a job scheduler sends it) unwinds like an
error: temporary folders are removed, worker processes stopped, exit code 130.

``endocam check`` answers with its own codes: 0 every invariant held in every run, 1 a run broke
one (violations found), 2 a run's log is malformed (not what endocam writes: columns, row count,
time stamps, quaternions, states; ``runner.log_schema``) or unreadable, refused in one line.
A malformed log is never passed, and never an internal error. One module per
command group (``policies``, ``run`` for run/demo/experiment/config, ``study``), each with
``register(subparsers)``; they import heavy parts (MuJoCo, FastAPI) only inside their handlers.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable, Iterator, Sequence
from types import FrameType
from typing import Any, TextIO

from endocam import __version__
from endocam.cli import check, export, kernels, link, policies, run, study, sweep
from endocam.cli.common import EXIT_INTERNAL, EXIT_UNSAFE, EXIT_USAGE, Parser, UsageError
from endocam.task.layout import FramingError

__all__ = [
    "EXIT_INTERNAL",
    "EXIT_UNSAFE",
    "EXIT_USAGE",
    "UsageError",
    "build_parser",
    "first_use_note",
    "main",
]

Handler = Callable[[argparse.Namespace], int | None]


def build_parser() -> argparse.ArgumentParser:
    """Build the full argument parser with every command group."""
    parser = Parser(
        prog="endocam",
        description="Autonomous 6-DoF endoscopic camera control for MIS.",
    )
    parser.add_argument("--version", action="version", version=f"endocam {__version__}")
    parser.add_argument(
        "--debug", action="store_true", help="print the traceback of an internal error"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for group in (policies, run, study, sweep, check, kernels, export, link):
        group.register(sub)
    return parser


def first_use_note(args: argparse.Namespace, environ: dict[str, str] | None = None) -> str | None:
    """The line saying a command's first episode compiles the kernels, or ``None``.

    Said when the command runs episodes (its parser's ``runs_episodes``) and numba's cache folder
    holds no compiled kernel yet (:func:`endocam.runner.precompile.kernels_cached`): the first
    episode then spends tens of seconds of CPU compiling before its first step, which its
    progress bar alone would show as a stall.
    """
    from endocam.runner.precompile import kernels_cached

    if not getattr(args, "runs_episodes", False) or kernels_cached(environ):
        return None
    folder = (os.environ if environ is None else environ)["NUMBA_CACHE_DIR"]
    return (
        "endocam: compiling the control loop's kernels for their first use (~20 s of CPU, once; "
        f"later runs load them from {folder}; `endocam compile` does it ahead)"
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Handler = args.handler
    note = first_use_note(args)
    if note is not None:
        print(note, file=sys.stderr)
    try:
        with _sigterm_interrupts(), _named_stdout():
            code = handler(args)
    except UsageError as exc:
        print(f"endocam: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except FramingError as exc:  # the config's port cannot frame its task
        print(f"endocam: error: config: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("endocam: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:  # the file system refused: where and why, in one line
        if args.debug:
            traceback.print_exc()
        where = f" {exc.filename}:" if exc.filename else ""
        print(f"endocam: error:{where} {exc.strerror or exc}", file=sys.stderr)
        return EXIT_USAGE
    except Exception as exc:
        if args.debug:
            traceback.print_exc()
        hint = "" if args.debug else " (--debug for the traceback)"
        print(f"endocam: internal error: {type(exc).__name__}: {exc}{hint}", file=sys.stderr)
        return EXIT_INTERNAL
    return int(code or 0)


STDOUT = "standard output"


class _NamedStdout:
    """``sys.stdout`` while a command runs: a failed write names standard output.

    A full disk (``endocam config > /dev/full``) or a closed pipe then ends as the one line
    ``endocam: error: standard output: No space left on device``.
    """

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        try:
            return self.stream.write(text)
        except OSError as exc:
            raise _stdout_error(exc) from None

    def flush(self) -> None:
        try:
            self.stream.flush()
        except OSError as exc:
            raise _stdout_error(exc) from None

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)


def _stdout_error(exc: OSError) -> OSError:
    return OSError(exc.errno, exc.strerror or str(exc), STDOUT)


@contextlib.contextmanager
def _named_stdout() -> Iterator[None]:
    """Run a command with :class:`_NamedStdout`, flushed at its end (so errors surface here).

    After a failed write, the stream's file descriptor is pointed at ``os.devnull``: what is
    still buffered cannot fail again at exit with a second message.
    """
    stream = sys.stdout
    sys.stdout = _NamedStdout(stream)
    try:
        yield
        sys.stdout.flush()
    except OSError as exc:
        if exc.filename == STDOUT:
            _silence(stream)
        raise
    finally:
        sys.stdout = stream


def _silence(stream: TextIO) -> None:
    with contextlib.suppress(OSError, ValueError):  # a stream without a file descriptor
        fd = stream.fileno()
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, fd)
        os.close(devnull)


def _interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


@contextlib.contextmanager
def _sigterm_interrupts() -> Iterator[None]:
    """While a command runs, ``SIGTERM`` raises ``KeyboardInterrupt`` (so clean-ups run).

    Only the main thread may set a signal handler; elsewhere (a test calling :func:`main` from
    a thread) nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

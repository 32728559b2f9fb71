"""``endocam check RUN_DIR...``: every logged step of finished runs against the safety invariants.

Prints one line per violation (step, time, invariant, value, limit) and one summary line per
run, and writes each run's ``check.json`` (atomically). A log that is not one endocam writes
(``runner.log_schema``: the carrier's columns, the row count of the duration at the control
rate, time stamps every control period, unit quaternions, known states) is refused, never
passed: it cannot be checked.

Exit codes (:data:`EXIT_CODES`): 0 every invariant held in every run; 1 a run broke an
invariant (violations found); 2 a run is malformed or cannot be read (one line on stderr
naming the file and the problem; runs before it are checked, none after). An internal error
also exits 1 (``endocam.cli``): never 0.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from endocam.cli.common import EXIT_USAGE, UsageError

EXIT_CLEAN = 0
EXIT_VIOLATIONS = 1
EXIT_CODES = (
    f"exit codes: {EXIT_CLEAN} every invariant holds in every run; {EXIT_VIOLATIONS} "
    f"violations found (or an internal error); {EXIT_USAGE} a run is malformed (a log "
    "endocam does not write: missing or extra columns, a row count other than the duration "
    "at the control rate gives, time stamps off the control period, non-unit quaternions, "
    "unknown states) or unreadable, refused with one line naming the problem"
)


def _check(args: argparse.Namespace) -> int:
    from endocam.runner.check import CHECK_JSON, check_run, write_check

    failed = 0
    for run in args.runs:
        try:
            result = check_run(Path(run))
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        if not args.quiet:
            for v in result.violations:
                print(f"{run}: {v.line()}")
        print(result.summary())
        fd, tmp = tempfile.mkstemp(prefix=f".{CHECK_JSON}.", dir=run)
        os.close(fd)
        try:
            write_check(result, Path(tmp))
            os.replace(tmp, Path(run) / CHECK_JSON)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        failed += not result.ok
    if len(args.runs) > 1:
        print(f"{len(args.runs) - failed} of {len(args.runs)} runs hold every invariant")
    return EXIT_VIOLATIONS if failed else EXIT_CLEAN


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``check`` to the CLI."""
    p = sub.add_parser(
        "check",
        help="check finished runs (scene.json + episode.csv) against the safety invariants",
        description="Check every logged step of each run folder against the safety invariants "
        "(floor, cone, wire clearance, carrier limits, finite poses, FK, holding on a lost "
        "observation), after refusing a log endocam does not write. Prints one line per "
        "violation and a summary, writes check.json into each run.",
        epilog=EXIT_CODES,
    )
    p.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run folders (endocam run --out)")
    p.add_argument("-q", "--quiet", action="store_true", help="only the summary lines")
    p.set_defaults(handler=_check)

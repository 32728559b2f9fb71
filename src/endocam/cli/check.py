"""``endocam check RUN_DIR...``: every logged step of finished runs against the safety invariants.

Prints one line per violation (step, time, invariant, value, limit) and one summary line per
run, writes each run's ``check.json`` (atomically), and exits 0 when every invariant held in
every run, 1 when any failed, 2 when a run cannot be read.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from endocam.cli.common import UsageError

EXIT_VIOLATIONS = 1


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
    return EXIT_VIOLATIONS if failed else 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``check`` to the CLI."""
    p = sub.add_parser(
        "check",
        help="check finished runs (scene.json + episode.csv) against the safety invariants",
        description="Check every logged step of each run folder against the safety invariants "
        "(floor, cone, carrier limits, finite poses, FK, holding on a lost observation). Prints "
        "one line per violation and a summary, writes check.json into each run; exit code 0 "
        "when all hold, 1 when any fails.",
    )
    p.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run folders (endocam run --out)")
    p.add_argument("-q", "--quiet", action="store_true", help="only the summary lines")
    p.set_defaults(handler=_check)

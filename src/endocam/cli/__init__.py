"""The ``endocam`` command line: parses, validates and calls the library.

Every user mistake (unknown policy, bad number, unwritable folder, malformed config) ends as one
line on stderr and exit code 2, never a traceback. One module per command group (``policies``,
``run`` for run/demo/experiment/config, ``study``), each with ``register(subparsers)``; they
import heavy parts (MuJoCo, FastAPI) only inside their handlers.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from endocam import __version__
from endocam.cli import policies, run, study, sweep
from endocam.cli.common import EXIT_USAGE, Parser, UsageError

__all__ = ["EXIT_USAGE", "UsageError", "build_parser", "main"]

Handler = Callable[[argparse.Namespace], int | None]


def build_parser() -> argparse.ArgumentParser:
    """Build the full argument parser with every command group."""
    parser = Parser(
        prog="endocam",
        description="Autonomous 6-DoF endoscopic camera control for MIS.",
    )
    parser.add_argument("--version", action="version", version=f"endocam {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for group in (policies, run, study, sweep):
        group.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Handler = args.handler
    try:
        code = handler(args)
    except UsageError as exc:
        print(f"endocam: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("endocam: interrupted", file=sys.stderr)
        return 130
    return int(code or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""The ``endocam`` command line: parses, validates and calls the library.

Every user mistake (unknown policy, bad number, unwritable folder, malformed config) ends as one
line on stderr and exit code 2, never a traceback. Subcommands live next to the code they drive;
each area module exposes ``register(subparsers)`` and this file only wires them together.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from typing import NoReturn

from endocam import __version__

EXIT_USAGE = 2


class UsageError(Exception):
    """A problem with what the user typed or pointed at; reported as one line, exit code 2."""


Handler = Callable[[argparse.Namespace], int | None]


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr with exit code 2."""

    def error(self, message: str) -> NoReturn:
        """Print ``prog: error: message`` (no usage block) and exit with code 2."""
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see --help)\n")


def _registrars() -> list[Callable[[argparse._SubParsersAction], None]]:
    """Import the subcommand modules lazily so optional extras stay optional."""
    from endocam.control import cli as control_cli

    regs: list[Callable[[argparse._SubParsersAction], None]] = [control_cli.register]
    for name in ("endocam.sim.cli", "endocam.study.cli", "endocam.robot.cli"):
        try:
            module = __import__(name, fromlist=["register"])
        except ModuleNotFoundError as exc:
            if exc.name is not None and exc.name.startswith("endocam"):
                continue  # area not built yet
            raise
        regs.append(module.register)
    return regs


def build_parser() -> argparse.ArgumentParser:
    """Build the full argument parser with every registered subcommand."""
    parser = _Parser(
        prog="endocam",
        description="Autonomous 6-DoF endoscopic camera control for MIS.",
    )
    parser.add_argument("--version", action="version", version=f"endocam {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for register in _registrars():
        register(sub)
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

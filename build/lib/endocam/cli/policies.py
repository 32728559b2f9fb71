"""CLI subcommands of the control layer: list the registered camera policies."""

from __future__ import annotations

import argparse


def _policies(args: argparse.Namespace) -> int:
    from endocam.registry import POLICIES

    for name, entry in POLICIES.items():
        print(f"{name:14s} {entry.summary}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``endocam policies`` to the CLI."""
    p = sub.add_parser("policies", help="list the registered camera policies")
    p.set_defaults(handler=_policies)

"""``endocam sweep``: a grid of episodes on this machine's process pool or on Ray."""

from __future__ import annotations

import argparse
from typing import Any

from endocam.cli.common import (
    ARM_CHOICES,
    PERCEPTION_CHOICES,
    UsageError,
    check_workers,
    integer,
    load_config_arg,
    out_dir,
)
from endocam.cli.run import safety_exit
from endocam.registry import POLICIES
from endocam.runner.pool import DEFAULT_WORKERS
from endocam.task.trajectory import TrajectoryKind


def _list(text: str) -> list[str]:
    return [v.strip() for v in text.split(",") if v.strip()]


def _value(text: str) -> Any:
    """A ``--set`` value: TOML's reading of it (numbers, booleans, lists), else the string."""
    import tomllib

    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _values(text: str) -> list[Any]:
    """``--set`` values as TOML array items (``0.05,0.1``, ``[0.1,0.2],[0.2,0.3]``), else words."""
    import tomllib

    try:
        return list(tomllib.loads(f"v = [{text}]")["v"])
    except tomllib.TOMLDecodeError:
        return [_value(v) for v in _list(text)]


def _short_forms(args: argparse.Namespace) -> dict[str, Any]:
    """The grid axes given on the command line."""
    from endocam.runner.sweep import parse_seeds

    grid: dict[str, Any] = {}
    if args.policy:
        grid["policy"] = _list(args.policy)
        unknown = [p for p in grid["policy"] if p not in POLICIES]
        if unknown:
            raise UsageError(f"unknown policy {unknown[0]!r}; choose from: {', '.join(POLICIES)}")
    if args.trajectory:
        grid["trajectory"] = _list(args.trajectory)
        kinds = [k.value for k in TrajectoryKind]
        bad = [k for k in grid["trajectory"] if k not in kinds]
        if bad:
            raise UsageError(f"unknown trajectory {bad[0]!r}; choose from: {', '.join(kinds)}")
    if args.control_points:
        try:
            grid["control_points"] = [int(v) for v in _list(args.control_points)]
        except ValueError:
            got = args.control_points
            raise UsageError(f"--control-points: expected integers, got {got!r}") from None
    if args.seeds:
        grid["seed"] = parse_seeds(args.seeds)
    if args.arm:
        grid["arm"] = _list(args.arm)
        bad = [a for a in grid["arm"] if a not in ARM_CHOICES]
        if bad:
            raise UsageError(f"unknown arm {bad[0]!r}; choose from: {', '.join(ARM_CHOICES)}")
    if args.perception:
        grid["perception.source"] = _list(args.perception)
        bad = [v for v in grid["perception.source"] if v not in PERCEPTION_CHOICES]
        if bad:
            raise UsageError(
                f"unknown perception {bad[0]!r}; choose from: {', '.join(PERCEPTION_CHOICES)}"
            )
    for item in args.set or []:
        path, sep, values = item.partition("=")
        if not sep or not path.strip():
            raise UsageError(f"--set: expected PATH=VALUE[,VALUE...], got {item!r}")
        grid[path.strip()] = _values(values)
    return grid


def _sweep(args: argparse.Namespace) -> int:
    from endocam.runner.sweep import (
        SweepError,
        describe,
        expand,
        load_sweep,
        make_backend,
        run_sweep,
    )

    check_workers(args.workers)
    try:
        short = _short_forms(args)
        if args.sweep is not None:
            base, grid, points = load_sweep(args.sweep)
            if args.config is not None:
                raise UsageError("--base-config: the sweep file names its base config")
        else:
            base, grid, points = load_config_arg(args.config), {}, []
        grid = {**grid, **short}  # the command line replaces a file's axis
        tasks = expand(base, grid, points)
        backend = make_backend(args.backend, workers=args.workers, address=args.address)
    except SweepError as exc:
        raise UsageError(str(exc)) from None
    out = out_dir(args.out)
    outcome = run_sweep(tasks, out, backend, description=describe(base, grid, points))
    print(
        f"{len(tasks)} episodes ({outcome.ran} run now, {outcome.skipped} already done, "
        f"{outcome.failed} failed) -> {outcome.results}, {outcome.summary}"
    )
    return safety_exit(out)  # 3 when an episode's safety check found violations


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``sweep`` to the CLI."""
    s = sub.add_parser(
        "sweep",
        help="run a grid of episodes (policies × trajectories × seeds × any config field) "
        "on a process pool or Ray; results.parquet and summary.html",
        description="Run every combination of the sweep's parameters as one headless episode "
        "(each writes what `endocam run --no-video` writes under OUT/episodes/), then gather "
        "them into OUT/results.parquet and OUT/summary.html. Resumable: run the same command "
        "again and only the missing episodes run.",
    )
    s.add_argument(
        "--config",
        dest="sweep",
        metavar="SWEEP.toml",
        help="sweep file: config = 'base.toml' or [base], [grid] name = [values], [[list]]",
    )
    s.add_argument("--out", required=True, help="sweep folder (kept between runs: resume)")
    s.add_argument(
        "--backend",
        choices=["local", "ray"],
        default="local",
        help="local: a process pool on this machine (default); ray: Ray tasks "
        "(pip install endocam[ray])",
    )
    s.add_argument("--address", help="Ray cluster address (default: start Ray on this machine)")
    s.add_argument(
        "--workers",
        type=integer,
        default=DEFAULT_WORKERS,
        help=f"local worker processes (default {DEFAULT_WORKERS}; 1: in this process)",
    )
    s.add_argument("--policy", help="comma-separated policies, e.g. orientation,centering")
    s.add_argument("--trajectory", help="comma-separated: ideal, noisy (default noisy)")
    s.add_argument("--control-points", help="comma-separated counts (default 71)")
    s.add_argument("--seeds", help="e.g. 0-99 or 0,3,7 (default 1)")
    s.add_argument("--arm", help="comma-separated carriers: free, psm, ecm (default the config's)")
    s.add_argument(
        "--perception",
        help="comma-separated ring pose sources: truth, stereo (default the config's, truth)",
    )
    s.add_argument(
        "--set",
        action="append",
        metavar="PATH=V1,V2",
        help="sweep a config field by its dotted path, SI units, e.g. "
        "episode.sensing_latency=0.05,0.1 (repeatable)",
    )
    s.add_argument(
        "--base-config", dest="config", help="base TOML/YAML config without a sweep file"
    )
    s.set_defaults(handler=_sweep, runs_episodes=True)

"""``endocam sweep``: a grid of episodes on a local process pool or on Ray, gathered into one table.

A sweep is a base :class:`ExperimentConfig` and a grid (or list) of overrides. Five names are
the episode's own parameters (:data:`EPISODE_PARAMS`: ``policy``, ``trajectory``,
``control_points``, ``seed``, ``arm`` = ``episode.arm``); any other name is a config field by
its dotted path (``episode.sensing_latency``, ``controller.d_f``), validated through
:class:`ExperimentConfig` per episode. Every combination is one :class:`SweepTask`.

Written into the sweep folder::

    sweep.json               what was swept (the grid, the list, the base config)
    episodes/<name>/         what ``endocam run --no-video`` writes (scene.json, episode.csv,
                             metrics.json, tracking.png, report.html) and task.json (the
                             parameters, the wall time, the error of a failed episode)
    results.parquet          one row per episode: parameters, flattened metrics, wall_time_s, error
    summary.html, plots/     each metric against each swept parameter, 95 % CIs over seeds

Resume: an episode folder appears only complete (it is written under a hidden name and renamed),
and a task whose folder exists is not run again, so a sweep killed half-way and started again
runs only the missing episodes. An episode that fails (an invalid override value, an exception
in the episode) is recorded in its ``task.json`` with its error instead of stopping the sweep.
A folder's name holds a hash of its parameters and base config, so changing either runs anew.
"""

from __future__ import annotations

import concurrent.futures
import functools
import hashlib
import itertools
import json
import math
import os
import re
import shutil
import socket
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
from pydantic import BaseModel
from tqdm import tqdm

from endocam.config import ExperimentConfig, config_from_mapping
from endocam.progress import progress_bar
from endocam.runner.episode import DEFAULT_SEED, LOG_STATES, EpisodeSpec, run_episode
from endocam.runner.experiments import ground_truth
from endocam.runner.outputs import (
    METRICS_JSON,
    OUTPUT_MARKER,
    check_output_folder,
    json_safe,
    write_atomic,
    write_json,
    write_marker,
    write_run,
)
from endocam.runner.pool import DEFAULT_WORKERS, executor
from endocam.task.touches import TouchReport
from endocam.task.trajectory import TrajectoryKind

EPISODE_PARAMS = ("policy", "trajectory", "control_points", "seed", "arm")
"""The episode's own parameters, always columns of the table, in this order."""
DEFAULTS: dict[str, Any] = {"trajectory": TrajectoryKind.NOISY.value, "control_points": 71}
DEFAULTS["seed"] = DEFAULT_SEED  # as `endocam run`
"""Values of the episode parameters a sweep does not set (``arm``: the config's)."""
BACKENDS = ("local", "ray")
RAY_MISSING = "the ray backend needs Ray: pip install endocam[ray]"
SWEEP_JSON = "sweep.json"
TASK_JSON = "task.json"
RESULTS_PARQUET = "results.parquet"
EPISODES = "episodes"
ERROR_MAX_CHARS = 500  # characters of an error message kept in task.json and the table
MAX_SWEEP_EPISODES = 100_000
"""Episodes of one sweep at most (count). A headless 60 s episode takes ≥ 0.86 s of CPU (the
control loop runs ≥ 70× real time) and leaves a ~5 MB folder (``episode.csv`` with the PSM's
joints), so the bound is already ≥ 1 CPU-day and ~0.5 TB; above it a typo
(``--seeds 0-300000000``) is refused before any list is built."""
STATS = ("mean", "p95", "max")
ERRORS = ("image_error_px", "center_error_mm", "orientation_error_deg")
METRIC_COLUMNS: tuple[str, ...] = (
    *(f"{e}_{s}" for e in ERRORS for s in STATS),
    "ring_out_of_view_fraction",
    "touches",
    "contact_fraction",
    *(f"state_{s}" for s in LOG_STATES),
    "duration_s",
)
"""The metrics of ``metrics.json`` as table columns (``state_<s>``: fraction of time in ``s``)."""


class SweepError(ValueError):
    """A problem with the sweep as given (a file, a name, a value): one line for the user."""


@dataclass(frozen=True)
class SweepTask:
    """One episode of a sweep.

    Attributes
    ----------
    name : str
        Folder name under ``episodes/`` (readable parameters and a hash of everything).
    params : dict
        The swept values by column name (:data:`EPISODE_PARAMS` and dotted paths), JSON types.
    base : dict
        The base config as JSON (overrides are applied and validated when the task runs).
    """

    name: str
    params: Mapping[str, Any]
    base: Mapping[str, Any]

    def episode(self) -> tuple[ExperimentConfig, EpisodeSpec]:
        """The validated config and episode of this task.

        Raises
        ------
        ValueError
            One line naming the invalid value.
        """
        data = json.loads(json.dumps(self.base))  # a deep copy
        for key, value in self.params.items():
            if key == "arm":
                _set_path(data, "episode.arm", value)
            elif key not in EPISODE_PARAMS:
                _set_path(data, key, value)
        config = config_from_mapping(data, "override")
        p = {**DEFAULTS, **self.params}
        try:
            kind = TrajectoryKind(p["trajectory"])
        except ValueError:
            kinds = ", ".join(k.value for k in TrajectoryKind)
            raise ValueError(f"trajectory: {p['trajectory']!r} is not one of {kinds}") from None
        spec = EpisodeSpec(str(p["policy"]), kind, int(p["control_points"]), int(p["seed"]))
        return config, spec


# ------------------------------------------------------------------------------ the grid
def parse_seeds(text: str) -> list[int]:
    """Seeds from ``"0-99"`` (inclusive), ``"3"`` or ``"0,4,7-9"``.

    Raises
    ------
    SweepError
        For anything else, or a negative or repeated seed.
    """
    ranges: list[range] = []
    for part in str(text).split(","):
        m = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
        if m is None:
            raise SweepError(f"seeds: expected e.g. 0-99 or 0,3,5, got {text!r}")
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) is not None else lo
        if hi < lo:
            raise SweepError(f"seeds: empty range {part.strip()!r}")
        ranges.append(range(lo, hi + 1))
    count = sum(len(r) for r in ranges)
    if count > MAX_SWEEP_EPISODES:
        raise SweepError(
            f"seeds: {text!r} names {count} seeds, more than a sweep's "
            f"MAX_SWEEP_EPISODES = {MAX_SWEEP_EPISODES} episodes"
        )
    seeds = [seed for r in ranges for seed in r]
    if len(set(seeds)) != len(seeds):
        raise SweepError(f"seeds: repeated in {text!r}")
    return seeds


def check_param(name: str) -> None:
    """Raise :class:`SweepError` unless ``name`` is an episode parameter or a config field."""
    if name in EPISODE_PARAMS:
        return
    model: Any = ExperimentConfig
    for i, part in enumerate(name.split(".")):
        fields = getattr(model, "model_fields", None)
        if fields is None or part not in fields:
            where = ".".join(name.split(".")[:i]) or "the config"
            known = ", ".join(fields) if fields else "no fields"
            raise SweepError(
                f"unknown sweep parameter {name!r}: {where} has {known} "
                f"(or use one of {', '.join(EPISODE_PARAMS)})"
            )
        model = fields[part].annotation
    if isinstance(model, type) and issubclass(model, BaseModel):
        raise SweepError(f"sweep parameter {name!r} is a section; name one of its fields")


def _set_path(data: dict[str, Any], path: str, value: Any) -> None:
    *parents, leaf = path.split(".")
    for part in parents:
        data = data.setdefault(part, {})
    data[leaf] = value


def _values(name: str, values: Any) -> list[Any]:
    if name == "seed" and isinstance(values, str):
        return list(parse_seeds(values))
    if not isinstance(values, list) or not values:
        raise SweepError(f"grid.{name}: expected a non-empty list of values")
    return values


def expand(
    base: ExperimentConfig,
    grid: Mapping[str, Any],
    points: Sequence[Mapping[str, Any]] = (),
) -> list[SweepTask]:
    """Every combination of the grid, crossed with each point of the list (if any).

    Parameters
    ----------
    base : ExperimentConfig
    grid : mapping
        Parameter name → list of values (``seed`` also takes ``"0-99"``).
    points : sequence of mapping
        Explicit parameter sets; each is crossed with the grid (their names must differ).

    Raises
    ------
    SweepError
        For an unknown name, an empty list, a name in both grid and list, or no policy.
    """
    grid = {name: _values(name, v) for name, v in grid.items()}
    points = [dict(p) for p in points] or [{}]
    count = math.prod(len(v) for v in grid.values()) * len(points)
    if count > MAX_SWEEP_EPISODES:
        sizes = " × ".join(str(n) for n in [*(len(v) for v in grid.values()), len(points)])
        raise SweepError(
            f"the sweep has {sizes} = {count} episodes, more than "
            f"MAX_SWEEP_EPISODES = {MAX_SWEEP_EPISODES}"
        )
    for name in {*grid, *(k for p in points for k in p)}:
        check_param(name)
    for p in points:
        both = sorted(set(p) & set(grid))
        if both:
            raise SweepError(f"{', '.join(both)} set both in the grid and in a list entry")
        if "policy" not in p and "policy" not in grid:
            raise SweepError("the sweep names no policy (grid.policy or --policy)")
    base_json = base.model_dump(mode="json")
    tasks: dict[str, SweepTask] = {}
    for point in points:
        for combo in itertools.product(*grid.values()):
            params = {**point, **dict(zip(grid, combo, strict=True))}
            ordered = {k: params[k] for k in EPISODE_PARAMS if k in params}
            ordered.update({k: v for k, v in params.items() if k not in EPISODE_PARAMS})
            task = SweepTask(task_name(ordered, base_json), ordered, base_json)
            tasks.setdefault(task.name, task)  # a repeated combination runs once
    return list(tasks.values())


def task_name(params: Mapping[str, Any], base: Mapping[str, Any]) -> str:
    """``<policy>-<trajectory>-<points>-s<seed>[-<arm>]-<hash>``: readable and unique."""
    p = {**DEFAULTS, **params}
    digest = hashlib.sha1(
        json.dumps([params, base], sort_keys=True, default=str).encode("utf-8")
    ).hexdigest()[:10]
    parts = [p["policy"], p["trajectory"], p["control_points"], f"s{p['seed']}"]
    if "arm" in params:
        parts.append(params["arm"])
    readable = "-".join(re.sub(r"[^A-Za-z0-9_.]+", "_", str(x)) for x in parts)
    return f"{readable[:80]}-{digest}"


def load_sweep(path: str | Path) -> tuple[ExperimentConfig, dict[str, Any], list[dict[str, Any]]]:
    """Read a sweep file (TOML): the base config, the grid and the list of points.

    The file holds ``config = "base.toml"`` (a config file, relative to the sweep file) or a
    ``[base]`` table (the config itself), a ``[grid]`` table (name → list of values) and
    optionally ``[[list]]`` entries (name → value).

    Raises
    ------
    SweepError
        One line for a missing, malformed or invalid file.
    """
    import tomllib

    from endocam.config import load_config, read_text

    p = Path(path)
    try:
        data = tomllib.loads(read_text(p, "sweep"))
    except tomllib.TOMLDecodeError as exc:
        raise SweepError(f"sweep {p} is malformed: {exc}") from None
    except ValueError as exc:  # missing, unreadable, too large, not UTF-8
        raise SweepError(str(exc)) from None
    unknown = sorted(set(data) - {"config", "base", "grid", "list"})
    if unknown:
        raise SweepError(f"sweep {p}: unknown key {unknown[0]!r} (config, base, grid, list)")
    if "config" in data and "base" in data:
        raise SweepError(f"sweep {p}: give config (a file) or [base], not both")
    try:
        if "config" in data:
            base = load_config(p.parent / str(data["config"]))
        else:
            base = config_from_mapping(data.get("base", {}), f"{p} [base]")
    except ValueError as exc:
        raise SweepError(str(exc)) from None
    grid = data.get("grid", {})
    points = data.get("list", [])
    if not isinstance(grid, dict) or not isinstance(points, list):
        raise SweepError(f"sweep {p}: [grid] must be a table and [[list]] a list of tables")
    return base, grid, points


# --------------------------------------------------------------------------- one episode
TOUCH_CACHE_SIZE = 8  # trajectories whose ground truth a worker keeps (~0.5 MB each for 60 s)
_TOUCHES: dict[tuple[str, TrajectoryKind, int, int], TouchReport] = {}


def shared_ground_truth(config: ExperimentConfig, spec: EpisodeSpec) -> TouchReport:
    """The ground-truth touches of an episode's trajectory, kept in this worker process.

    They depend on the task config and the trajectory (kind, control points, seed) alone, not
    on the policy, the carrier or the controller, so the episodes of a sweep that share a
    trajectory compute them once per worker (:func:`trajectory_order` runs them in turn). The
    :data:`TOUCH_CACHE_SIZE` most recently used trajectories are kept.
    """
    key = (config.task.model_dump_json(), spec.trajectory, spec.control_points, spec.seed)
    touches = _TOUCHES.pop(key, None)
    if touches is None:
        touches = ground_truth(config, spec.trajectory, spec.control_points, spec.seed)
    _TOUCHES[key] = touches  # the most recently used last
    while len(_TOUCHES) > TOUCH_CACHE_SIZE:
        del _TOUCHES[next(iter(_TOUCHES))]
    return touches


def trajectory_order(tasks: Sequence[SweepTask]) -> list[SweepTask]:
    """The tasks with those that share a trajectory next to each other (otherwise in order).

    A trajectory is named by its parameters (kind, control points, seed) and the ``task.*``
    overrides, so a worker's cache (:func:`shared_ground_truth`) serves the next episodes.
    """

    def key(task: SweepTask) -> str:
        p = {**DEFAULTS, **task.params}
        world = sorted((k, v) for k, v in p.items() if k.startswith("task."))
        return json.dumps([p["trajectory"], p["control_points"], p["seed"], world], default=str)

    return sorted(tasks, key=key)


def run_task(task: SweepTask, episodes_dir: str | Path) -> str:
    """Run one task and write its folder (in a worker); returns the task's name.

    A failure of the episode is written to ``task.json`` (``error``), never raised: the sweep
    goes on. The folder is written under a hidden name and renamed when complete.
    """
    root = Path(episodes_dir)
    stage = root / f".{task.name}.stage-{socket.gethostname()}-{os.getpid()}"  # any node
    t0 = time.perf_counter()
    error = None
    try:
        config, spec = task.episode()
        result = run_episode(config, spec, touches=shared_ground_truth(config, spec))
        write_run(result, stage, video=False)
    except Exception as exc:  # recorded: one episode must not stop the sweep
        error = f"{type(exc).__name__}: {exc}"[:ERROR_MAX_CHARS]
        shutil.rmtree(stage, ignore_errors=True)
        stage.mkdir(parents=True)
    record = {
        "name": task.name,
        "params": dict(task.params),
        "wall_time_s": time.perf_counter() - t0,
        "error": error,
    }
    write_json(stage / TASK_JSON, json_safe(record))
    os.replace(stage, root / task.name)
    return task.name


def done(task: SweepTask, episodes_dir: Path) -> bool:
    """Whether the task's folder is complete (it exists only once complete)."""
    return (episodes_dir / task.name / TASK_JSON).is_file()


def clean_partial(episodes_dir: Path) -> None:
    """Remove what a killed sweep left half-written (hidden stage and temporary folders)."""
    if episodes_dir.is_dir():
        for p in episodes_dir.glob(".*"):
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)


# ------------------------------------------------------------------------------ backends
Progress = Callable[[int], object]
Backend = Callable[[Sequence[SweepTask], Path, Progress], None]
"""Runs tasks, calling ``progress(k)`` as ``k`` more are done."""


def local_backend(workers: int = DEFAULT_WORKERS) -> Backend:
    """Run tasks on this machine's process pool (:func:`endocam.runner.pool.executor`)."""

    def run(tasks: Sequence[SweepTask], episodes_dir: Path, progress: Progress) -> None:
        with executor(workers) as pool:
            futures = []
            for task in tasks:
                fut = pool.submit(run_task, task, episodes_dir)
                if fut.done():  # one worker runs inline: report each episode as it ends
                    _settle(fut.result)
                    progress(1)
                else:
                    futures.append(fut)
            for fut in concurrent.futures.as_completed(futures):
                _settle(fut.result)
                progress(1)

    return run


LOST = "no result: its worker died before writing it (run the sweep again to retry it)"


def _settle(result: Callable[[], object]) -> None:
    """Wait for a task; a worker that died is reported and its task left to a rerun.

    Episode failures never get here (:func:`run_task` records them); this is the machinery
    failing (a killed or crashed worker), after which the task has no folder.
    """
    try:
        result()
    except Exception as exc:
        tqdm.write(f"endocam sweep: a worker failed: {type(exc).__name__}: {exc}"[:300])


def import_ray() -> Any:
    """The ``ray`` module, or :class:`SweepError` naming the extra to install."""
    try:
        import ray
    except ImportError:
        raise SweepError(RAY_MISSING) from None
    return ray


def ray_backend(address: str | None = None) -> Backend:
    """Run tasks on Ray: the running session, else ``ray.init(address)`` (local if ``None``).

    With a remote cluster the sweep folder must be on a file system every node shares.
    """
    ray = import_ray()

    def run(tasks: Sequence[SweepTask], episodes_dir: Path, progress: Progress) -> None:
        started = not ray.is_initialized()
        if started:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
        try:
            remote = ray.remote(num_cpus=1, max_retries=0)(run_task)
            pending = [remote.remote(t, str(episodes_dir)) for t in tasks]
            while pending:
                finished, pending = ray.wait(pending, num_returns=1)
                _settle(functools.partial(ray.get, finished))
                progress(len(finished))
        finally:
            if started:
                ray.shutdown()

    return run


def make_backend(
    name: str, *, workers: int = DEFAULT_WORKERS, address: str | None = None
) -> Backend:
    """The backend called ``name`` (:data:`BACKENDS`).

    Raises
    ------
    SweepError
        For an unknown name, ``--address`` without Ray, or Ray missing.
    """
    if name == "local":
        if address is not None:
            raise SweepError("--address needs --backend ray")
        if workers < 1:
            raise SweepError(f"workers must be ≥ 1, got {workers}")
        return local_backend(workers)
    if name == "ray":
        return ray_backend(address)
    raise SweepError(f"unknown backend {name!r}; choose one of: {', '.join(BACKENDS)}")


# ------------------------------------------------------------------------------- the sweep
@dataclass(frozen=True)
class SweepOutcome:
    """What a sweep did: episodes run now, found done, failed (in total), and its files."""

    ran: int
    skipped: int
    failed: int
    results: Path
    summary: Path


def run_sweep(
    tasks: Sequence[SweepTask],
    out_dir: Path,
    backend: Backend,
    *,
    description: Mapping[str, Any] | None = None,
) -> SweepOutcome:
    """Run the missing tasks, then gather every task into the table and the summary.

    Parameters
    ----------
    tasks : sequence of SweepTask
        From :func:`expand`.
    out_dir : Path
        The sweep folder (created and marked with ``.endocam-output``; kept between runs to
        resume). An existing folder must be empty or endocam's own.
    backend : Backend
        From :func:`make_backend`.
    description : mapping, optional
        Written to ``sweep.json`` (the grid as given).
    """
    from endocam.runner.summary import write_summary

    out_dir = check_output_folder(out_dir)  # empty, or endocam's own (a sweep to resume)
    episodes_dir = out_dir / EPISODES
    episodes_dir.mkdir(parents=True, exist_ok=True)
    if not (out_dir / OUTPUT_MARKER).is_file():
        write_marker(out_dir)
    clean_partial(episodes_dir)
    write_atomic(out_dir / SWEEP_JSON, lambda p: write_json(p, json_safe(dict(description or {}))))
    todo = [t for t in tasks if not done(t, episodes_dir)]
    with progress_bar(
        total=len(tasks),
        initial=len(tasks) - len(todo),
        desc="episodes",
        unit="episode",
        leave=True,
    ) as bar:
        if todo:
            backend(trajectory_order(todo), episodes_dir, bar.update)
    rows = gather(tasks, episodes_dir)
    table = results_table(rows, swept_names(tasks))
    results = out_dir / RESULTS_PARQUET
    write_atomic(results, lambda p: pq.write_table(table, p))
    summary = write_summary(rows, swept_names(tasks), out_dir)
    failed = sum(r["error"] is not None for r in rows)
    return SweepOutcome(len(todo), len(tasks) - len(todo), failed, results, summary)


def swept_names(tasks: Sequence[SweepTask]) -> list[str]:
    """Every parameter name the tasks set, episode parameters first."""
    names = dict.fromkeys(k for t in tasks for k in t.params)
    return [
        *(k for k in EPISODE_PARAMS if k in names),
        *(k for k in names if k not in EPISODE_PARAMS),
    ]


# -------------------------------------------------------------------------------- the table
def metric_columns(metrics: Mapping[str, Any]) -> dict[str, Any]:
    """``metrics.json`` flattened into the :data:`METRIC_COLUMNS` (``None`` where undefined)."""
    row: dict[str, Any] = {}
    for e in ERRORS:
        for s in STATS:
            row[f"{e}_{s}"] = metrics[e][s]
    for key in ("ring_out_of_view_fraction", "touches", "contact_fraction"):
        row[key] = metrics[key]
    for s in LOG_STATES:
        row[f"state_{s}"] = metrics["state_fractions"].get(s, 0.0)
    row["duration_s"] = metrics["episode"]["duration_s"]
    return row


def gather(tasks: Sequence[SweepTask], episodes_dir: Path) -> list[dict[str, Any]]:
    """One row per task, from its folder: parameters, metrics, wall time and error."""
    rows = []
    for task in tasks:
        folder = episodes_dir / task.name
        if not done(task, episodes_dir):
            record = {"error": LOST, "wall_time_s": None}
        else:
            record = json.loads((folder / TASK_JSON).read_text(encoding="utf-8"))
        row: dict[str, Any] = {"episode": task.name, **DEFAULTS}
        row["arm"] = task.base["episode"]["arm"]
        row.update(task.params)
        if record["error"] is None:
            metrics = json.loads((folder / METRICS_JSON).read_text(encoding="utf-8"))
            row["arm"] = metrics["arm"]  # the carrier used (a policy may force one)
            row.update(metric_columns(metrics))
        else:
            row.update(dict.fromkeys(METRIC_COLUMNS))
        row["wall_time_s"] = record["wall_time_s"]
        row["error"] = record["error"]
        rows.append(row)
    return rows


_TYPES = {"touches": pa.int64(), "error": pa.string(), "wall_time_s": pa.float64()}


def results_table(rows: Sequence[Mapping[str, Any]], swept: Sequence[str]) -> pa.Table:
    """The tidy table: ``episode``, parameters, :data:`METRIC_COLUMNS`, ``wall_time_s``, ``error``.

    Parameter columns take their values' type; metrics are float64 (``touches`` int64), null
    for a failed episode.
    """
    params = [*EPISODE_PARAMS, *(s for s in swept if s not in EPISODE_PARAMS)]
    columns = ["episode", *params, *METRIC_COLUMNS, "wall_time_s", "error"]
    arrays = []
    for name in columns:
        values = [r.get(name) for r in rows]
        if name in METRIC_COLUMNS or name in _TYPES:
            arrays.append(pa.array(values, type=_TYPES.get(name, pa.float64())))
        else:
            arrays.append(pa.array(values))
    return pa.Table.from_arrays(arrays, names=columns)


def describe(
    base: ExperimentConfig, grid: Mapping[str, Any], points: Sequence[Mapping[str, Any]]
) -> dict[str, Any]:
    """What ``sweep.json`` records: the grid, the list and the base config."""
    return {
        "grid": dict(grid),
        "list": [dict(p) for p in points],
        "base": base.model_dump(mode="json"),
    }


__all__ = [
    "BACKENDS",
    "EPISODE_PARAMS",
    "METRIC_COLUMNS",
    "SweepError",
    "SweepOutcome",
    "SweepTask",
    "expand",
    "gather",
    "load_sweep",
    "make_backend",
    "parse_seeds",
    "results_table",
    "run_sweep",
    "run_task",
]

"""The paper's claim, measured: the observer's counting error and what each condition shows.

``hypothesis.json`` compares the study's camera conditions (any number) on the study's most
difficult trajectory and over extra noise seeds of it (``study make --seeds N``). It leads with
the simulator's closing gap (:mod:`endocam.study.visibility`): the share of touches ``resolved``
(in sight from an eye and at least 2 px wide at 0.5 mm), in sight from either eye and from the
left eye, each with a seed-level bootstrap 95 % interval over the extra seeds. Then, per
condition, the automatic observer's counting error, precision and recall against the
simulator's touches, and the image-space observability of the true touches (the silhouette gap
seen just before each one and whether it closes visibly,
:func:`endocam.study.observer.gap_view`).

Re-analysis without re-rendering. ``study make --keep-seed-videos`` keeps the extra seeds'
videos in the study folder::

    seeds/<noise seed>/<condition>.mp4   left eye, H.264, one per condition
    seeds/<noise seed>/truth.json   {"seed", "fps", "true_events": [[t_start, t_end], ...] (s),
                                     "closing_gap": {condition: [per touch, ...]}, ...}

and :func:`recount_study` (``endocam study observe``) counts every video of the folder again
with the current observer and rewrites ``observer.json/.html``, the image-space columns of
``observability.json/.csv`` and ``hypothesis.json`` from them. Seeds whose videos were not kept
cannot be counted again: their rows are left as they were and ``extra_seeds.recounted`` says so.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import json
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from endocam.runner.outputs import write_atomic
from endocam.runner.pool import DEFAULT_WORKERS, executor
from endocam.study.manifest import Manifest, condition_policies, load_manifest
from endocam.study.observability import (
    OBSERVABILITY_CSV,
    OBSERVABILITY_JSON,
    TouchObservation,
    count_hiders,
    finite_median,
    hidden_counts,
    known_share,
    observability_csv,
    observability_json,
    row_columns,
    summarize,
)
from endocam.study.observer import (
    OBSERVER_HTML,
    OBSERVER_JSON,
    ColourKeys,
    VideoObservation,
    gap_view,
    keys_for_study,
    match_events,
    observe_video,
    observer_document,
    observer_html,
)
from endocam.study.visibility import hider_kind, share_ci

HYPOTHESIS_JSON = "hypothesis.json"
SEEDS_DIR = "seeds"  # kept extra-seed videos: seeds/<noise seed>/<condition>.mp4
TRUTH_JSON = "truth.json"  # per kept seed: the simulator's touch intervals

Interval = tuple[float, float]  # (t_start, t_end), s
Hidden = dict[str, list[str | None]]  # per condition, per touch: what hides its gap (None: nothing)
Gaps = dict[str, list[dict[str, Any]]]  # per condition, per touch: visibility.gap_row
_FLOAT = ("float", float)  # a dataclass field's type, as a string under postponed annotations


# ------------------------------------------------------------------------------ per touch
def with_gaps(record: TouchObservation, obs: VideoObservation) -> TouchObservation:
    """``record`` with the image-space gap columns from its video's per-frame gaps."""
    view = gap_view(obs.gaps_px, obs.fps, record.t_start_s, record.t_end_s)
    return dataclasses.replace(
        record,
        gap_before_px=view.gap_before_px,
        gap_min_px=view.gap_min_px,
        closes_visibly=view.closes_visibly,
    )


def load_records(path: str | Path) -> list[TouchObservation]:
    """The per-touch records of an ``observability.json`` (JSON ``null`` read back as NaN).

    Raises
    ------
    ValueError
        One line if the file is unreadable or a record does not match :class:`TouchObservation`.
    """
    p = Path(path)
    try:
        touches = json.loads(p.read_text("utf-8"))["touches"]
        floats = {f.name for f in dataclasses.fields(TouchObservation) if f.type in _FLOAT}
        nan_for_null: list[dict[str, Any]] = [
            {k: math.nan if v is None and k in floats else v for k, v in t.items()} for t in touches
        ]
        return [TouchObservation(**t) for t in nan_for_null]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"cannot read the touches of {p}: {exc}") from None


# ------------------------------------------------------------------------------ extra seeds
def seed_rows(
    folder: Path,
    seed: int,
    true_events: Sequence[Interval],
    keys: ColourKeys,
    conditions: Sequence[str],
    hidden: Hidden | None = None,
    gaps: Gaps | None = None,
) -> list[dict[str, Any]]:
    """Observe one extra seed's videos (``folder/<condition>.mp4``), one row per condition.

    Each row: ``seed``, ``condition``, ``true_touches``, ``counted_touches``,
    ``matched_touches`` (seen touches overlapping a true one within a frame, one to one:
    :func:`~endocam.study.observer.match_events`), and per true touch ``gap_before_px``,
    ``closes_visibly``, from the simulator ``closing_gap`` (``gaps[condition]``: both eyes'
    view of the closing gap, :func:`~endocam.study.visibility.gap_row`) and the left eye's
    ``gap_hidden_by`` and ``gap_in_sight`` (from ``gaps``, else ``hidden[condition]``); None
    when not known.
    """
    if gaps is not None:
        hidden = {c: [g["hidden_by_left"] for g in rows] for c, rows in gaps.items()}
    rows: list[dict[str, Any]] = []
    for c in conditions:
        obs = observe_video(folder / f"{c}.mp4", keys)
        views = [gap_view(obs.gaps_px, obs.fps, t0, t1) for t0, t1 in true_events]
        match = match_events(
            [(t.t_start, t.t_end) for t in obs.touches], list(true_events), 1.0 / obs.fps
        )
        rows.append(
            {
                "seed": seed,
                "condition": c,
                "true_touches": len(true_events),
                "counted_touches": len(obs.touches),
                "matched_touches": match.true_positives,
                "gap_before_px": [v.gap_before_px for v in views],
                "closes_visibly": [v.closes_visibly for v in views],
                "gap_in_sight": None if hidden is None else [h is None for h in hidden[c]],
                "gap_hidden_by": None if hidden is None else hidden[c],
                "closing_gap": None if gaps is None else gaps[c],
            }
        )
    return rows


def write_truth(
    folder: Path,
    seed: int,
    fps: float,
    true_events: Sequence[Interval],
    hidden: Hidden | None,
    keep: Mapping[str, object] | None = None,
    gaps: Gaps | None = None,
) -> None:
    """Write a kept seed's ``truth.json`` (atomically); ``hidden``: per condition, per touch.

    ``gap_hidden_by`` is what hides each touch's closing gap from the left eye (None: it is in
    sight), ``gap_in_sight`` the same as flags, ``closing_gap`` both eyes' view of it
    (:func:`~endocam.study.visibility.gap_row`; kept from ``keep`` when not given). ``keep``: the
    file as it was (a replay's rewrite), whose other keys (a user's notes, say) are kept.
    """
    doc = {
        **(keep or {}),
        "seed": seed,
        "fps": fps,
        "true_events": [list(e) for e in true_events],
        "gap_in_sight": None
        if hidden is None
        else {c: [h is None for h in hs] for c, hs in hidden.items()},
        "gap_hidden_by": hidden,
    }
    if gaps is not None:
        doc["closing_gap"] = gaps
    write_atomic(folder / TRUTH_JSON, lambda p: p.write_text(json.dumps(doc) + "\n", "utf-8"))


class KeptSeed(NamedTuple):
    """An extra seed whose videos the study kept (``seeds/<seed>/``)."""

    seed: int
    events: list[Interval]  # the true touches, (t_start, t_end), s
    hidden: Hidden | None  # per condition, what hides each gap (None: before the column)
    gaps: Gaps | None  # per condition, each touch's closing gap (None: before the column)


def kept_seeds(study: Path, conditions: Sequence[str]) -> list[KeptSeed]:
    """Every extra seed the study kept, with its true touches and what the simulator saw.

    Raises
    ------
    ValueError
        One line naming a kept seed's folder that lacks a video of one of ``conditions`` or has
        a malformed truth.json.
    """
    out: list[KeptSeed] = []
    root = study / SEEDS_DIR
    if not root.is_dir():
        return out
    for folder in sorted(root.iterdir(), key=lambda p: p.name):
        if not folder.is_dir():
            continue
        try:
            doc = json.loads((folder / TRUTH_JSON).read_text("utf-8"))
            events = [(float(a), float(b)) for a, b in doc["true_events"]]
            seed = int(doc["seed"])
            hidden = doc.get("gap_hidden_by")
            gaps = doc.get("closing_gap")
        except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{folder}: no valid {TRUTH_JSON}: {exc}") from None
        missing = [c for c in conditions if not (folder / f"{c}.mp4").is_file()]
        if missing:
            raise ValueError(f"{folder}: missing video(s) {', '.join(missing)}")
        out.append(KeptSeed(seed, events, hidden, gaps))
    return out


# ------------------------------------------------------------------------------ the document
def hypothesis_dict(
    manifest: Manifest,
    observer: dict[str, Any],
    records: Sequence[TouchObservation],
    trajectory: str,
    extra: Sequence[dict[str, Any]],
    frame_s: float,
    recounted: bool = True,
    skipped: Sequence[int] = (),
) -> dict[str, Any]:
    """``hypothesis.json``: the closing gap, the observer's counting error, image-space views.

    Per condition (the manifest's, in order), on the most difficult study trajectory (named
    ``trajectory``) and over the extra seeds' rows (:func:`seed_rows`): first the closing gap
    (``resolved``, in sight from either eye and the left one; over the extra seeds with
    seed-level bootstrap 95 % intervals, :mod:`endocam.study.visibility`), then the observer;
    precision and recall pair seen with true touches overlapping within ``frame_s`` (one
    frame, s). ``recounted`` is False when the extra rows were counted by an earlier observer
    (their videos were not kept); ``skipped``: extra seeds left out (no legible path).
    """
    counted = {v["id"]: v["counted_touches"] for v in observer["videos"]}
    events = {v["id"]: v["events"] for v in observer["videos"]}
    study: dict[str, Any] = {}
    for c in manifest.conditions:
        video = manifest.most_difficult(c)
        rs = [r for r in records if r.video_id == video.id]
        seen = [(e["t_start"], e["t_end"]) for e in events[video.id]]
        match = match_events(seen, [(r.t_start_s, r.t_end_s) for r in rs], frame_s)
        study[c] = {
            "video": video.id,
            "resolved_share": known_share([r.resolved for r in rs]),
            "gap_in_sight_either_share": known_share([r.gap_in_sight_either for r in rs]),
            "median_gap_px": finite_median([r.gap_px for r in rs]),
            "true_touches": video.true_touches,
            "counted_touches": counted[video.id],
            "abs_error": abs(counted[video.id] - video.true_touches),
            "precision": match.precision,
            "recall": match.recall,
            "median_gap_before_px": finite_median([r.gap_before_px for r in rs]),
            "closes_visibly_share": known_share([r.closes_visibly for r in rs]),
            "gap_in_sight_share": known_share([r.gap_in_sight for r in rs]),
            "gap_hidden_by": hidden_counts(rs),
        }
    seeds: dict[str, Any] = {}
    for c in manifest.conditions:
        rows = [r for r in extra if r["condition"] == c]
        if not rows:
            continue
        errors = [abs(r["counted_touches"] - r["true_touches"]) for r in rows]
        tp = sum(r["matched_touches"] for r in rows)
        n_seen = sum(r["counted_touches"] for r in rows)
        n_true = sum(r["true_touches"] for r in rows)
        gaps = [g for r in rows for g in r["gap_before_px"]]
        closes = [f for r in rows for f in r["closes_visibly"]]
        seeds[c] = {
            "videos": len(rows),
            **_gap_shares(rows),
            "mean_abs_error": float(np.mean(errors)),
            "sd_abs_error": float(np.std(errors, ddof=1)) if len(errors) > 1 else None,
            "precision": tp / n_seen if n_seen else 1.0,
            "recall": tp / n_true if n_true else 1.0,
            "median_gap_before_px": finite_median(gaps),
            "closes_visibly_share": known_share(closes),
            "gap_in_sight_share": known_share(
                [f for r in rows for f in (r.get("gap_in_sight") or [None] * r["true_touches"])]
            ),
            "gap_hidden_by": None
            if any(r.get("gap_hidden_by") is None for r in rows)
            else count_hiders([h for r in rows for h in r["gap_hidden_by"] if h is not None]),
        }
    return {
        "trajectory": trajectory,
        "study": study,
        "extra_seeds": {
            "n": len({r["seed"] for r in extra}),
            "seeds": sorted({r["seed"] for r in extra}),
            "recounted": recounted,
            "skipped": list(skipped),
            "conditions": seeds,
            "videos": list(extra),
        },
    }


def _gap_shares(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The closing-gap summary of one condition's extra-seed rows (None where not recorded)."""
    if any(r.get("closing_gap") is None for r in rows):
        return {k: None for k in ("resolved", "gap_in_sight_either", "gap_in_sight_left")} | {
            "median_gap_px": None,
            "hidden_from_both": None,
        }
    gaps = [g for r in rows for g in r["closing_gap"]]

    def share(key: str) -> dict[str, Any] | None:
        value = share_ci({r["seed"]: [bool(g[key]) for g in r["closing_gap"]] for r in rows})
        return None if value is None else value.model_dump(mode="json")

    return {
        "resolved": share("resolved"),
        "gap_in_sight_either": share("in_sight_either"),
        "gap_in_sight_left": share("in_sight_left"),
        "median_gap_px": finite_median([g["gap_px"] for g in gaps if g["gap_px"] is not None]),
        "hidden_from_both": count_hiders(
            [hider_kind(g["hidden_by_left"]) for g in gaps if not g["in_sight_either"]]
        ),
    }


# ------------------------------------------------------------------------------ re-analysis
def _write_text(path: Path, text: str) -> None:
    write_atomic(path, lambda p: p.write_text(text, "utf-8"))


def recount_study(
    folder: str | Path,
    workers: int = DEFAULT_WORKERS,
    progress: Callable[[int], object] | None = None,
) -> dict[str, Any] | None:
    """Count every video of a study folder again with the current observer (module docstring).

    Always rewrites ``observer.json`` and ``observer.html``. When the folder has
    ``observability.json`` (every ``study make`` writes it), also its image-space columns and
    ``observability.csv``, and ``hypothesis.json`` (extra seeds from the kept videos, else the
    earlier rows, marked ``recounted: false``). Each file is replaced atomically.

    Parameters
    ----------
    folder : str or Path
        Study folder (``manifest.json``, the videos).
    workers : int
        Processes that decode and count videos in parallel (1: in this process).
    progress : callable, optional
        Called with 1 per video (the study's and each kept seed's three) counted.

    Returns
    -------
    dict or None
        The new ``hypothesis.json``; None when the folder has no ``observability.json``.

    Raises
    ------
    ValueError
        One line for a malformed observability.json, hypothesis.json or kept seed.
    """
    root = Path(folder)
    manifest = load_manifest(root)
    keys = keys_for_study(root)
    has_records = (root / OBSERVABILITY_JSON).is_file()
    if has_records:
        replay_gap_in_sight(root, workers)
    conditions = manifest.conditions
    seeds = kept_seeds(root, conditions) if has_records else []
    observations: dict[str, VideoObservation] = {}
    extra_rows: dict[int, list[dict[str, Any]]] = {}
    tick = progress or (lambda _n: None)
    with executor(workers, "spawn") as pool:
        video_jobs = {
            pool.submit(observe_video, root / v.file, keys): v.id for v in manifest.videos
        }
        seed_jobs = {
            pool.submit(
                seed_rows,
                root / SEEDS_DIR / str(k.seed),
                k.seed,
                k.events,
                keys,
                conditions,
                k.hidden,
                k.gaps,
            ): k.seed
            for k in seeds
        }
        for fut in concurrent.futures.as_completed(video_jobs):
            observations[video_jobs[fut]] = fut.result()
            tick(1)
        for job in concurrent.futures.as_completed(seed_jobs):
            extra_rows[seed_jobs[job]] = job.result()
            tick(len(conditions))
    observer = observer_document(manifest, observations)
    _write_text(root / OBSERVER_JSON, json.dumps(observer, indent=2) + "\n")
    _write_text(root / OBSERVER_HTML, observer_html(manifest, observations))
    if not has_records:
        return None
    earlier = load_records(root / OBSERVABILITY_JSON)
    records = [with_gaps(r, observations[r.video_id]) for r in earlier]
    summary = summarize(records, conditions=conditions)
    _write_text(root / OBSERVABILITY_JSON, observability_json(summary, records))
    _write_text(root / OBSERVABILITY_CSV, observability_csv(records))
    recounted = True
    if seeds:
        extra = [row for k in seeds for row in extra_rows[k.seed]]
    else:
        extra = _earlier_rows(root / HYPOTHESIS_JSON)
        recounted = not extra
    hardest = manifest.most_difficult(manifest.conditions[0])
    fps = next(iter(observations.values())).fps if observations else 30.0
    skipped = _earlier_skipped(root / HYPOTHESIS_JSON)
    doc = hypothesis_dict(
        manifest, observer, records, hardest.trajectory, extra, 1.0 / fps, recounted, skipped
    )
    _write_text(root / HYPOTHESIS_JSON, json.dumps(doc, indent=2) + "\n")
    return doc


def _earlier_rows(path: Path) -> list[dict[str, Any]]:
    """The extra-seed rows of an existing ``hypothesis.json`` (none if there is no file)."""
    if not path.is_file():
        return []
    try:
        return list(json.loads(path.read_text("utf-8"))["extra_seeds"]["videos"])
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"cannot read the extra seeds of {path}: {exc}") from None


def _earlier_skipped(path: Path) -> list[int]:
    """The skipped extra seeds of an existing ``hypothesis.json`` (none if not recorded)."""
    try:
        return list(json.loads(path.read_text("utf-8"))["extra_seeds"].get("skipped", []))
    except (OSError, json.JSONDecodeError, KeyError, TypeError, AttributeError):
        return []


# ------------------------------------------------------------------------------ replay
def replay_gap_in_sight(study: Path, workers: int = DEFAULT_WORKERS) -> int:
    """Fill in the closing-gap columns (``gap_in_sight`` ... ``resolved``) where they are missing.

    Folders made before the columns existed: the episodes are deterministic, so each is run
    again (no rendering) from its logged config (``logs/<id>/scene.json``), its condition's
    policy and its trajectory's noise seed (``design.json``; a kept seed's ``truth.json``), and
    the columns are computed as ``study make`` computes them
    (:func:`endocam.study.visibility.closing_gap`). ``observability.json`` and the kept
    seeds' ``truth.json`` are rewritten atomically.

    Returns
    -------
    int
        Episodes replayed (0: nothing was missing).

    Raises
    ------
    ValueError
        One line if a replayed episode's touches differ from the recorded ones (a folder made
        by other code or another config).
    """
    records = load_records(study / OBSERVABILITY_JSON)
    videos = sorted(
        {
            r.video_id
            for r in records
            if r.resolved is None
            or r.gap_in_sight is None
            or not (r.gap_in_sight or r.gap_hidden_by)
        }
    )
    manifest = load_manifest(study)
    conditions = list(manifest.conditions)
    seeds = [(k.seed, k.events) for k in kept_seeds(study, conditions) if k.gaps is None]
    if not videos and not seeds:
        return 0
    design = json.loads((study / "design.json").read_text("utf-8"))
    policies = condition_policies(design, conditions)
    by_id = {v.id: v for v in manifest.videos}
    paths = {t["name"]: t for t in design["trajectories"]}

    def logged_config(video_id: str) -> dict[str, Any]:
        scene = json.loads((study / "logs" / video_id / "scene.json").read_text("utf-8"))
        return dict(scene["config"])

    jobs: dict[concurrent.futures.Future[Any], tuple[str, Any]] = {}
    with executor(workers, "spawn") as pool:
        for vid in videos:
            v = by_id[vid]
            path = paths[v.trajectory]
            starts = [r.t_start_s for r in records if r.video_id == vid]
            fut = pool.submit(
                _replay,
                logged_config(vid),
                path["control_points"],
                path["noise_seed"],
                {v.condition: policies[v.condition]},
                starts,
            )
            jobs[fut] = ("video", vid)
        if seeds:
            hardest = manifest.most_difficult(manifest.conditions[0])
            cfg, cp = logged_config(hardest.id), paths[hardest.trajectory]["control_points"]
            for s, ev in seeds:
                fut = pool.submit(_replay, cfg, cp, s, policies, [a for a, _ in ev])
                jobs[fut] = ("seed", s)
        results = {key: fut.result() for fut, key in jobs.items()}
    for (kind, key), gaps in results.items():
        if kind == "seed":
            folder = study / SEEDS_DIR / str(key)
            doc = json.loads((folder / TRUTH_JSON).read_text("utf-8"))
            seed, fps, events = int(doc["seed"]), float(doc["fps"]), doc["true_events"]
            hidden = {c: [g["hidden_by_left"] for g in rows] for c, rows in gaps.items()}
            write_truth(folder, seed, fps, events, hidden, keep=doc, gaps=gaps)
    filled = {vid: iter(results[("video", vid)][by_id[vid].condition]) for vid in videos}

    def refilled(r: TouchObservation) -> TouchObservation:
        if r.video_id not in filled:
            return r
        return dataclasses.replace(r, **row_columns(next(filled[r.video_id])))

    records = [refilled(r) for r in records]
    summary = summarize(records, conditions=conditions)
    _write_text(study / OBSERVABILITY_JSON, observability_json(summary, records))
    _write_text(study / OBSERVABILITY_CSV, observability_csv(records))
    return len(videos) + len(conditions) * len(seeds)


def _replay(
    config: dict[str, Any],
    control_points: int,
    seed: int,
    policies: Mapping[str, str],
    t_starts: Sequence[float],
) -> Gaps:
    """Run one trajectory's episodes again; per condition, each touch's closing gap (a row).

    ``policies``: condition → the policy that filmed it (:func:`condition_policies`).
    """
    from endocam.config import ExperimentConfig
    from endocam.runner.episode import EpisodeSpec, run_episode
    from endocam.runner.experiments import ground_truth
    from endocam.sim.render import WireChaserScene
    from endocam.study.visibility import closing_gap, gap_row
    from endocam.task.trajectory import TrajectoryKind

    cfg = ExperimentConfig.model_validate(config)
    kind = TrajectoryKind.NOISY
    touches = ground_truth(cfg, kind, control_points, seed)
    if [e.t_start for e in touches.events] != list(t_starts):
        raise ValueError(
            f"replaying noise seed {seed} gives other touches than the study recorded: "
            "the folder was made by other code or another config"
        )
    out: Gaps = {}
    for c, policy in policies.items():
        spec = EpisodeSpec(policy, kind, control_points, seed)
        result = run_episode(cfg, spec, touches=touches)
        with WireChaserScene(cfg.task, result.camera) as scene:
            out[c] = [gap_row(closing_gap(result, scene, t)) for t in t_starts]
    return out

"""The closed loop on stereo perception, one thing changed at a time, on the first seconds.

Runs the ``endocam`` tracker on one of the paper's paths (``--path``, e.g. ``ideal-36``) on
``truth`` and on ``stereo`` with each ``--variant`` (``name:field=value,...`` over the
``perception`` section, or dotted paths, e.g. ``nofilter:filter_alpha=1,filter_beta=0`` or
``nopredict:controller.tracker.predict=false``), for the episode's
first ``--seconds`` s (the world cut there; the ring moves as in the full episode), and prints
per run the means over the steps (image error px, 3D error of the left eye mm, orientation
error deg, ring out of view %) and the steps held by the gate and as stale. Stereo episodes
render both eyes at 30 Hz: ~5 s of CPU per simulated second.

  MUJOCO_GL=egl OMP_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/perception_loop.py \
      --path ideal-36 --seconds 20 --variant base: --variant hold:resample=false

A variant's ``oracle=centre``, ``oracle=normal`` or ``oracle=both`` replaces that part of every
estimate the estimator delivers by the truth at the frame's capture (the ring pose at that step
in the camera at that step), keeping everything else (the frames the estimator lost, the track
filter, the delays, the resampling): what the loop would do with a perfect centre, normal or
both on the same capture schedule — the share of the error each part of the estimate causes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import replace
from typing import Any

import numpy as np

import endocam.runner.episode as episode_module
import endocam.runner.ring_source as ring_source_module
from endocam.config import ExperimentConfig
from endocam.control.checks import GATE_REASON
from endocam.control.gate import STALE_REASON
from endocam.robot.camera_arm import ArmKind
from endocam.runner.episode import EpisodeResult, run_episode
from endocam.runner.experiments import paper_paths

os.environ.setdefault("MUJOCO_GL", "egl")


def cut_world(seconds: float) -> Any:
    """``episode_world`` with its rows after ``seconds`` s dropped (a shorter run, same ring)."""
    full = episode_module.episode_world

    def cut(config: ExperimentConfig, trajectory: Any) -> Any:
        w = full(config, trajectory)
        n = min(w.n, round(seconds * config.episode.control_rate) + 1)
        return replace(
            w,
            t=w.t[:n],
            T_world_ring=w.T_world_ring[:n],
            t_ring=w.t_ring[:n],
            T_world_ring_sensed=w.T_world_ring_sensed[:n],
            p_world_tips=w.p_world_tips[:n],
        )

    return cut


def summary(result: EpisodeResult) -> dict[str, float]:
    """Means over the steps: px, mm, deg, %; steps held by the gate and as stale."""
    reason = np.asarray(result.log.reason)
    return {
        "image_error_px": float(np.mean(result.image_error_saturated)),
        "center_error_mm": float(np.mean(result.center_error)) * 1e3,
        "orientation_error_deg": math.degrees(float(np.mean(result.orientation_error))),
        "out_of_view_pct": 100.0 * float(np.mean(result.ring_out_of_view)),
        "gate_refused": int(np.count_nonzero(reason == GATE_REASON)),
        "stale": int(np.count_nonzero(reason == STALE_REASON)),
        "lost_tracking_pct": 100.0 * float(np.mean(result.log.state == "lost_tracking")),
    }


ORACLES = ("centre", "normal", "both")


def with_oracle(part: str | None) -> None:
    """Make the stereo source deliver the truth's ``part`` of each estimate (None: undo)."""
    estimate = ring_source_module.estimate_ring_detail
    capture = ring_source_module.StereoSource._capture
    real_estimate = getattr(estimate, "real", estimate)
    real_capture = getattr(capture, "real", capture)
    if part is None:
        ring_source_module.estimate_ring_detail = real_estimate
        ring_source_module.StereoSource._capture = real_capture  # type: ignore[method-assign]
        return
    truth: dict[str, np.ndarray] = {}

    def oracle_capture(self: Any, k: int, T_world_cam: np.ndarray, q: np.ndarray) -> None:
        truth["T_cam_ring"] = np.linalg.inv(T_world_cam) @ self.world.T_world_ring[k]
        real_capture(self, k, T_world_cam, q)

    def oracle_estimate(*args: Any, **kwargs: Any) -> Any:
        out = real_estimate(*args, **kwargs)
        if out.estimate is None:
            return out
        T = truth["T_cam_ring"]
        p, n = out.estimate.p_cam_ring, out.estimate.n_cam
        n_true = T[:3, 2] if float(T[:3, 2] @ T[:3, 3]) < 0.0 else -T[:3, 2]  # towards the eye
        if part in ("centre", "both"):
            p = T[:3, 3].copy()
        if part in ("normal", "both"):
            n = n_true.copy()
        return replace(out, estimate=replace(out.estimate, p_cam_ring=p, n_cam=n))

    oracle_estimate.real = real_estimate  # type: ignore[attr-defined]
    oracle_capture.real = real_capture  # type: ignore[attr-defined]
    ring_source_module.estimate_ring_detail = oracle_estimate
    ring_source_module.StereoSource._capture = oracle_capture  # type: ignore[method-assign]


def parse_variant(text: str) -> tuple[str, dict[str, Any]]:
    """``name:field=value,...`` → (name, the perception fields, JSON values)."""
    name, _, rest = text.partition(":")
    fields: dict[str, Any] = {}
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition("=")
        fields[key] = json.loads(value)
    return name, fields


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--path", default="ideal-36")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--arm", default="free", choices=["free", "psm"])
    ap.add_argument("--variant", action="append", default=[])
    ap.add_argument("--truth", action="store_true", help="also run on truth")
    ap.add_argument("--json", default=None)
    ap.add_argument("--npz", default=None, help="folder: per-step arrays of each run")
    args = ap.parse_args()
    paths = {p.name: p for p in paper_paths()}
    if args.path not in paths:
        print(f"--path: unknown {args.path!r}; choose from {sorted(paths)}", file=sys.stderr)
        return 2
    path = paths[args.path]
    episode_module.episode_world = cut_world(args.seconds)  # type: ignore[assignment]
    base = path.config(ExperimentConfig())
    base = base.model_copy(
        update={"episode": base.episode.model_copy(update={"arm": ArmKind(args.arm)})}
    )
    runs: list[tuple[str, ExperimentConfig, str | None]] = []
    if args.truth:
        runs.append(("truth", base, None))
    for text in args.variant:
        name, fields = parse_variant(text)
        oracle = fields.pop("oracle", None)
        if oracle is not None and oracle not in ORACLES:
            print(f"--variant {name}: oracle must be one of {ORACLES}", file=sys.stderr)
            return 2
        data = base.model_dump()
        data["perception"] = {**data["perception"], "source": "stereo"}
        for key, value in fields.items():  # perception fields, or dotted paths from the top
            parts = key.split(".") if "." in key else ["perception", key]
            node = data
            for part in parts[:-1]:
                node = node[part]
            node[parts[-1]] = value
        config = ExperimentConfig.model_validate(data)
        runs.append((name, config, oracle))
    out = {}
    for name, config, oracle in runs:
        t0, c0 = time.perf_counter(), time.process_time()
        with_oracle(oracle)
        result = run_episode(config, path.spec("endocam"))
        with_oracle(None)
        row = summary(result)
        row["cpu_s"] = time.process_time() - c0
        row["wall_s"] = time.perf_counter() - t0
        out[name] = row
        if args.npz:
            os.makedirs(args.npz, exist_ok=True)
            est = result.log.estimates
            np.savez(
                os.path.join(args.npz, f"{args.path}-{args.arm}-{name}.npz"),
                t=result.log.t,
                image_error_px=result.image_error_saturated,
                center_error_m=result.center_error,
                orientation_error_rad=result.orientation_error,
                state=result.log.state,
                reason=np.asarray(result.log.reason),
                T_world_ring=result.log.T_world_ring,
                T_world_cam=result.log.T_world_cam,
                T_world_ring_seen=result.log.T_world_ring_sensed
                if est is None
                else est.T_world_ring_seen,
                t_ring_seen=result.log.t if est is None else est.t_ring_seen,
                est_t_capture=np.zeros(0) if est is None else est.t_capture,
                est_p=np.zeros(0) if est is None else est.p_world,
                est_n=np.zeros(0) if est is None else est.n_world,
                frame_steps=np.zeros(0) if est is None else est.frame_steps,
                frame_status=np.zeros(0) if est is None else est.frame_status,
            )
        cells = " ".join(f"{k}={v:.3g}" for k, v in row.items())
        print(f"{args.path} {args.arm} {args.seconds:g}s {name}: {cells}", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Coverage of the 95 % intervals of the SD across assessors and of the SD ratio (issue 28).

``study analyze`` gives, per condition, the SD of the assessment error across assessors and, for
the last condition against a reference, the ratio of the two SDs, each with a 95 % bootstrap
interval that resamples the assessors (:func:`endocam.study.agreement.sd_comparisons`). This
script measures how often those intervals hold the true value, for the analysis's own function
(round 12: Bonett's interval for each SD, ``agreement.bonett_sd_interval``; the percentile
bootstrap of the ratio, resampling assessors as pairs) and, beside it, for BCa bootstraps
(``scipy.stats.bootstrap``, the same resample count) of each SD and of the ratio, and for the
percentile bootstrap of each SD the analysis used before round 12 (``effects.resample_indices``,
``effects.percentile_ci``).

Two models of a reference and a last condition's errors (touches) of the same assessors:

- ``discrete``: the simulated assessors of ``study simulate``'s preset with an effect
  (``endocam.study.simulate``): report ``clip(round(t + b + s ε), 0, 99)``, error ``|r − t|``;
  reference t = 8, b = −1, s = 1.5; last t = 9, b = −0.75, s = 1.05; independent ε. The true SDs
  come from ``simulate.error_moments`` (exact), the true ratio is theirs.
- ``gamma``: ``study power``'s model from the paper's figures (``power.paper_model()``, gamma
  marginals joined by a Gaussian copula, ρ = 0.5, SD ratio 0.69 of centring to orientation),
  drawn by ``power.draw_errors`` (continuous); the true SDs and ratio are the model's.

Each (model, N) cell runs R replications seeded ``default_rng([seed, N, r])``; the Monte Carlo
SE of a coverage c is ``sqrt(c (1 − c) / R)``. Run::

    OMP_NUM_THREADS=1 PYTHONPATH=src nice -n 5 .venv/bin/python bench/agreement_coverage.py \\
        --replications 2000
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from endocam.study.agreement import sd_comparisons
from endocam.study.effects import BOOTSTRAP_RESAMPLES, percentile_ci, resample_indices
from endocam.study.manifest import MAX_TOUCHES
from endocam.study.power import draw_errors, paper_model
from endocam.study.simulate import (
    EFFECT_BIAS,
    EFFECT_NOISE_SD,
    REFERENCE_BIAS,
    REFERENCE_NOISE_SD,
    error_moments,
)

SIZES = (15, 30, 60)  # assessors per study
TRUE_TOUCHES = (8, 9)  # the tiny study's most difficult centring and orientation videos
KEYS = ("sd ref", "sd last", "sd ratio")
Draw = Callable[[np.random.Generator, int], NDArray[np.float64]]  # → (n, 2): ref, last


def discrete_model() -> tuple[Draw, dict[str, float]]:
    """The preset's rounded reports: a draw of (n, 2) errors and the true values."""
    params = (
        (TRUE_TOUCHES[0], REFERENCE_BIAS, REFERENCE_NOISE_SD),
        (TRUE_TOUCHES[1], EFFECT_BIAS, EFFECT_NOISE_SD),
    )

    def draw(rng: np.random.Generator, n: int) -> NDArray[np.float64]:
        cols = []
        for t, b, s in params:
            r = np.clip(np.rint(t + b + s * rng.standard_normal(n)), 0, MAX_TOUCHES)
            cols.append(np.abs(r - t))
        return np.column_stack(cols)

    sd_ref, sd_last = (error_moments(t, b, s)[1] for t, b, s in params)
    return draw, {"sd ref": sd_ref, "sd last": sd_last, "sd ratio": sd_last / sd_ref}


def gamma_model() -> tuple[Draw, dict[str, float]]:
    """``study power``'s paper model, centring (ref) and orientation (last)."""
    model = paper_model()

    def draw(rng: np.random.Generator, n: int) -> NDArray[np.float64]:
        return draw_errors(model, n, 1, rng)[0, :, 1:]  # (n, 2): centering, orientation

    sd_ref, sd_last = model.sd_error[1], model.sd_error[2]
    return draw, {"sd ref": sd_ref, "sd last": sd_last, "sd ratio": sd_last / sd_ref}


def percentile_intervals(x: NDArray[np.float64], seed: int) -> dict[str, tuple | None]:
    """Percentile bootstraps: each SD's before round 12; the ratio's, the analysis's still."""
    idx = resample_indices(x.shape[0], BOOTSTRAP_RESAMPLES, seed)
    boot = np.std(x[idx], axis=1, ddof=1)  # (B, 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(boot[:, 0] > 0, boot[:, 1] / boot[:, 0], np.nan)
    return {
        "sd ref": percentile_ci(boot[:, 0]),
        "sd last": percentile_ci(boot[:, 1]),
        "sd ratio": percentile_ci(ratio),
    }


def analysis_intervals(x: NDArray[np.float64], seed: int) -> dict[str, tuple | None]:
    """The analysis's intervals (``agreement.sd_comparisons``: Bonett's SD, percentile ratio)."""
    sds, comp = sd_comparisons({"ref": x[:, 0], "last": x[:, 1]}, BOOTSTRAP_RESAMPLES, seed)
    return {
        "sd ref": sds["ref"].ci95,
        "sd last": sds["last"].ci95,
        "sd ratio": comp["last_vs_ref"].sd_ratio.ci95,
    }


def _sd(x: NDArray[np.float64], axis: int = -1) -> NDArray[np.float64]:
    return np.std(x, axis=axis, ddof=1)


def _ratio(
    last: NDArray[np.float64], ref: NDArray[np.float64], axis: int = -1
) -> NDArray[np.float64]:
    return _sd(last, axis) / _sd(ref, axis)


def _bca(samples: tuple, statistic: Callable, seed: int) -> tuple[float, float] | None:
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore")  # scipy's DegenerateDataWarning: NaN, handled below
        ci = stats.bootstrap(
            samples,
            statistic,
            n_resamples=BOOTSTRAP_RESAMPLES,
            method="BCa",
            paired=len(samples) > 1,
            rng=np.random.default_rng(seed),
        ).confidence_interval
    lo, hi = float(ci.low), float(ci.high)
    return (lo, hi) if np.isfinite(lo) and np.isfinite(hi) else None


def bca_intervals(x: NDArray[np.float64], seed: int) -> dict[str, tuple | None]:
    """BCa bootstrap intervals (``scipy.stats.bootstrap``) of each SD and of the paired ratio."""
    return {
        "sd ref": _bca((x[:, 0],), _sd, seed),
        "sd last": _bca((x[:, 1],), _sd, seed),
        "sd ratio": _bca((x[:, 1], x[:, 0]), _ratio, seed),
    }


METHODS = {
    "analysis": analysis_intervals,
    "bca": bca_intervals,
    "percentile": percentile_intervals,
}


def cell(draw: Draw, truth: dict[str, float], n: int, replications: int, seed: int) -> dict:
    """Coverage (and mean width) of every method's intervals over the replications."""
    hits = {m: dict.fromkeys(KEYS, 0) for m in METHODS}
    given = {m: dict.fromkeys(KEYS, 0) for m in METHODS}
    width = {m: dict.fromkeys(KEYS, 0.0) for m in METHODS}
    for r in range(replications):
        x = draw(np.random.default_rng([seed, n, r]), n)
        for method, intervals in METHODS.items():
            ci = intervals(x, r)
            for key in KEYS:
                if ci.get(key) is None:
                    continue
                lo, hi = ci[key]
                given[method][key] += 1
                hits[method][key] += int(lo <= truth[key] <= hi)
                width[method][key] += hi - lo
    out: dict = {}
    for method in METHODS:
        for key in KEYS:
            g = given[method][key]
            c = hits[method][key] / g if g else math.nan
            out[f"{method} {key}"] = {
                "coverage": c,
                "mc_se": math.sqrt(c * (1 - c) / g) if g else math.nan,
                "given": g,
                "mean_width": width[method][key] / g if g else math.nan,
            }
    return out


def _fmt(res: dict) -> str:
    if not res["given"]:
        return "–"
    return f"{res['coverage']:.3f} ± {res['mc_se']:.3f} ({res['mean_width']:.3f})"


def main(argv: list[str] | None = None) -> int:
    """Run every (model, N) cell; print a Markdown table, optionally write JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replications", type=int, default=2000, help="per cell (default 2000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args(argv)
    if args.replications < 1:
        print("agreement_coverage: --replications must be ≥ 1", file=sys.stderr)
        return 2
    results: dict = {}
    print(
        "| model | N | interval | true | analysis: coverage ± MC SE (mean width) "
        "| BCa | percentile (before round 12) |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, (draw, truth) in (("discrete", discrete_model()), ("gamma", gamma_model())):
        for n in SIZES:
            t0 = time.process_time()
            res = cell(draw, truth, n, args.replications, args.seed)
            results[f"{name} N={n}"] = res | {"cpu_s": time.process_time() - t0}
            for key in KEYS:
                cols = " | ".join(_fmt(res[f"{m} {key}"]) for m in METHODS)
                print(f"| {name} | {n} | {key} | {truth[key]:.3f} | {cols} |", flush=True)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"replications": args.replications, "seed": args.seed} | results, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

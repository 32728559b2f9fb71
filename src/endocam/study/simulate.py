r"""The simulated-assessor check: synthetic assessors with known errors through the real pipeline.

**The assessors** (:class:`AssessorModel`): in condition c an assessor reports, for a video with
``t`` true touches, :math:`r = \mathrm{clip}(\mathrm{round}(t + b_c + s_c\,\varepsilon), 0, 99)`,
:math:`\varepsilon \sim N(0, 1)` independent per assessor and video: ``bias_touches`` :math:`b_c`
(a systematic over- or under-count) and ``noise_sd_touches`` :math:`s_c` (counting noise).

**The known effects** (:func:`true_effects`): the analysed error :math:`|r - t|` on a condition's
most difficult video has an exactly computable distribution (the normal's mass on each rounded
count, the clipping included); its mean and SD, and the ratio of the last condition's SD to each
other one's, are the values the analysis must recover.

**The pipeline** (:func:`run_replication`): every replication is a fresh database behind the real
web app (:func:`endocam.study.app.create_app`, driven over its HTTP API in process with
FastAPI's test client): each assessor consents, answers demographics and practice when the study
has them, reports the player's ``ended`` event when the study requires watching, answers every
video in the order the app gives and the attention question; then the database is read back
read-only (:meth:`~endocam.study.db.StudyDB.export_rows`) and analysed by
:func:`endocam.study.analysis.analyze`, exactly as ``study analyze --db`` does.

**What is checked** (:func:`simulate`), over R seeded replications (``default_rng([seed, r])``):

- *coverage*: the share of replications whose 95 % interval holds the true value, for
  the SD across assessors per condition and each SD ratio, with its Monte Carlo SE
  :math:`\sqrt{c(1-c)/R}`;
- *rejections*: the share of replications whose primary test (:mod:`endocam.study.power`: the
  last condition against the one before it, Wilcoxon, Holm) rejects at α in the true direction,
  against the rate **predicted** by the same tests on many errors drawn directly from the model
  (no app, no database): with an effect this is the power, without one the false-positive rate
  (≤ α/2 in one direction). The two must agree within their Monte Carlo error.

**The rates in process** (:func:`rate_check`): the app replications above prove the pipeline
but cost ~50 ms each; the rejection rates need hundreds of studies. :func:`analysis_rejections`
draws R studies' errors from the same reports (:func:`model_errors`) and runs on each the
function ``study analyze`` runs on its complete cases,
:func:`endocam.study.analysis.within_subject_tests` (scipy's Wilcoxon per pair, Holm's
correction), counting rejections by a :class:`Criterion`: the primary test in the true
direction (with an effect: the power) or any pair (without one: the family-wise false-positive
rate, ≤ α by Holm). The prediction is ``study power``'s simulation (:func:`predicted_rate`: its
own batched tests, :func:`endocam.study.power.study_p_values`, on S studies drawn
independently); a correct analysis rejects binomial(R, p) times, so the two agree within
``AGREEMENT_SE`` combined SEs :math:`\sqrt{p(1-p)(1/R + 1/S)}`. An analysis that lost Holm's
adjustment or tested one-sided rejects more often and fails the check
(``tests/test_study_simulate.py`` states how likely).

The analysis runs without an outlier rule by default: the known values are those of all
assessors, and an outlier rule trims the spread it is asked to recover (``outliers`` changes it).
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable
from enum import StrEnum
from itertools import combinations
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy import stats

from endocam.study.analysis import (
    AnalysisConfig,
    AnalysisResult,
    OutlierRule,
    analyze,
    within_subject_tests,
)
from endocam.study.manifest import MAX_TOUCHES, Manifest, load_manifest
from endocam.study.power import primary_pair, study_p_values

SIMULATE_JSON, SIMULATE_MD = "simulate.json", "simulate.md"
DEFAULT_ASSESSORS = 30  # the paper's N
DEFAULT_REPLICATIONS = 100
PREDICTION_SIMULATIONS = 4000  # studies drawn directly from the model for the predicted rate
AGREEMENT_SE = 3.0  # pipeline and prediction agree within this many combined Monte Carlo SEs
REFERENCE_BIAS = -1.0  # touches, every reference condition's bias (an undercount) in the presets
REFERENCE_NOISE_SD = 1.5  # touches, every reference condition's counting noise in the presets
EFFECT_BIAS = -0.75  # touches, the last condition's bias with an effect
EFFECT_NOISE_SD = 1.05  # touches, the last condition's noise with an effect (about -30 % SD)
UNLIMITED_STARTS = 10**9  # session starts allowed per second: the synthetic ones come fast
WATCHED_WHOLE = {"kind": "ended", "media_time_s": 1.0, "watched_s": 1.0}
"""The page's ``ended`` event of a simulated assessor who watched the whole video (times in s; a
nominal 1 s video: the must-watch rule compares the two)."""
SHM_DIR = "/dev/shm"  # memory-backed folder for the replications' databases (Linux)
ADMIN_TOKEN = "simulated-assessors"  # the in-process app's admin token (never served)


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class AssessorModel(_Frozen):
    """Per condition (the study's order): counting bias and noise, touches."""

    conditions: tuple[str, ...]
    bias_touches: tuple[float, ...]
    noise_sd_touches: tuple[Annotated[float, Field(gt=0)], ...]
    n_assessors: Annotated[int, Field(ge=3)] = DEFAULT_ASSESSORS


class TrueEffects(_Frozen):
    """The known values: error mean and SD per condition, the last condition's SD ratios."""

    mean_error: dict[str, float]
    sd_error: dict[str, float]
    sd_ratio: dict[str, float]


class Criterion(StrEnum):
    """What counts as a rejection in a simulated study."""

    PRIMARY = "primary"  # the primary test (power.primary_pair) at α, in the true direction
    FAMILYWISE = "familywise"  # any pairwise test at α (Holm bounds its rate by α)


class RateCheck(_Frozen):
    """Result of :func:`rate_check`: the analysis's rejections against the predicted rate."""

    criterion: Criterion
    n_assessors: int
    replications: int
    rejections: int
    rate: float
    predicted_rate: float
    predicted_simulations: int
    mc_se: float
    tolerance: float
    agrees: bool


class Coverage(_Frozen):
    """How often an interval held the true value over the replications that gave one."""

    true_value: float
    covered: int
    replications: int
    rate: float | None
    mc_se: float | None


class SimulationResult(_Frozen):
    """Result of :func:`simulate` (``model_dump`` is ``simulate.json``)."""

    model: AssessorModel
    effects: TrueEffects
    replications: int
    seed: int
    alpha: float
    outliers: OutlierRule
    coverage: dict[str, Coverage]
    primary_test: str
    rejections: int
    rejection_rate: float
    predicted_rate: float
    predicted_simulations: int
    agrees: bool


def preset(manifest: Manifest, effect: bool, n_assessors: int = DEFAULT_ASSESSORS) -> AssessorModel:
    """Every condition alike, except, with ``effect``, the last (smaller bias and noise)."""
    k = len(manifest.conditions)
    bias = [REFERENCE_BIAS] * k
    noise = [REFERENCE_NOISE_SD] * k
    if effect:
        bias[-1], noise[-1] = EFFECT_BIAS, EFFECT_NOISE_SD
    return AssessorModel(
        conditions=manifest.conditions,
        bias_touches=tuple(bias),
        noise_sd_touches=tuple(noise),
        n_assessors=n_assessors,
    )


def error_moments(true_touches: int, bias: float, noise_sd: float) -> tuple[float, float]:
    """Exact mean and SD of :math:`|r - t|` for the model's report r of t true touches."""
    r = np.arange(MAX_TOUCHES + 1)
    upper = stats.norm.cdf((r + 0.5 - true_touches - bias) / noise_sd)
    lower = stats.norm.cdf((r - 0.5 - true_touches - bias) / noise_sd)
    upper[-1], lower[0] = 1.0, 0.0  # clipping: everything below 0 reads 0, above 99 reads 99
    p = upper - lower
    e = np.abs(r - true_touches)
    mean = float(np.sum(p * e))
    return mean, float(np.sqrt(np.sum(p * (e - mean) ** 2)))


def true_effects(model: AssessorModel, manifest: Manifest) -> TrueEffects:
    """The known values on each condition's most difficult video (the analysis's default)."""
    moments = {
        c: error_moments(manifest.most_difficult(c).true_touches, b, s)
        for c, b, s in zip(
            model.conditions, model.bias_touches, model.noise_sd_touches, strict=True
        )
    }
    *refs, last = model.conditions
    return TrueEffects(
        mean_error={c: m[0] for c, m in moments.items()},
        sd_error={c: m[1] for c, m in moments.items()},
        sd_ratio={f"{last}_vs_{r}": moments[last][1] / moments[r][1] for r in reversed(refs)},
    )


def draw_reports(
    model: AssessorModel, manifest: Manifest, rng: np.random.Generator, n: int
) -> dict[str, NDArray[np.int64]]:
    """Video id → (n,) reported touches of n assessors (the model's reports)."""
    index = {c: i for i, c in enumerate(model.conditions)}
    out = {}
    for v in manifest.videos:
        c = index[v.condition]
        noise = model.noise_sd_touches[c] * rng.standard_normal(n)
        value = np.rint(v.true_touches + model.bias_touches[c] + noise)
        out[v.id] = np.clip(value, 0, MAX_TOUCHES).astype(np.int64)
    return out


def answer_through_app(study: Path, db_path: Path, reports: dict[str, NDArray[np.int64]]) -> None:
    """Every synthetic assessor takes part through the app's HTTP API (module docstring).

    The requests go to the ASGI app in process (``httpx.ASGITransport``), one assessor after the
    other, each with its own session cookie.
    """
    import asyncio

    import httpx

    from endocam.study.app import create_app
    from endocam.study.web import RateLimit  # the study extra (starlette), imported on use

    unlimited = RateLimit(per_client=UNLIMITED_STARTS, total=UNLIMITED_STARTS, window_s=1.0)
    app = create_app(study, db_path, ADMIN_TOKEN, session_rate=unlimited)
    manifest: Manifest = app.state.manifest
    n = len(next(iter(reports.values())))

    async def assessor(a: int) -> None:
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://sim.local") as client:

            async def post(url: str, body: dict[str, Any], status: int = 201) -> Any:
                r = await client.post(url, json=body)
                if r.status_code != status:
                    raise RuntimeError(
                        f"the app refused a synthetic {url}: {r.status_code} {r.text}"
                    )
                return r.json() if status == 201 else None

            body: dict[str, Any] = {"consent": True, "participant_id": f"sim{a:04d}"}
            step = (await post("/api/session", body))["next"]
            while step["kind"] != "done":
                kind = step["kind"]
                if kind == "demographics":
                    step = (await post("/api/demographics", {}))["next"]
                    continue
                if kind == "attention":
                    body = {"answer": manifest.attention.answer}
                    step = (await post("/api/attention", body))["next"]
                    continue
                vid = "_practice" if kind == "practice" else step["video_id"]
                if manifest.must_watch:
                    await post("/api/event", WATCHED_WHOLE | {"video_id": vid}, 204)
                if kind == "practice":
                    assert manifest.practice is not None
                    body = {"reported_touches": manifest.practice.true_touches}
                    step = (await post("/api/practice", body))["next"]
                else:
                    body = {"video_id": vid, "reported_touches": int(reports[vid][a])}
                    step = (await post("/api/answer", body))["next"]

    async def everyone() -> None:
        for a in range(n):
            await assessor(a)

    asyncio.run(everyone())


def scratch_dir() -> str | None:
    """Where the replications' databases live: ``/dev/shm`` (memory) if usable, else the default.

    Every answer is committed with ``synchronous=FULL``; on a disk each commit waits for the
    disk, in memory it does not, and a replication's database is deleted at once anyway.
    """
    shm = Path(SHM_DIR)
    return str(shm) if shm.is_dir() and os.access(shm, os.W_OK) else None


def run_replication(
    study: Path,
    model: AssessorModel,
    rng: np.random.Generator,
    config: AnalysisConfig,
) -> tuple[AnalysisResult, dict[str, NDArray[np.int64]]]:
    """One replication through app, database and analysis; (its analysis, the reports sent)."""
    from endocam.study.db import StudyDB

    manifest = load_manifest(study, check_files=False)
    reports = draw_reports(model, manifest, rng, model.n_assessors)
    with tempfile.TemporaryDirectory(prefix="endocam-sim-", dir=scratch_dir()) as tmp:
        db_path = Path(tmp) / "study.db"
        answer_through_app(study, db_path, reports)
        rows = StudyDB(db_path, read_only=True).export_rows()
    return analyze(rows, manifest, config), reports


def model_errors(
    model: AssessorModel, manifest: Manifest, rng: np.random.Generator, simulations: int
) -> NDArray[np.float64]:
    """(simulations, n, k) errors |r - t| (touches) on each condition's most difficult video.

    The analysed errors of ``simulations`` studies of ``model.n_assessors`` assessors, from the
    reports :func:`draw_reports` gives (the ones the app replications send), drawn directly
    (no app, no database); conditions in the study's order.
    """
    n = model.n_assessors
    reports = draw_reports(model, manifest, rng, simulations * n)
    hardest = [manifest.most_difficult(c) for c in model.conditions]
    errors = [np.abs(reports[v.id] - v.true_touches).reshape(simulations, n) for v in hardest]
    return np.stack(errors, axis=-1).astype(np.float64)


def rejected(
    p_holm: NDArray[np.float64],
    effect: NDArray[np.float64],
    criterion: Criterion,
    primary: int,
    alpha: float,
) -> NDArray[np.bool_]:
    """(S,) whether each study rejects by ``criterion`` (:class:`Criterion`).

    p_holm, effect : (S, m) Holm-adjusted p-values and rank-biserial correlations of the m
    pairs (``combinations`` order; NaN p counts as no rejection); primary : the primary pair's
    index among them.
    """
    with np.errstate(invalid="ignore"):
        if criterion == Criterion.FAMILYWISE:
            return np.any(p_holm < alpha, axis=-1)
        return (p_holm[:, primary] < alpha) & (effect[:, primary] > 0)


def predicted_rate(
    model: AssessorModel,
    manifest: Manifest,
    config: AnalysisConfig,
    alpha: float,
    seed: int,
    criterion: Criterion = Criterion.PRIMARY,
    simulations: int = PREDICTION_SIMULATIONS,
) -> float:
    """Rejection rate by ``criterion`` that ``study power``'s simulation predicts.

    ``study power``'s own batched tests (:func:`endocam.study.power.study_p_values`) on
    ``simulations`` studies drawn directly from the model (``default_rng([seed, 2**31])``).
    """
    errors = model_errors(model, manifest, np.random.default_rng([seed, 2**31]), simulations)
    p_holm, effect, _ = study_p_values(errors, config)
    index, _ = primary_pair(model.conditions)
    return float(np.mean(rejected(p_holm, effect, criterion, index, alpha)))


def analysis_rejections(
    model: AssessorModel,
    manifest: Manifest,
    replications: int,
    seed: int,
    alpha: float,
    criterion: Criterion,
) -> int:
    """How many of ``replications`` studies drawn from the model the analysis's tests reject.

    Each study's complete-case errors (:func:`model_errors`, ``default_rng([seed, 2**32 + 1])``)
    go to :func:`endocam.study.analysis.within_subject_tests`, the function ``study analyze``
    runs on its complete cases (scipy's Wilcoxon per pair, Holm's correction), one study per
    call; the outlier rule is none (the errors are the complete cases as they are).
    """
    errors = model_errors(model, manifest, np.random.default_rng([seed, 2**32 + 1]), replications)
    index, _ = primary_pair(model.conditions)
    pairs = [f"{a}_vs_{b}" for a, b in combinations(model.conditions, 2)]
    p_holm = np.ones((replications, len(pairs)))
    effect = np.zeros((replications, len(pairs)))
    for r in range(replications):
        table = {c: errors[r, :, i] for i, c in enumerate(model.conditions)}
        tests = within_subject_tests(table, resamples=1, seed=r)  # the interval is not used
        for m, name in enumerate(pairs):
            test = tests.wilcoxon.get(name)
            if test is not None and test.p_holm is not None:
                p_holm[r, m], effect[r, m] = test.p_holm, test.rank_biserial or 0.0
    return int(np.sum(rejected(p_holm, effect, criterion, index, alpha)))


def rate_check(
    model: AssessorModel,
    manifest: Manifest,
    replications: int,
    seed: int = 0,
    alpha: float = 0.05,
    criterion: Criterion = Criterion.PRIMARY,
    simulations: int = PREDICTION_SIMULATIONS,
) -> RateCheck:
    r"""The analysis's rejection rate against ``study power``'s prediction (module docstring).

    If the analysis is right, its rejections are binomial(R, p) with p the rate the power
    simulation predicts from S studies; the two agree within ``AGREEMENT_SE`` combined Monte
    Carlo SEs, :math:`\sqrt{p(1-p)(1/R + 1/S)}`.
    """
    config = AnalysisConfig(outliers=OutlierRule.NONE)
    hits = analysis_rejections(model, manifest, replications, seed, alpha, criterion)
    predicted = predicted_rate(model, manifest, config, alpha, seed, criterion, simulations)
    variance = max(predicted * (1.0 - predicted), 1.0 / replications)
    se = math.sqrt(variance * (1.0 / replications + 1.0 / simulations))
    rate = hits / replications
    return RateCheck(
        criterion=criterion,
        n_assessors=model.n_assessors,
        replications=replications,
        rejections=hits,
        rate=rate,
        predicted_rate=predicted,
        predicted_simulations=simulations,
        mc_se=se,
        tolerance=AGREEMENT_SE * se,
        agrees=abs(rate - predicted) <= AGREEMENT_SE * se,
    )


def _coverage(true_value: float, intervals: list[tuple[float, float] | None]) -> Coverage:
    given = [ci for ci in intervals if ci is not None]
    hits = sum(1 for lo, hi in given if lo <= true_value <= hi)
    rate = hits / len(given) if given else None
    se = None if rate is None else math.sqrt(rate * (1.0 - rate) / len(given))
    return Coverage(
        true_value=true_value, covered=hits, replications=len(given), rate=rate, mc_se=se
    )


def simulate(
    study: Path,
    model: AssessorModel,
    replications: int,
    seed: int = 0,
    config: AnalysisConfig | None = None,
    alpha: float = 0.05,
    progress: Callable[[int], Any] | None = None,
) -> SimulationResult:
    """Run the check (module docstring); ``progress`` is called with 1 after each replication."""
    if replications < 1:
        raise ValueError(f"replications must be ≥ 1, got {replications}")
    config = config or AnalysisConfig(outliers=OutlierRule.NONE)
    manifest = load_manifest(study, check_files=True)
    if manifest.conditions != model.conditions:
        raise ValueError(f"model conditions {model.conditions} are not the study's")
    effects = true_effects(model, manifest)
    _, name = primary_pair(model.conditions)
    intervals: dict[str, list[tuple[float, float] | None]] = {}
    hits = 0
    for r in range(replications):
        rng = np.random.default_rng([seed, r])
        result, _ = run_replication(
            study, model, rng, config.model_copy(update={"bootstrap_seed": r})
        )
        test = result.tests.wilcoxon.get(name)
        if (
            test
            and test.p_holm is not None
            and test.p_holm < alpha
            and (test.rank_biserial or 0) > 0
        ):
            hits += 1
        a = result.assessors
        for c in model.conditions:
            ci = a.sd_across_assessors[c].ci95 if a else None
            intervals.setdefault(f"sd_error {c}", []).append(ci)
        for key in effects.sd_ratio:
            comp = a.sd_comparisons.get(key) if a else None
            intervals.setdefault(f"sd_ratio {key}", []).append(comp.sd_ratio.ci95 if comp else None)
        if progress:
            progress(1)
    truth = {f"sd_error {c}": v for c, v in effects.sd_error.items()} | {
        f"sd_ratio {k}": v for k, v in effects.sd_ratio.items()
    }
    predicted = predicted_rate(model, manifest, config, alpha, seed)
    rate = hits / replications
    se = math.sqrt(
        max(rate * (1 - rate), 1.0 / replications) / replications
        + predicted * (1 - predicted) / PREDICTION_SIMULATIONS
    )
    return SimulationResult(
        model=model,
        effects=effects,
        replications=replications,
        seed=seed,
        alpha=alpha,
        outliers=config.outliers,
        coverage={key: _coverage(truth[key], intervals[key]) for key in truth},
        primary_test=f"Wilcoxon signed-rank {name}, two-sided, Holm over all pairs",
        rejections=hits,
        rejection_rate=rate,
        predicted_rate=predicted,
        predicted_simulations=PREDICTION_SIMULATIONS,
        agrees=abs(rate - predicted) <= AGREEMENT_SE * se,
    )


def simulate_markdown(result: SimulationResult) -> str:
    """A readable summary of :func:`simulate`."""
    m = result.model
    lines = [
        "# Simulated assessors through the study pipeline",
        "",
        f"{result.replications} replications (seed {result.seed}) of {m.n_assessors} synthetic "
        "assessors answering through the app's HTTP API, read back from the database and "
        f"analysed by `study analyze` (outlier rule {result.outliers.value}).",
        "",
        "| condition | bias (touches) | noise SD (touches) | true mean error | true SD |",
        "|---|---|---|---|---|",
    ]
    for c, b, s in zip(m.conditions, m.bias_touches, m.noise_sd_touches, strict=True):
        e = result.effects
        lines.append(f"| {c} | {b:g} | {s:g} | {e.mean_error[c]:.3f} | {e.sd_error[c]:.3f} |")
    lines += ["", "| interval (95 %) | true value | coverage | MC SE |", "|---|---|---|---|"]
    for key, cov in result.coverage.items():
        rate = "–" if cov.rate is None else f"{cov.rate:.3f} ({cov.covered}/{cov.replications})"
        se = "–" if cov.mc_se is None else f"{cov.mc_se:.3f}"
        lines.append(f"| {key} | {cov.true_value:.3f} | {rate} | {se} |")
    verdict = "agree" if result.agrees else "**DISAGREE**"
    lines += [
        "",
        f"Primary test ({result.primary_test}, α = {result.alpha:g}, true direction): rejected "
        f"in {result.rejections} of {result.replications} replications "
        f"({result.rejection_rate:.3f}); predicted from the model directly "
        f"({result.predicted_simulations} studies): {result.predicted_rate:.3f}; they {verdict} "
        f"within {AGREEMENT_SE:g} Monte Carlo SEs.",
    ]
    return "\n".join(lines) + "\n"

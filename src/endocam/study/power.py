r"""Power and sample size of the study's primary test, by simulation of the analysis itself.

**The primary test** is the one ``study analyze`` runs for the study's claim: the two-sided
Wilcoxon signed-rank test of the assessment error (touches) in the **last** condition (the
proposed camera) against the condition **before it** (the nearest reference: centring in the
paper's order), Holm-adjusted over all k(k−1)/2 pairwise tests, at level α; it counts as a
rejection only in the expected direction (the reference's errors larger, rank-biserial > 0). The
Friedman test over all k conditions is reported beside it.

**The model of the assessors** (:class:`ErrorModel`): each assessor's k errors are drawn
jointly: a Gaussian copula with correlation matrix ``corr`` and gamma marginals with each
condition's mean and SD (errors are positive and right-skewed); drawn from a pilot's errors they
are rounded to whole touches, as the pilot's are. The model comes from

- a **pilot** (:func:`pilot_model`): the mean, SD and correlations of the errors of the pilot's
  assessors who passed the attention question and answered every analysed video; or
- **the paper's figures** (:func:`paper_model`) when there is no pilot: condition III's mean
  error is 25 % / 21 % below conditions II / I, its SD 31 % / 32 % below (paper Sec. V). The
  paper gives no absolute scale, spread or correlation: the SD/mean of condition II
  (``PAPER_CV``) and the correlation between an assessor's conditions (``PAPER_RHO``) are
  assumptions, stated in every output. With the defaults the paired standardized effect is
  :math:`d_z \approx 0.35` (the issue's "d = 0.3–0.4").

**The simulation** draws ``simulations`` studies of n assessors (``numpy.random.default_rng``
seeded per (seed, n)), runs the analysis's own steps on each (the per-condition outlier rule of
:func:`endocam.study.analysis.outlier_mask`, complete cases, ``scipy.stats.friedmanchisquare``,
``scipy.stats.wilcoxon`` per pair, Holm) and counts rejections; the Monte Carlo standard error
of a power p is :math:`\sqrt{p(1-p)/S}`. Holm's adjustment is applied to all simulations at once
by :func:`holm_batch` (the formula of ``statsmodels``' ``multipletests(method="holm")``, against
which it is tested: ``multipletests`` runs a full garbage collection on every call, 0.1–0.5 s,
too slow for thousands of studies; the analysis's own :func:`endocam.study.analysis.holm` calls
``multipletests``, one study at a time, so that the two stay independent and
``simulate.rate_check`` can catch a mistake in either).
The sample size is the smallest n whose simulated power reaches the target: a coarse grid, then
bisection, from ``MIN_N`` assessors up (a target already reached there is reported as such).
With ≤ 13 pairs and ties (whole touches) scipy's Wilcoxon test is an exact permutation test,
~25 ms a call; :func:`signflip_p` computes the same p-values for all studies at once.

**Closed forms, for comparison** (:func:`closed_forms`): the paired t-test's n from
``statsmodels.stats.power.TTestPower`` for :math:`d_z = (\mu_{ref} - \mu_{last}) / \sigma_{d}`,
at α and at the Bonferroni level α/m (Holm's smallest threshold), and that n times π/3, the
signed-rank test's n under normality (asymptotic relative efficiency 3/π). No closed form covers
gamma errors, outlier removal and Holm together; the simulation does.

**Attrition**: ``attrition`` is the share of recruited assessors expected to be excluded
(the paper: 3 of 30 failed the attention question); assessors to recruit =
:math:`\lceil n / (1 - \text{attrition}) \rceil`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Annotated, Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy import stats

from endocam.study.analysis import (
    MIN_TEST_N,
    AnalysisConfig,
    OutlierRule,
    assessment_errors,
    outlier_mask,
)
from endocam.study.effects import kendall_w, rank_biserial
from endocam.study.manifest import Manifest
from endocam.study.responses import ResponseRow

POWER_JSON, POWER_MD, POWER_PNG = "power.json", "power.md", "power.png"
PAPER_CONDITIONS = ("fixed", "centering", "orientation")  # the paper's conditions I, II, III
PAPER_MEAN_RATIO = {"fixed": 1.0 - 0.21, "centering": 1.0 - 0.25}  # mean(III) / mean(ref)
PAPER_SD_RATIO = {"fixed": 1.0 - 0.32, "centering": 1.0 - 0.31}  # SD(III) / SD(ref)
PAPER_CV = 0.8  # assumed SD / mean of condition II's error (the paper gives no spread)
PAPER_RHO = 0.5  # assumed correlation of one assessor's errors between conditions
PAPER_ATTRITION = 3.0 / 30.0  # the paper's share excluded (failed the attention question)
DEFAULT_ALPHA = 0.05
DEFAULT_POWER = 0.8
DEFAULT_SIMULATIONS = 2000
DEFAULT_MAX_N = 300  # assessors: the search's upper end
SMALL_TIED_N = 13  # at most this many pairs with ties: scipy's exact permutation test
MIN_N = 5  # assessors: the search's lower end
GRID_POINTS = 10  # coarse grid of n (geometric) before the bisection
MIN_PILOT = 3  # pilot assessors with complete errors needed for a model
EIG_FLOOR = 1e-6  # smallest eigenvalue kept when a pilot's correlation matrix is repaired


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class ErrorModel(_Frozen):
    """Joint distribution of one assessor's errors (touches) in the k conditions.

    ``mean_error``, ``sd_error``: (k,) per condition, touches (relative units for the paper's
    figures); ``corr``: (k, k) correlation of the copula; ``discrete``: draws rounded to whole
    touches; ``source``: where the numbers come from; ``assumptions``: what is assumed.
    """

    conditions: tuple[str, ...]
    mean_error: tuple[float, ...]
    sd_error: tuple[float, ...]
    corr: tuple[tuple[float, ...], ...]
    discrete: bool
    source: str
    n_pilot: int | None = None
    assumptions: tuple[str, ...] = ()


class PowerConfig(_Frozen):
    """Settings of :func:`sample_size`: level, target power, simulations, search, attrition."""

    alpha: Annotated[float, Field(gt=0, lt=1)] = DEFAULT_ALPHA
    power: Annotated[float, Field(gt=0, lt=1)] = DEFAULT_POWER
    simulations: Annotated[int, Field(ge=100)] = DEFAULT_SIMULATIONS
    seed: Annotated[int, Field(ge=0)] = 0
    max_n: Annotated[int, Field(ge=MIN_N)] = DEFAULT_MAX_N
    attrition: Annotated[float, Field(ge=0, lt=1)] = PAPER_ATTRITION
    outliers: OutlierRule = OutlierRule.TUKEY
    tukey_k: Annotated[float, Field(gt=0, allow_inf_nan=False)] = 1.5


class PowerPoint(_Frozen):
    """Simulated power at n assessors analysed, with its Monte Carlo standard error."""

    n: int
    power: float
    mc_se: float
    power_friedman: float | None


class PowerResult(_Frozen):
    """Result of :func:`sample_size` (``model_dump`` is the ``power.json`` document)."""

    model: ErrorModel
    config: PowerConfig
    primary_test: str
    expected_direction: str
    closed_forms: dict[str, float | None]
    curve: list[PowerPoint]
    n_required: int | None
    n_recruit: int | None
    note: str | None = None


def paper_model(cv: float = PAPER_CV, rho: float = PAPER_RHO) -> ErrorModel:
    """The paper's relative figures with an assumed spread ``cv`` and correlation ``rho``.

    Condition II's mean error is 1 (relative units); see the module docstring.
    """
    if not (math.isfinite(cv) and cv > 0):
        raise ValueError(f"cv must be > 0, got {cv}")
    if not (math.isfinite(rho) and -0.5 < rho < 1):
        raise ValueError(f"rho must be in (-0.5, 1), got {rho}")
    m_iii = PAPER_MEAN_RATIO["centering"]  # mean(II) = 1
    s_iii = PAPER_SD_RATIO["centering"] * cv
    mean = (m_iii / PAPER_MEAN_RATIO["fixed"], 1.0, m_iii)
    sd = (s_iii / PAPER_SD_RATIO["fixed"], cv, s_iii)
    corr = tuple(tuple(1.0 if i == j else rho for j in range(3)) for i in range(3))
    return ErrorModel(
        conditions=PAPER_CONDITIONS,
        mean_error=mean,
        sd_error=sd,
        corr=corr,
        discrete=False,
        source="the paper's figures (Sec. V: mean error -25 % / -21 %, SD -31 % / -32 %)",
        assumptions=(
            f"SD/mean of condition II's error = {cv:g} (assumed; the paper gives none)",
            f"correlation of an assessor's errors between conditions = {rho:g} (assumed)",
            "errors continuous, in units of condition II's mean error",
        ),
    )


def _nearest_correlation(c: NDArray[np.float64]) -> NDArray[np.float64]:
    w, v = np.linalg.eigh(c)
    fixed = v @ np.diag(np.maximum(w, EIG_FLOOR)) @ v.T
    d = np.sqrt(np.diag(fixed))
    return fixed / np.outer(d, d)


def pilot_model(
    rows: Sequence[ResponseRow], manifest: Manifest, all_videos: bool = False
) -> ErrorModel:
    """The error model of a pilot's answers (errors as ``study analyze`` computes them).

    Raises
    ------
    ValueError
        Fewer than ``MIN_PILOT`` usable assessors, or a condition whose errors do not vary.
    """
    video_ids = {
        c: [v.id for v in manifest.videos_of(c)] if all_videos else [manifest.most_difficult(c).id]
        for c in manifest.conditions
    }
    errors, _ = assessment_errors(rows, manifest, video_ids)
    if len(errors) < MIN_PILOT:
        raise ValueError(
            f"pilot: {len(errors)} assessor(s) passed the attention question with every analysed"
            f" video answered; a model needs at least {MIN_PILOT}"
        )
    table = np.array([[errors[p][c] for c in manifest.conditions] for p in sorted(errors)])
    mean, sd = table.mean(axis=0), table.std(axis=0, ddof=1)
    flat = [c for c, m, s in zip(manifest.conditions, mean, sd, strict=True) if m <= 0 or s <= 0]
    if flat:
        raise ValueError(
            f"pilot: the errors in {', '.join(flat)} do not vary (mean or SD 0): no model"
        )
    corr = _nearest_correlation(np.corrcoef(table, rowvar=False))
    return ErrorModel(
        conditions=manifest.conditions,
        mean_error=tuple(float(x) for x in mean),
        sd_error=tuple(float(x) for x in sd),
        corr=tuple(tuple(float(x) for x in r) for r in corr),
        discrete=bool(np.all(table == np.round(table))),
        source=f"pilot of {len(errors)} assessors",
        n_pilot=len(errors),
        assumptions=("errors gamma-distributed per condition, joined by a Gaussian copula",),
    )


def draw_errors(
    model: ErrorModel, n: int, simulations: int, rng: np.random.Generator
) -> NDArray[np.float64]:
    """(simulations, n, k) errors of n assessors per simulated study (module docstring)."""
    k = len(model.conditions)
    z = rng.multivariate_normal(np.zeros(k), np.array(model.corr), size=(simulations, n))
    mean, sd = np.array(model.mean_error), np.array(model.sd_error)
    x = stats.gamma.ppf(stats.norm.cdf(z), (mean / sd) ** 2, scale=sd**2 / mean)
    return np.round(x) if model.discrete else x


def holm_batch(p: NDArray[np.float64]) -> NDArray[np.float64]:
    r"""Holm-adjusted p-values along the last axis (as ``multipletests(method="holm")``).

    .. math:: \tilde p_{(i)} = \min\bigl(1, \max_{j \le i} (m - j + 1)\, p_{(j)}\bigr)

    p : (..., m) raw p-values in [0, 1]. Returns (..., m), the input order.
    """
    p = np.asarray(p, dtype=np.float64)
    m = p.shape[-1]
    order = np.argsort(p, axis=-1, kind="stable")
    ranked = np.take_along_axis(p, order, axis=-1) * np.arange(m, 0, -1)
    adjusted = np.minimum(1.0, np.maximum.accumulate(ranked, axis=-1))
    out = np.empty_like(adjusted)
    np.put_along_axis(out, order, adjusted, axis=-1)
    return out


def wilcoxon_batch(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Two-sided ``scipy.stats.wilcoxon(a[r], b[r]).pvalue`` for every row r, batched.

    scipy picks its method (exact, permutation, asymptotic) once per call from the ties and
    zeros of all the data it is given; the rows are therefore batched by that choice, so each
    p-value is the one a call on its row alone gives (the analysis's call).

    a, b : (S, n) paired values. Returns (S,) p-values (NaN where every difference is 0).
    """
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    srt = np.sort(np.abs(d), axis=-1)
    tied = np.any(srt[:, 1:] == srt[:, :-1], axis=-1) | np.any(d == 0.0, axis=-1)
    p = np.full(d.shape[0], np.nan)
    for group in (np.flatnonzero(~tied), np.flatnonzero(tied)):
        if group.size == 0:
            continue
        if d.shape[1] <= SMALL_TIED_N and tied[group[0]]:  # scipy: exact permutation test
            p[group] = signflip_p(d[group])
        else:
            p[group] = stats.wilcoxon(d[group], axis=-1).pvalue
    return p


def signflip_p(d: NDArray[np.float64]) -> NDArray[np.float64]:
    r"""Two-sided exact sign-flip p-value of the signed-rank statistic, per row.

    What ``scipy.stats.wilcoxon`` computes for ≤ 13 pairs with ties or zeros (an exact
    ``permutation_test`` over all :math:`2^n` sign patterns): :math:`T = \sum r_i [d_i > 0]`
    with ``r`` the average ranks of the non-zero :math:`|d_i|`,
    :math:`p = \min(1, 2 \min(P(T^* \le T + \gamma), P(T^* \ge T - \gamma)))`,
    :math:`\gamma = 100\,\epsilon\,|T|` (scipy's tolerance for equal values).

    d : (S, n) paired differences, n ≤ ``SMALL_TIED_N``. Returns (S,) p-values.
    """
    n = d.shape[1]
    ranks = stats.rankdata(np.where(d == 0.0, np.inf, np.abs(d)), axis=-1)
    ranks = np.where(d == 0.0, 0.0, ranks)
    observed = np.sum(np.where(d > 0.0, ranks, 0.0), axis=-1)  # (S,)
    signs = (np.arange(2**n)[:, None] >> np.arange(n)) & 1  # (2^n, n): every pattern once
    null = ranks @ signs.T.astype(np.float64)  # (S, 2^n)
    gamma = np.abs(100.0 * np.finfo(np.float64).eps * observed)[:, None]
    less = np.mean(null <= observed[:, None] + gamma, axis=-1)
    greater = np.mean(null >= observed[:, None] - gamma, axis=-1)
    return np.clip(2.0 * np.minimum(less, greater), 0.0, 1.0)


def study_p_values(
    errors: NDArray[np.float64], config: AnalysisConfig
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The analysis's tests on simulated studies.

    Parameters
    ----------
    errors : (S, n, k) float array
        S studies of n assessors' errors in k conditions (the study's order), touches.
    config : AnalysisConfig
        Its outlier rule and Tukey k are applied per condition, as ``analyze`` does.

    Returns
    -------
    p_holm : (S, m) Holm-adjusted Wilcoxon p-values, pairs (i < j) in ``combinations`` order
        (NaN-free: an undefined test counts as p = 1, as in the analysis).
    rank_biserial : (S, m) each pair's rank-biserial correlation (> 0: the first's errors larger).
    p_friedman : (S,) Friedman p-values (NaN with k < 3 or too few complete cases).
    """
    s, n, k = errors.shape
    pairs = [(i, j) for i in range(k) for j in range(i + 1, k)]
    p_raw = np.ones((s, len(pairs)))
    effect = np.full((s, len(pairs)), np.nan)
    p_friedman = np.full(s, np.nan)
    keep = np.ones((s, n), dtype=bool)
    for index in range(s):
        for c in range(k):
            out, _ = outlier_mask(
                errors[index, :, c], config.outliers, config.tukey_k, config.z_threshold
            )
            keep[index] &= ~out
    kept = keep.sum(axis=1)
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        for size in np.unique(kept[kept >= MIN_TEST_N]):  # studies with as many complete cases
            rows = np.flatnonzero(kept == size)
            x = errors[rows][keep[rows]].reshape(rows.size, size, k)  # (S', size, k)
            if k >= 3:  # Friedman's tie-corrected chi-square is n (k - 1) W
                chi2 = kendall_w(x) * size * (k - 1)
                p_friedman[rows] = stats.chi2.sf(chi2, k - 1)
            for m, (i, j) in enumerate(pairs):
                p = wilcoxon_batch(x[..., i], x[..., j])
                p_raw[rows, m] = np.where(np.isfinite(p), p, 1.0)
                effect[rows, m] = rank_biserial(x[..., i], x[..., j])
    return holm_batch(p_raw), effect, p_friedman


def primary_pair(conditions: Sequence[str]) -> tuple[int, str]:
    """Index (among the pairs) and name of the primary comparison: the last two conditions."""
    k = len(conditions)
    pairs = [(i, j) for i in range(k) for j in range(i + 1, k)]
    index = pairs.index((k - 2, k - 1))
    return index, f"{conditions[k - 2]}_vs_{conditions[k - 1]}"


def simulate_power(model: ErrorModel, n: int, config: PowerConfig) -> PowerPoint:
    """Simulated power of the primary test (and of Friedman's) with n assessors analysed."""
    rng = np.random.default_rng([config.seed, n])
    errors = draw_errors(model, n, config.simulations, rng)
    analysis = AnalysisConfig(outliers=config.outliers, tukey_k=config.tukey_k)
    p_holm, effect, p_friedman = study_p_values(errors, analysis)
    index, _ = primary_pair(model.conditions)
    sign = np.sign(model.mean_error[-2] - model.mean_error[-1]) or 1.0
    hits = (p_holm[:, index] < config.alpha) & (np.sign(effect[:, index]) == sign)
    power = float(hits.mean())
    friedman = None if len(model.conditions) < 3 else float(np.mean(p_friedman < config.alpha))
    se = math.sqrt(power * (1.0 - power) / config.simulations)
    return PowerPoint(n=n, power=power, mc_se=se, power_friedman=friedman)


def closed_forms(model: ErrorModel, alpha: float, power: float) -> dict[str, float | None]:
    """Paired-t sample sizes for the primary comparison (module docstring); None if no effect."""
    from statsmodels.stats.power import TTestPower

    s_ref, s_new = model.sd_error[-2], model.sd_error[-1]
    rho = model.corr[-2][-1]
    sd_diff = math.sqrt(s_ref**2 + s_new**2 - 2.0 * rho * s_ref * s_new)
    dz = (model.mean_error[-2] - model.mean_error[-1]) / sd_diff
    k = len(model.conditions)
    m = k * (k - 1) // 2
    out: dict[str, float | None] = {"d_z": dz}
    if abs(dz) < 1e-9:
        return out | {"n_paired_t": None, "n_paired_t_bonferroni": None, "n_wilcoxon_are": None}
    solver = TTestPower()
    n_t = float(solver.solve_power(effect_size=abs(dz), alpha=alpha, power=power))
    n_b = float(solver.solve_power(effect_size=abs(dz), alpha=alpha / m, power=power))
    return out | {
        "n_paired_t": n_t,
        "n_paired_t_bonferroni": n_b,
        "n_wilcoxon_are": n_b * math.pi / 3,
    }


def sample_size(
    model: ErrorModel, config: PowerConfig, progress: Callable[[int], Any] | None = None
) -> PowerResult:
    """Smallest n of analysed assessors with simulated power ≥ ``config.power``.

    ``progress`` is called with the number of simulated studies after each n.
    """
    curve: dict[int, PowerPoint] = {}

    def at(n: int) -> PowerPoint:
        if n not in curve:
            curve[n] = simulate_power(model, n, config)
            if progress:
                progress(config.simulations)
        return curve[n]

    grid = sorted({round(float(x)) for x in np.geomspace(MIN_N, config.max_n, GRID_POINTS)})
    lo, hi = None, None
    for n in grid:
        if at(n).power >= config.power:
            hi = n
            break
        lo = n
    if hi is not None and lo is not None:
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if at(mid).power >= config.power:
                hi = mid
            else:
                lo = mid
    _, name = primary_pair(model.conditions)
    ref, new = model.conditions[-2], model.conditions[-1]
    return PowerResult(
        model=model,
        config=config,
        primary_test=f"Wilcoxon signed-rank {name}, two-sided, Holm over all pairs",
        expected_direction=f"{ref}'s errors larger than {new}'s"
        if model.mean_error[-2] >= model.mean_error[-1]
        else f"{new}'s errors larger than {ref}'s (the model's direction, against the hypothesis)",
        closed_forms=closed_forms(model, config.alpha, config.power),
        curve=[curve[n] for n in sorted(curve)],
        n_required=hi,
        n_recruit=None if hi is None else math.ceil(hi / (1.0 - config.attrition) - 1e-9),
        note=f"power {config.power:g} is reached at {MIN_N}, the smallest n searched: fewer may do"
        if hi == grid[0]
        else None,
    )


def power_markdown(result: PowerResult) -> str:
    """A readable summary of :func:`sample_size`'s result."""
    c, m = result.config, result.model
    lines = [
        "# Power of the study's primary test",
        "",
        f"- Primary test: {result.primary_test}; α = {c.alpha:g}; rejection counted only when "
        f"{result.expected_direction}.",
        f"- Model: {m.source}; conditions {', '.join(m.conditions)}.",
        *(f"- Assumption: {a}." for a in m.assumptions),
        f"- Simulation: {c.simulations} studies per n, seed {c.seed}; outlier rule "
        f"{c.outliers.value}"
        + (f" (k {c.tukey_k:g})" if c.outliers == OutlierRule.TUKEY else "")
        + ".",
        "",
        "| condition | mean error | SD |",
        "|---|---|---|",
        *(
            f"| {name} | {mu:.3g} | {sd:.3g} |"
            for name, mu, sd in zip(m.conditions, m.mean_error, m.sd_error, strict=True)
        ),
        "",
    ]
    if result.n_required is None:
        lines.append(
            f"**Power {c.power:g} is not reached with up to {c.max_n} assessors** (raise --max-n)."
        )
    else:
        lines.append(
            f"**{result.n_required} assessors analysed reach power {c.power:g}; recruit "
            f"{result.n_recruit}** (expecting {100 * c.attrition:.0f} % excluded)."
        )
    if result.note:
        lines.append(f"Note: {result.note}.")
    cf = result.closed_forms
    lines += ["", f"Closed forms for comparison (paired t, d_z = {cf['d_z']:.3f}):"]
    for key, label in (
        ("n_paired_t", "paired t at α"),
        ("n_paired_t_bonferroni", "paired t at α/m (Holm's smallest level)"),
        ("n_wilcoxon_are", "signed-rank at α/m under normality (× π/3)"),
    ):
        value = cf.get(key)
        lines.append(f"- {label}: " + ("–" if value is None else f"{value:.1f}"))
    lines += ["", "| n analysed | power | MC SE | Friedman power |", "|---|---|---|---|"]
    for p in result.curve:
        fr = "–" if p.power_friedman is None else f"{p.power_friedman:.3f}"
        lines.append(f"| {p.n} | {p.power:.3f} | {p.mc_se:.3f} | {fr} |")
    return "\n".join(lines) + "\n"


def plot_power(result: PowerResult, path: Any) -> None:
    """Write the power curve (PNG) to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ns = [p.n for p in result.curve]
    power = np.array([p.power for p in result.curve])
    se = np.array([p.mc_se for p in result.curve])
    fig, ax = plt.subplots(figsize=(6.0, 4.0), dpi=120)
    ax.errorbar(ns, power, yerr=1.96 * se, marker="o", capsize=3, label="primary (simulated)")
    if result.curve[0].power_friedman is not None:
        fr = [np.nan if p.power_friedman is None else p.power_friedman for p in result.curve]
        ax.plot(ns, fr, marker=".", linestyle="--", label="Friedman (simulated)")
    ax.axhline(result.config.power, color="grey", linewidth=0.8)
    if result.n_required is not None:
        ax.axvline(
            result.n_required, color="tab:red", linewidth=0.8, label=f"n = {result.n_required}"
        )
    ax.set_xlabel("assessors analysed")
    ax.set_ylabel("power")
    ax.set_ylim(0.0, 1.0)
    ax.set_title(
        f"{result.model.source}: {result.config.simulations} simulations per n", fontsize=9
    )
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, format="png")
    plt.close(fig)


def power_document(result: PowerResult) -> dict[str, Any]:
    """The ``power.json`` document."""
    return result.model_dump(mode="json")


def model_summary(model: ErrorModel) -> Mapping[str, Any]:
    """The model's per-condition figures, for the pre-registration."""
    return {
        c: {"mean_error": mu, "sd_error": sd}
        for c, mu, sd in zip(model.conditions, model.mean_error, model.sd_error, strict=True)
    }

"""A sweep's ``summary.html``: each metric against each swept parameter, 95 % CIs over seeds.

For a swept parameter *x*, the episodes are grouped by the value of *x* and, when other
parameters (not the seed) vary too, by their values (one line per combination); each point is
the mean over the group's episodes (its seeds) with a Student-t 95 % confidence interval.
Failed episodes are listed with their errors and left out of the plots.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from scipy import stats

from endocam.runner.outputs import PLOT_DPI, render_template, write_atomic

SUMMARY_HTML = "summary.html"
PLOTS = "plots"
CONFIDENCE = 0.95  # two-sided level of the intervals
SUMMARY_METRICS = (  # column, label
    ("image_error_px_mean", "Image centring error, mean (px)"),
    ("center_error_mm_mean", "3D centring error, mean (mm)"),
    ("orientation_error_deg_mean", "Orientation error, mean (deg)"),
    ("image_error_px_p95", "Image centring error, p95 (px)"),
    ("ring_out_of_view_fraction", "Ring out of view (fraction)"),
    ("touches", "Touches (count)"),
    ("contact_fraction", "Contact (fraction of time)"),
    ("wall_time_s", "Wall time per episode (s)"),
)


def mean_ci(values: Sequence[float], level: float = CONFIDENCE) -> tuple[float, float, int]:
    """Mean and half-width of the Student-t confidence interval of the finite ``values``.

    Returns ``(mean, half_width, n)``; the half-width is NaN for fewer than two values.
    """
    v = np.asarray([x for x in values if x is not None], dtype=float)
    v = v[np.isfinite(v)]
    n = len(v)
    if n == 0:
        return math.nan, math.nan, 0
    if n == 1:
        return float(v[0]), math.nan, 1
    half = float(stats.t.ppf(0.5 + level / 2, n - 1) * v.std(ddof=1) / math.sqrt(n))
    return float(v.mean()), half, n


def _key(value: Any) -> Any:
    """A sortable, hashable form of a parameter value."""
    return tuple(value) if isinstance(value, list) else value


def _label(value: Any) -> str:
    return str(value)


def _sorted(values: Sequence[Any]) -> list[Any]:
    unique = list(dict.fromkeys(_key(v) for v in values))
    try:
        return sorted(unique)
    except TypeError:
        return unique


def group_table(rows: Sequence[Mapping[str, Any]], by: Sequence[str]) -> list[dict[str, Any]]:
    """Per combination of ``by``: the episodes, failures and each metric's mean and CI."""
    ok = [r for r in rows if r["error"] is None]
    groups: dict[tuple[Any, ...], list[Mapping[str, Any]]] = {}
    for r in rows:
        groups.setdefault(tuple(_key(r[b]) for b in by), [])
    for r in ok:
        groups[tuple(_key(r[b]) for b in by)].append(r)
    out = []
    for combo in sorted(groups, key=lambda c: tuple(str(x) for x in c)):
        members = groups[combo]
        entry: dict[str, Any] = {"values": [_label(v) for v in combo], "episodes": len(members)}
        entry["failed"] = sum(
            1 for r in rows if r["error"] is not None and tuple(_key(r[b]) for b in by) == combo
        )
        entry["metrics"] = {m: mean_ci([r[m] for r in members]) for m, _ in SUMMARY_METRICS}
        out.append(entry)
    return out


def plot_against(
    rows: Sequence[Mapping[str, Any]], x: str, series: Sequence[str], path: Path
) -> None:
    """Every summary metric against parameter ``x``, one line per combination of ``series``."""
    ok = [r for r in rows if r["error"] is None]
    xs = _sorted([r[x] for r in ok])
    numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in xs)
    pos = {v: (float(v) if numeric else float(i)) for i, v in enumerate(xs)}
    combos = _sorted([tuple(_key(r[s]) for s in series) for r in ok]) if series else [()]
    ncols = 4
    nrows = math.ceil(len(SUMMARY_METRICS) / ncols)
    fig = Figure(figsize=(4.0 * ncols, 3.2 * nrows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    span = (max(pos.values()) - min(pos.values())) if numeric and len(xs) > 1 else 1.0
    width = 0.3 * span / max(len(xs), 1)
    for ax, (metric, label) in zip(axes, SUMMARY_METRICS, strict=False):
        for j, combo in enumerate(combos):
            members = [r for r in ok if tuple(_key(r[s]) for s in series) == combo]
            points = []
            for v in xs:
                mean, half, n = mean_ci([r[metric] for r in members if _key(r[x]) == v])
                if n:
                    points.append((pos[v], mean, 0.0 if math.isnan(half) else half))
            if not points:
                continue
            shift = (j - (len(combos) - 1) / 2) * width / max(len(combos), 1)
            px, py, pe = (np.array(c) for c in zip(*points, strict=True))
            name = ", ".join(f"{s}={_label(c)}" for s, c in zip(series, combo, strict=True))
            style = "-" if numeric else "none"  # categories: no line between them
            ax.errorbar(
                px + shift, py, yerr=pe, marker="o", capsize=3, lw=1.2, ls=style, label=name or None
            )
        ax.set_title(label, fontsize=9)
        ax.set_xlabel(x)
        ax.grid(alpha=0.3)
        if not numeric:
            ax.set_xticks([pos[v] for v in xs], [_label(v) for v in xs], fontsize=8)
    for ax in axes[len(SUMMARY_METRICS) :]:
        ax.set_visible(False)
    if series and len(combos) > 1:
        axes[0].legend(fontsize=7)
    fig.suptitle(f"Metrics against {x} (mean and {CONFIDENCE:.0%} CI over seeds)")
    fig.savefig(path, dpi=PLOT_DPI, format="png")


def write_summary(rows: Sequence[Mapping[str, Any]], swept: Sequence[str], out_dir: Path) -> Path:
    """Write ``plots/<param>.png`` and ``summary.html`` into ``out_dir``; returns the HTML path.

    Every file is written under a temporary name and renamed.
    """
    out_dir = Path(out_dir)
    plots_dir = out_dir / PLOTS
    plots_dir.mkdir(parents=True, exist_ok=True)
    varying = [s for s in swept if len({_key(r[s]) for r in rows}) > 1]
    by = [s for s in varying if s != "seed"]
    plots = []
    for x in varying:
        png = plots_dir / f"{x}.png"
        series = [s for s in by if s != x]
        write_atomic(png, functools.partial(plot_against, rows, x, series))
        plots.append((x, f"{PLOTS}/{png.name}"))
    html = render_template(
        "sweep.html",
        n=len(rows),
        failed=[r for r in rows if r["error"] is not None],
        swept=list(swept),
        by=by,
        groups=group_table(rows, by),
        metrics=SUMMARY_METRICS,
        plots=plots,
        confidence=CONFIDENCE,
    )
    path = out_dir / SUMMARY_HTML
    write_atomic(path, lambda p: p.write_text(html, encoding="utf-8"))
    return path

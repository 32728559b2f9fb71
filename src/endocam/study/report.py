"""Outputs of the study analysis: ``analysis.json``, two plots and ``report.html``.

The plots: a Fig. 7-style box plot of the errors and the SD across assessors per condition.

All files are first written to a temporary folder inside the output folder and then moved into
place with ``os.replace``, so a reader never sees a half-written file.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from endocam import __version__
from endocam.study.analysis import AnalysisResult, result_json
from endocam.study.observability import ObservabilitySummary
from endocam.study.visibility import ShareCI

ANALYSIS_JSON = "analysis.json"
BOXPLOT_PNG = "assessment_errors.png"
SD_PNG = "assessor_sd.png"
REPORT_HTML = "report.html"
_TEMPLATES = Path(__file__).parent / "templates"


class Labels(dict[str, str]):
    """Condition names as the report words them; a name without a label stands for itself."""

    def __missing__(self, key: str) -> str:
        return key


LABELS = Labels(
    fixed="Fixed",
    centering="Centering",
    orientation="Orientation",
    endocam="endocam (orientation)",
)
BOXPLOT_DPI = 150  # dots per inch of the PNG
SLANT_FROM_K = 4  # condition labels are slanted from this many conditions on
# What hides a gap, by the scene's geom names (endocam.sim.scene), as the report words it.
_HIDER_LABELS = (  # (geom-name prefix, label); first match wins
    ("wire", "the wire"),
    ("ring_handle", "the ring's handle"),
    ("ring", "the ring"),
    ("psm", "an instrument"),
    ("board", "the board"),
    ("wall", "the box"),
    ("post", "a post of the wire"),
    ("camera_arm", "the camera's arm"),
)


NOT_RECORDED = "not recorded (run `endocam study observe`)"


def hidden_by_text(counts: dict[str, int] | None) -> str:
    """``gap_hidden_by`` counts in words, most first: ``"the wire 20, the ring 2"`` (``–``: none).

    Geoms of one kind are summed (an instrument's jaws and shaft); names not in the table
    (e.g. ``"outside the image"``) are kept as they are. ``None``: ``NOT_RECORDED``.
    """
    if counts is None:
        return NOT_RECORDED
    out: dict[str, int] = {}
    for name, n in counts.items():
        label = next((lab for pre, lab in _HIDER_LABELS if name.startswith(pre)), name)
        out[label] = out.get(label, 0) + n
    ranked = sorted(out.items(), key=lambda kv: (-kv[1], kv[0]))
    return ", ".join(f"{label} {n}" for label, n in ranked) or "–"


def share_text(value: ShareCI | None) -> str:
    """``"52 % (38–66 %)"``: a share with its seed-level 95 % interval (``–``: not recorded)."""
    if value is None:
        return "–"
    if value.ci95 is None:
        return f"{100 * value.share:.0f} %"
    lo, hi = value.ci95
    return f"{100 * value.share:.0f} % ({100 * lo:.0f}–{100 * hi:.0f} %)"


def ci_text(value: float | None, ci95: tuple[float, float] | None, digits: int = 2) -> str:
    """``"0.79 (0.28 to 0.98)"``: a statistic with its 95 % interval (``–``: undefined)."""
    if value is None:
        return "–"
    if ci95 is None:
        return f"{value:.{digits}f}"
    return f"{value:.{digits}f} ({ci95[0]:.{digits}f} to {ci95[1]:.{digits}f})"


def kinds_text(counts: dict[str, int] | None) -> str:
    """Counts by hider kind in words, ``"wire 12, rim 3"`` (``–``: none; None: not recorded)."""
    if counts is None:
        return NOT_RECORDED
    return ", ".join(f"{kind} {n}" for kind, n in counts.items()) or "–"


def _figsize(k: int) -> tuple[float, float]:
    """Figure size (inches) for k conditions: wider as k grows, so the labels keep apart."""
    return (max(5.0, 1.0 + 1.2 * k), 4.0)


def _condition_axis(ax: Any, names: list[str]) -> None:
    """The x axis of a per-condition plot: one tick per condition, labels slanted for k ≥ 4."""
    rotation = 20 if len(names) >= SLANT_FROM_K else 0
    ax.set_xticks(
        range(1, len(names) + 1),
        labels=[LABELS[n] for n in names],
        rotation=rotation,
        ha="right" if rotation else "center",
    )
    ax.set_xlim(0.5, len(names) + 0.5)
    ax.set_xlabel("Camera condition")


def plot_assessor_sd(result: AnalysisResult, path: Path) -> None:
    """SD of the assessment error across assessors per condition, with Bonett's 95 % intervals.

    Parameters
    ----------
    result : AnalysisResult
        Its ``assessors.sd_across_assessors`` (touches) are drawn; a condition without an SD
        is left empty.
    path : Path
        PNG file to write.
    """
    names = list(result.conditions)
    sds = result.assessors.sd_across_assessors if result.assessors else {}
    fig = Figure(figsize=_figsize(len(names)), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for i, name in enumerate(names, start=1):
        est = sds.get(name)
        if est is None or est.value is None:
            continue
        ax.bar(i, est.value, width=0.5, color="0.75", edgecolor="0.3")
        if est.ci95 is not None:
            lo, hi = est.ci95
            ax.errorbar(
                i, est.value, yerr=[[est.value - lo], [hi - est.value]], color="k", capsize=4
            )
    _condition_axis(ax, names)
    ax.set_ylabel("SD of the error across assessors (touches)")
    n = result.assessors.n_complete if result.assessors else 0
    ax.set_title(f"Spread across assessors (n = {n}, Bonett's 95 % CI)")
    ax.grid(axis="y", alpha=0.3)
    fig.savefig(path, dpi=BOXPLOT_DPI, format="png")


def plot_errors(result: AnalysisResult, path: Path) -> None:
    """Box plot of the kept assessment errors per condition (like the paper's Fig. 7).

    Parameters
    ----------
    result : AnalysisResult
        Its ``kept_errors`` (touches) are drawn; the mean is marked with a triangle.
    path : Path
        PNG file to write.
    """
    names = list(result.conditions)
    data = [result.kept_errors.get(name, []) for name in names]
    fig = Figure(figsize=_figsize(len(names)), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    positions = [i + 1 for i, values in enumerate(data) if values]
    if positions:
        ax.boxplot(
            [data[p - 1] for p in positions], positions=positions, showmeans=True, widths=0.5
        )
    _condition_axis(ax, names)
    ax.set_ylabel("Assessment error (touches)")
    which = "all videos (mean)" if result.config.all_videos else "most difficult video"
    ax.set_title(f"Assessment error, {which}")
    ax.grid(axis="y", alpha=0.3)
    fig.savefig(path, dpi=BOXPLOT_DPI, format="png")


def render_report(result: AnalysisResult, observability: ObservabilitySummary | None = None) -> str:
    """The HTML report (needs jinja2 from the ``study`` extra).

    Parameters
    ----------
    result : AnalysisResult
        The analysis.
    observability : ObservabilitySummary, optional
        The study's objective touch observability (``observability.json`` written by
        ``study make``); adds a section when given.
    """
    try:
        import jinja2
    except ModuleNotFoundError as exc:  # pragma: no cover - depends on the installed extras
        raise ModuleNotFoundError(
            "report.html needs jinja2: pip install 'endocam[study]'", name=exc.name
        ) from None
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(_TEMPLATES)),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
    )
    return env.get_template("report.html").render(
        result=result,
        observability=observability,
        labels=LABELS,
        last=list(result.conditions)[-1],
        share=share_text,
        hidden_kinds=kinds_text,
        boxplot=BOXPLOT_PNG,
        sd_plot=SD_PNG,
        ci=ci_text,
        version=__version__,
        fmt=lambda x, digits=2: "–" if x is None else f"{x:.{digits}f}",
        pct=lambda x: "–" if x is None else f"{100 * x:.0f} %",
        hidden_by=hidden_by_text,
    )


def write_outputs(
    result: AnalysisResult,
    out_dir: str | Path,
    observability: ObservabilitySummary | None = None,
) -> dict[str, Path]:
    """Write ``analysis.json``, the box plot PNG and ``report.html`` atomically into ``out_dir``.

    Parameters
    ----------
    result : AnalysisResult
        What to write.
    out_dir : str or Path
        Output folder, created if missing (marked with ``.endocam-output``); an existing one
        must be empty or endocam's own, and its files of the same names are replaced.
    observability : ObservabilitySummary, optional
        Shown as a section of ``report.html`` when given.

    Returns
    -------
    dict name → Path
        The written files.
    """
    from endocam.runner.outputs import OUTPUT_MARKER, check_replaceable, write_marker

    out = Path(out_dir)
    check_replaceable(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        if not (out / OUTPUT_MARKER).is_file():
            write_marker(out)
        tmp = Path(tempfile.mkdtemp(prefix=".analysis-", dir=out))
    except OSError as exc:
        raise ValueError(f"out_dir: cannot write to {out}: {exc.strerror or exc}") from None
    try:
        doc = json.dumps(result_json(result), indent=2, allow_nan=False) + "\n"
        (tmp / ANALYSIS_JSON).write_text(doc, encoding="utf-8")
        plot_errors(result, tmp / BOXPLOT_PNG)
        plot_assessor_sd(result, tmp / SD_PNG)
        (tmp / REPORT_HTML).write_text(render_report(result, observability), encoding="utf-8")
        written = {}
        for name in (ANALYSIS_JSON, BOXPLOT_PNG, SD_PNG, REPORT_HTML):
            os.replace(tmp / name, out / name)
            written[name] = out / name
        return written
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

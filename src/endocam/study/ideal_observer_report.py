"""``ideal_observer.html``: the ideal observer's table as a page a study author can read.

Made from ``ideal_observer.json``'s content alone (:func:`report_html`), so a page can be
remade from a kept JSON without refitting: the table (AUC and d′ with their CIs, frames, seeds,
counted and true touches), a plot of the AUCs with their intervals, the condition that carries
the most information and how sure that is, each seed's AUC and count, and the method in words.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Sequence
from typing import Any

PLOT_W_IN, PLOT_H_IN, PLOT_DPI = 6.4, 2.6, 110  # the AUC plot's size, inches and dots per inch
INPUT_MARKERS = {"mono": ("o", "#1f77b4"), "stereo": ("s", "#d62728")}

STYLE = (
    "body{font-family:sans-serif;margin:1.5em;max-width:62em;line-height:1.4}"
    "table{border-collapse:collapse;margin:.6em 0;font-size:90%}"
    "th,td{border:1px solid #ccc;padding:2px 6px;text-align:right}td{white-space:nowrap}"
    "th:first-child,td:first-child,th:nth-child(2),td:nth-child(2){text-align:left}"
    "th{background:#f0f0f0}.best{font-weight:bold}.note{color:#555;font-size:small}"
    "details{margin:.5em 0}"
)


def fmt(x: float | None, digits: int = 3) -> str:
    """A number for the page; ``–`` for None or NaN."""
    if x is None or not math.isfinite(x):
        return "–"
    return f"{x:.{digits}f}"


def auc_plot_png(rows: Sequence[dict[str, Any]], target: float) -> bytes:
    """A PNG: per condition, each input's AUC with its 95 % CI; chance (0.5) dashed.

    ``rows`` : the JSON's rows (``condition``, ``input``, ``auc``, ``auc_ci``); ``target`` : the
    CI half-width aimed at, drawn as a bar for scale.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conditions = list(dict.fromkeys(r["condition"] for r in rows))
    inputs = list(dict.fromkeys(r["input"] for r in rows))
    fig, ax = plt.subplots(figsize=(PLOT_W_IN, PLOT_H_IN), dpi=PLOT_DPI)
    step = 0.25
    for r in rows:
        k, j = conditions.index(r["condition"]), inputs.index(r["input"])
        y = k + (j - (len(inputs) - 1) / 2) * step
        lo, hi = r["auc_ci"]
        marker, colour = INPUT_MARKERS.get(r["input"], ("^", "k"))
        ax.plot([lo, hi], [y, y], color=colour, lw=2)
        ax.plot(r["auc"], y, marker=marker, color=colour, ls="none", label=r["input"])
    ax.axvline(0.5, color="grey", ls="--", lw=1)
    ax.text(0.5, -0.7, " chance", color="grey", fontsize=8, va="center")
    ax.plot([0.97 - 2 * target, 0.97], [-0.7, -0.7], color="k", lw=3)
    ax.text(
        0.97 - 2 * target,
        -0.7,
        f"CI width of the ±{target:g} target ",
        fontsize=8,
        va="center",
        ha="right",
    )
    ax.set_yticks(range(len(conditions)), conditions)
    ax.set_ylim(len(conditions) - 0.4, -1.0)
    ax.set_xlim(0.3, 1.0)
    ax.set_xlabel("AUC (touch vs ≥ 0.5 mm apart), 95 % CI over seeds")
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    ax.legend(unique.values(), unique.keys(), loc="lower left", fontsize=8)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()


def main_table(doc: dict[str, Any]) -> list[str]:
    """The table's HTML rows, the best condition per input in bold."""
    best = {name: b["condition"] for name, b in doc["most_informative"].items()}
    parts = [
        "<table><tr><th>condition</th><th>input</th><th>AUC</th><th>AUC 95 % CI</th>"
        "<th>± half-width</th><th>d′</th><th>d′ 95 % CI</th><th>frames: contact / labelled</th>"
        "<th>seeds</th><th>touches counted / true</th><th>mean |counted − true| (per seed)</th>"
        "<th>seeds for ±"
        f"{doc['target_half_width']:g}</th></tr>"
    ]
    for r in doc["rows"]:
        cls = " class='best'" if best.get(r["input"]) == r["condition"] else ""
        (lo, hi), (dlo, dhi) = r["auc_ci"], r["d_prime_ci"]
        parts.append(
            f"<tr{cls}><td>{html.escape(r['condition'])}</td><td>{html.escape(r['input'])}</td>"
            f"<td>{fmt(r['auc'])}</td><td>{fmt(lo)} – {fmt(hi)}</td>"
            f"<td>{fmt(r['auc_ci_half_width'])}</td><td>{fmt(r['d_prime'], 2)}</td>"
            f"<td>{fmt(dlo, 2)} – {fmt(dhi, 2)}</td>"
            f"<td>{r['n_contact_frames']} / {r['n_frames']}</td><td>{r['n_seeds']}</td>"
            f"<td>{r['counted_touches']} / {r['true_touches']}</td>"
            f"<td>{fmt(r['mean_abs_count_error'], 1)}</td>"
            f"<td>{r['seeds_for_target']}</td></tr>"
        )
    parts.append(
        "</table><p class='note'>Bold: the highest AUC of its input. ± half-width: half the "
        "95 % CI's width. Seeds for ±target: how many seeds would bring this row's CI to the "
        "target, by the 1/√seeds scaling of a seed bootstrap.</p>"
    )
    return parts


def verdict(doc: dict[str, Any]) -> list[str]:
    """Per input, the most informative condition and its paired differences, in words."""
    parts = []
    for name, b in doc["most_informative"].items():
        items: list[str] = []
        above: list[str] = []
        level: list[str] = []
        for v in b["versus"]:
            lo, hi = v["ci"]
            (above if lo > 0.0 else level).append(html.escape(v["other"]))
            items.append(
                f"{html.escape(v['other'])} {v['auc_difference']:+.3f} [{lo:+.3f}, {hi:+.3f}]"
            )
        best = html.escape(b["condition"])
        plain = f"above {', '.join(above)} (95 % CI of the difference above 0)" if above else ""
        plain += ("; " if above and level else "") + (
            f"not distinguishable from {', '.join(level)} (CI includes 0)" if level else ""
        )
        parts.append(
            f"<li><b>{html.escape(name)}</b>: the highest AUC is <b>{best}</b>'s: {plain}. "
            f"Its AUC minus the others' (paired seed bootstrap, 95 % CI): {'; '.join(items)}.</li>"
        )
    return ["<ul>", *parts, "</ul>"]


def seed_table(doc: dict[str, Any]) -> list[str]:
    """Per condition × input and seed: the seed's AUC and its counted / true touches."""
    seeds = sorted({s["seed"] for r in doc["rows"] for s in r["per_seed"]})
    head = "".join(f"<th>{s}</th>" for s in seeds)
    parts = [
        "<details><summary>Per seed: AUC of the held-out seed's frames, and touches counted / "
        "true</summary><table>",
        f"<tr><th>condition</th><th>input</th>{head}</tr>",
    ]
    for r in doc["rows"]:
        by_seed = {s["seed"]: s for s in r["per_seed"]}
        cells = "".join(
            f"<td>{fmt(by_seed[s].get('auc'))}<br><span class='note'>"
            f"{by_seed[s]['counted_touches']} / {by_seed[s]['true_touches']}</span></td>"
            if s in by_seed
            else "<td>–</td>"
            for s in seeds
        )
        parts.append(
            f"<tr><td>{html.escape(r['condition'])}</td><td>{html.escape(r['input'])}</td>"
            f"{cells}</tr>"
        )
    parts.append("</table></details>")
    return parts


def report_html(doc: dict[str, Any]) -> str:
    """The self-contained page for an ``ideal_observer.json`` document."""
    rows = doc["rows"]
    png = base64.b64encode(auc_plot_png(rows, doc["target_half_width"])).decode()
    seeds = sorted({s["seed"] for r in rows for s in r["per_seed"]})
    worst = max(rows, key=lambda r: r["auc_ci_half_width"])
    need = max(r["seeds_for_target"] for r in rows)
    target = doc["target_half_width"]
    met = worst["auc_ci_half_width"] <= target
    width = (
        f"Every CI half-width is at most ±{target:g} (the target)."
        if met
        else f"The widest CI is ±{worst['auc_ci_half_width']:.3f} "
        f"({html.escape(worst['condition'])}, {html.escape(worst['input'])}), above the "
        f"±{target:g} target; by the 1/√seeds scaling of a seed bootstrap, about {need} "
        "seeds would bring every row to the target."
    )
    parts = [
        "<!doctype html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>endocam ideal observer</title><style>{STYLE}</style></head><body>",
        "<h1>What the video carries: the ideal observer</h1>",
        "<p>A classifier learned, for each camera condition, to tell video frames where the ring "
        f"<b>touches</b> the wire from frames where it is at least {doc['labels']['apart_mm']:g} "
        "mm <b>apart</b>, from a small crop around the ring (frames in between are left out). "
        "It is tested only on seeds it never saw. Its <b>AUC</b> is the chance that a random "
        "touching frame scores above a random apart frame: 0.5 is chance (the video shows "
        "nothing about touches), 1 is perfect. <b>d′</b> is the same on a detection-theory "
        "scale (0 is chance). A higher AUC means the video carries more information about "
        "touches. It is a lower bound on what the pixels hold (a better model could only find "
        "more), and it knows where the ring is; it does not predict what a person will count."
        "</p>",
        f"<p class='note'>Study: {html.escape(doc['study'])}; seeds: "
        f"{', '.join(str(s) for s in seeds)} ({len(seeds)}). <b>mono</b>: the left eye (the "
        "video assessors watch); <b>stereo</b>: both eyes' crops side by side.</p>",
        f"<img alt='AUC per condition with 95 % CI' src='data:image/png;base64,{png}'>",
        *main_table(doc),
        f"<p>{width}</p>",
        "<h2>Which condition carries the most touch information</h2>",
        *verdict(doc),
        *seed_table(doc),
        "<h2>Method</h2><ul>",
        f"<li>Input: {html.escape(doc['features'])}; {doc['crop_px']} × {doc['crop_px']} px.</li>",
        f"<li>Model: {html.escape(doc['model'])}.</li>",
        f"<li>Cross-validation: {html.escape(doc['cv'])}.</li>",
        f"<li>Intervals: {html.escape(doc['ci'])}; d′ = {html.escape(doc['d_prime'])}.</li>",
        "<li>Touches counted: each held-out seed's frame scores thresholded (the threshold "
        "chosen on the training seeds only) and debounced as the hand-tuned observer does.</li>",
        f"</ul><p class='note'>endocam {html.escape(str(doc.get('endocam_version', '')))}</p>",
        "</body></html>\n",
    ]
    return "\n".join(parts)

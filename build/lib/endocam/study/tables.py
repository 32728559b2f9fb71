"""``hypothesis.json`` as Markdown: the closing gap first, then the observer's counts.

``study make`` and ``study observe`` print :func:`hypothesis_table`; docs/study.md shows it.
"""

from __future__ import annotations

from typing import Any


def _fmt(value: float | None, spec: str) -> str:
    return "–" if value is None else format(value, spec)


def _share(value: dict[str, Any] | None) -> str:
    """A share with its interval, ``52 % (38–66 %)`` (``–``: not recorded)."""
    if value is None:
        return "–"
    if value.get("ci95") is None:
        return f"{value['share']:.0%}"
    lo, hi = value["ci95"]
    return f"{value['share']:.0%} ({lo:.0%}–{hi:.0%})"


def gap_table(doc: dict[str, Any]) -> str:
    """The closing gap per condition (``hypothesis.json``), as a Markdown table: the lead."""
    extra = doc["extra_seeds"]
    lines = [
        f"| condition | {doc['trajectory']}: resolved | in sight (either eye) | "
        f"median gap (px) | {extra['n']} extra seeds: resolved (95 % CI) | "
        "in sight, either eye (95 % CI) | left eye (95 % CI) | hidden from both by |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c, row in doc["study"].items():
        e = extra["conditions"].get(c) or {}
        hidden = e.get("hidden_from_both")
        lines.append(
            f"| {c} | {_fmt(row.get('resolved_share'), '.0%')} | "
            f"{_fmt(row.get('gap_in_sight_either_share'), '.0%')} | "
            f"{_fmt(row.get('median_gap_px'), '.1f')} | {_share(e.get('resolved'))} | "
            f"{_share(e.get('gap_in_sight_either'))} | {_share(e.get('gap_in_sight_left'))} | "
            + ("–" if not hidden else ", ".join(f"{k} {n}" for k, n in hidden.items()))
            + " |"
        )
    return "\n".join(lines) + "\n"


def hypothesis_table(doc: dict[str, Any]) -> str:
    """``hypothesis.json`` as Markdown: the closing gap (:func:`gap_table`), then the observer."""
    return gap_table(doc) + "\n" + observer_table(doc)


def observer_table(doc: dict[str, Any]) -> str:
    """The observer's counts per condition (``hypothesis.json``), as a Markdown table."""
    extra = doc["extra_seeds"]
    stale = "" if extra.get("recounted", True) else " (earlier observer)"
    lines = [
        f"| condition | {doc['trajectory']}: counted / true, abs. error | precision / recall | "
        f"gap before (px) | closes visibly | gap in sight | {extra['n']} extra seeds{stale}: "
        "mean abs. error (SD) | precision / recall | gap before (px) | closes visibly | "
        "gap in sight |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c, row in doc["study"].items():
        e = extra["conditions"].get(c)
        tail = (
            "– | – | – | – | –"
            if e is None
            else f"{e['mean_abs_error']:.2f} ({_fmt(e['sd_abs_error'], '.2f')}) | "
            f"{e['precision']:.2f} / {e['recall']:.2f} | "
            f"{_fmt(e['median_gap_before_px'], '.1f')} | "
            f"{_fmt(e['closes_visibly_share'], '.0%')} | "
            f"{_fmt(e.get('gap_in_sight_share'), '.0%')}"
        )
        lines.append(
            f"| {c} | {row['counted_touches']} / {row['true_touches']}, {row['abs_error']} | "
            f"{row['precision']:.2f} / {row['recall']:.2f} | "
            f"{_fmt(row['median_gap_before_px'], '.1f')} | "
            f"{_fmt(row['closes_visibly_share'], '.0%')} | "
            f"{_fmt(row.get('gap_in_sight_share'), '.0%')} | {tail} |"
        )
    return "\n".join(lines) + "\n"

"""Pre-registration: the study's plan, frozen from its own files, and the check ``analyze`` makes.

:func:`plan` builds the plan from the study folder and the analysis settings, the same objects
``study analyze`` runs on (:class:`~endocam.study.manifest.Manifest`,
:class:`~endocam.study.analysis.AnalysisConfig`, the videos the analysis selects), so the
document cannot say something the analysis does not do:

- ``hypotheses``: the primary test (:mod:`endocam.study.power`: the last condition against the
  one before it), the omnibus Friedman test, the SD comparisons of the paper's second claim;
- ``design``: conditions, videos per condition, the presentation orders (the manifest's Williams
  design), within-set shuffling, practice, demographics, the attention question's place, the
  must-watch rule;
- ``exclusions``: the rules in the order ``analyze`` applies them;
- ``analysis``: every :class:`AnalysisConfig` field, the analysed video ids, the tests, the level;
- ``files``: the SHA-256 of ``manifest.json`` and of every file it names (videos, practice video,
  consent and message files).

``plan_sha256`` is the SHA-256 of the plan's canonical JSON (sorted keys, no spaces). The document
(:func:`preregistration`) adds the power calculation (``study power``'s ``power.json``, if given),
the endocam version and the time; those are outside the hash.

:func:`check` rebuilds the plan at analysis time and compares: the same hash means the analysis
follows the registered plan; otherwise every differing entry is listed as a deviation (a changed
video is ``files.videos/v03.mp4``; a changed outlier rule ``analysis.config.tukey_k``), and fewer
analysed assessors than the registered sample size is one too.
"""

from __future__ import annotations

import hashlib
import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from endocam import __version__
from endocam.study.analysis import FRIEDMAN_MIN_CONDITIONS, AnalysisConfig, OutlierRule
from endocam.study.flow import attention_after_set
from endocam.study.manifest import MANIFEST_NAME, Manifest, load_manifest
from endocam.study.power import DEFAULT_ALPHA, primary_pair

PREREGISTRATION_JSON, PREREGISTRATION_MD = "preregistration.json", "preregistration.md"
CHECK_JSON = "preregistration-check.json"
MISSING = "missing"  # the hash entry of a file the manifest names but the folder lacks
CHUNK_BYTES = 1 << 20  # bytes read at a time when hashing a file


def sha256_file(path: Path) -> str:
    """SHA-256 (hex) of a file's bytes."""
    digest = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(CHUNK_BYTES):
            digest.update(chunk)
    return digest.hexdigest()


def _files(folder: Path, manifest: Manifest) -> dict[str, str]:
    names = [MANIFEST_NAME, *(v.file for v in manifest.videos)]
    if manifest.practice:
        names.append(manifest.practice.file)
    names += [f for f in (manifest.consent_file, manifest.messages_file) if f]
    return {
        name: sha256_file(folder / name) if (folder / name).is_file() else MISSING for name in names
    }


def _exclusions(config: AnalysisConfig) -> list[str]:
    if config.outliers == OutlierRule.TUKEY:
        rule = (
            f"Tukey's fences: outside [Q1 - {config.tukey_k:g} IQR, Q3 + {config.tukey_k:g} IQR]"
            " (numpy's linear quartiles)"
        )
    elif config.outliers == OutlierRule.ZSCORE:
        rule = f"|z| > {config.z_threshold:g} (sample SD)"
    else:
        rule = "none"
    return [
        "only each participant id's first session; an id with a withdrawn session never",
        "participants who failed or did not answer the attention question: removed entirely",
        "participants without an answer for an analysed video: removed entirely",
        f"outliers per condition, {rule}: removed from that condition only",
        "the tests use the complete cases (a kept value in every condition)",
    ]


def plan(study: str | Path, config: AnalysisConfig | None = None) -> dict[str, Any]:
    """The study's plan (module docstring) from its folder and the analysis settings.

    A file the manifest names but the folder lacks is hashed as ``"missing"`` (a deviation at
    analysis time; :func:`preregistration` refuses it).

    Raises
    ------
    ValueError
        No usable manifest (one line).
    """
    folder = Path(study)
    manifest = load_manifest(folder, check_files=False)
    config = config or AnalysisConfig()
    conds = manifest.conditions
    _, primary = primary_pair(conds)
    *refs, last = conds
    analysed = {
        c: [v.id for v in manifest.videos_of(c)]
        if config.all_videos
        else [manifest.most_difficult(c).id]
        for c in conds
    }
    tests = [
        f"primary: Wilcoxon signed-rank {primary}, two-sided, Holm over all "
        f"{len(conds) * (len(conds) - 1) // 2} pairs, alpha {DEFAULT_ALPHA:g}",
        "every pair: Wilcoxon signed-rank with Holm, rank-biserial correlation with a "
        "participant-bootstrap 95 % interval",
    ]
    if len(conds) >= FRIEDMAN_MIN_CONDITIONS:
        tests.insert(1, f"omnibus: Friedman over the {len(conds)} conditions, Kendall's W")
    tests += [
        "SD across assessors per condition with Bonett's 95 % interval; of "
        f"{last} against {', '.join(reversed(refs))}: ratio with a paired BCa bootstrap 95 % "
        "interval, Pitman-Morgan test",
        "agreement: ICC(2,1) and Krippendorff's alpha (interval) with bootstrap 95 % intervals",
    ]
    return {
        "hypotheses": {
            "primary": f"the assessment error (touches) in {last} differs from that in "
            f"{conds[-2]}, expected lower",
            "omnibus": "the assessment error differs among the conditions",
            "spread": f"the SD of the error across assessors is lower in {last}",
        },
        "design": {
            "conditions": list(conds),
            "videos": {c: [v.id for v in manifest.videos_of(c)] for c in conds},
            "orders": [list(o) for o in manifest.orders],
            "within_subject": True,
            "shuffle_within_set": manifest.shuffle_within_set,
            "practice": manifest.practice is not None,
            "demographics": manifest.demographics,
            "attention_after_set": attention_after_set(len(conds)),
            "attention_answer": manifest.attention.answer,
            "must_watch": manifest.must_watch,
            "touch_definition": manifest.touch_definition,
        },
        "exclusions": _exclusions(config),
        "analysis": {
            "config": config.model_dump(mode="json"),
            "analysed_videos": analysed,
            "error": "mean |reported - true| over the analysed videos, per condition",
            "tests": tests,
            "alpha": DEFAULT_ALPHA,
        },
        "files": _files(folder, manifest),
    }


def plan_sha256(doc: dict[str, Any]) -> str:
    """SHA-256 of the plan's canonical JSON."""
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def preregistration(
    study: str | Path, config: AnalysisConfig | None = None, power: dict[str, Any] | None = None
) -> dict[str, Any]:
    """The pre-registration document: the plan, its hash, the power calculation, provenance."""
    the_plan = plan(study, config)
    missing = [name for name, h in the_plan["files"].items() if h == MISSING]
    if missing:
        raise ValueError(f"{study}: files named in the manifest are missing: {missing}")
    sample = None
    if power is not None:
        sample = {
            "n_analysed": power.get("n_required"),
            "n_recruit": power.get("n_recruit"),
            "primary_test": power.get("primary_test"),
            "model": (power.get("model") or {}).get("source"),
            "simulations": (power.get("config") or {}).get("simulations"),
            "power": (power.get("config") or {}).get("power"),
        }
    return {
        "plan_sha256": plan_sha256(the_plan),
        "plan": the_plan,
        "sample_size": sample,
        "endocam_version": __version__,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }


def _flat(doc: Any, prefix: str = "") -> dict[str, Any]:
    """Nested dicts → {"a.b.c": leaf}; lists and scalars are leaves."""
    if isinstance(doc, dict) and doc:
        out: dict[str, Any] = {}
        for key, value in doc.items():
            out |= _flat(value, f"{prefix}.{key}" if prefix else str(key))
        return out
    return {prefix: doc}


def check(
    registered: dict[str, Any], study: str | Path, config: AnalysisConfig, n_analysed: int
) -> dict[str, Any]:
    """Compare the analysis about to be reported with a pre-registration document.

    Returns
    -------
    dict
        ``follows`` (bool), ``registered_sha256``, ``actual_sha256`` and ``deviations``: one
        line per differing plan entry, and one if fewer assessors are analysed than registered.

    Raises
    ------
    ValueError
        ``registered`` is not a pre-registration document.
    """
    if not isinstance(registered, dict) or not isinstance(registered.get("plan"), dict):
        raise ValueError("not a pre-registration (no plan): write one with study preregister")
    actual = plan(study, config)
    before, now = _flat(registered["plan"]), _flat(actual)
    deviations = []
    for key in sorted(set(before) | set(now)):
        if before.get(key, "<absent>") != now.get(key, "<absent>"):
            was, is_ = before.get(key, "<absent>"), now.get(key, "<absent>")
            deviations.append(f"{key}: registered {was!r}, analysed {is_!r}")
    if plan_sha256(registered["plan"]) != registered.get("plan_sha256"):
        deviations.append("plan_sha256: the document's plan was edited after registration")
    planned = (registered.get("sample_size") or {}).get("n_analysed")
    if isinstance(planned, int) and n_analysed < planned:
        deviations.append(f"sample size: {n_analysed} assessors analysed, {planned} registered")
    return {
        "follows": not deviations,
        "registered_sha256": registered.get("plan_sha256"),
        "actual_sha256": plan_sha256(actual),
        "deviations": deviations,
    }


def preregistration_markdown(doc: dict[str, Any]) -> str:
    """The readable pre-registration."""
    p = doc["plan"]
    d, a = p["design"], p["analysis"]
    lines = [
        "# Pre-registration",
        "",
        f"Plan SHA-256: `{doc['plan_sha256']}` (endocam {doc['endocam_version']}, "
        f"{doc['created']}). `endocam study analyze` rebuilds this plan from the study folder "
        "and its own settings and lists every deviation.",
        "",
        "## Hypotheses",
        "",
        *(f"- **{k}**: {v}." for k, v in p["hypotheses"].items()),
        "",
        "## Design",
        "",
        f"- Within-subject; conditions, in this order: {', '.join(d['conditions'])}.",
        *(f"- {c}: videos {', '.join(v)}." for c, v in d["videos"].items()),
        "- Presentation orders (one per participant, balanced): "
        + "; ".join(" > ".join(o) for o in d["orders"])
        + ".",
        f"- Videos shuffled within a set: {'yes' if d['shuffle_within_set'] else 'no'}; "
        f"practice video: {'yes' if d['practice'] else 'no'}; demographics: "
        f"{'yes' if d['demographics'] else 'no'}; must watch each video to its end: "
        f"{'yes' if d['must_watch'] else 'no'}.",
        f"- Attention question after set {d['attention_after_set']} (answer "
        f"{d['attention_answer']}).",
        f"- Touch definition shown: {d['touch_definition']}",
        "",
        "## Exclusions, in order",
        "",
        *(f"{i}. {rule}" for i, rule in enumerate(p["exclusions"], 1)),
        "",
        "## Analysis",
        "",
        f"- Error: {a['error']}; analysed videos: "
        + "; ".join(f"{c} {', '.join(v)}" for c, v in a["analysed_videos"].items())
        + ".",
        *(f"- {t}." for t in a["tests"]),
        f"- Settings: `{json.dumps(a['config'], sort_keys=True)}`.",
        "",
        "## Sample size",
        "",
    ]
    s = doc.get("sample_size")
    if s is None:
        lines.append("No power calculation given (`endocam study power`, then --power).")
    else:
        lines.append(
            f"{s['n_analysed']} assessors analysed for power {s['power']} of the "
            f"{s['primary_test']} ({s['model']}, {s['simulations']} simulations per n); "
            f"recruit {s['n_recruit']}."
        )
    lines += ["", "## Files (SHA-256)", "", "| file | SHA-256 |", "|---|---|"]
    lines += [f"| {name} | `{h}` |" for name, h in p["files"].items()]
    return "\n".join(lines) + "\n"

"""``endocam study power``, ``study preregister`` and ``study simulate``: planning a study.

``power`` sizes the study (:mod:`endocam.study.power`), ``preregister`` freezes its plan
(:mod:`endocam.study.preregister`), ``simulate`` checks the whole pipeline with synthetic
assessors (:mod:`endocam.study.simulate`). Registered by :mod:`endocam.cli.study`.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from endocam.cli.common import UsageError, integer, out_dir
from endocam.study.analysis import AnalysisConfig, OutlierRule

_EXTRA_HINT = "install the study extra: pip install 'endocam[study]'"


def write_files(out: Path, files: dict[str, Callable[[Path], object]]) -> list[Path]:
    """Create ``out`` (marked as endocam's) and write each file atomically; the paths written."""
    from endocam.runner.outputs import OUTPUT_MARKER, write_atomic, write_marker

    try:
        out.mkdir(parents=True, exist_ok=True)
        if not (out / OUTPUT_MARKER).is_file():
            write_marker(out)
    except OSError as exc:
        raise UsageError(f"--out: cannot write to {out}: {exc.strerror or exc}") from None
    for name, write in files.items():
        write_atomic(out / name, write)
    return [out / name for name in files]


def text_writer(text: str) -> Callable[[Path], object]:
    """A ``write`` for :func:`write_files` that writes ``text`` (UTF-8)."""
    return lambda path: path.write_text(text, encoding="utf-8")


def load_pilot(args: argparse.Namespace) -> tuple[Any, list[Any]] | None:
    """(manifest, answers) of ``--study`` with ``--db`` or ``--responses``; None without them."""
    from endocam.study.db import StudyDB
    from endocam.study.manifest import load_manifest
    from endocam.study.responses import read_responses_csv

    if args.db is None and args.responses is None:
        return None
    if args.study is None:
        raise UsageError("--study: a pilot (--db or --responses) needs its study folder")
    try:
        manifest = load_manifest(args.study, check_files=False)
        if args.db is not None:
            try:
                rows = StudyDB(args.db, read_only=True).export_rows()
            except ValueError as exc:
                raise UsageError(f"--db: {exc}") from None
        else:
            rows = read_responses_csv(args.responses)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not rows:
        raise UsageError("the pilot has no answers")
    return manifest, rows


def _check_fraction(name: str, value: float, low_open: bool = True) -> None:
    ok = math.isfinite(value) and (0 < value < 1 if low_open else 0 <= value < 1)
    if not ok:
        interval = "(0, 1)" if low_open else "[0, 1)"
        raise UsageError(f"--{name} must be in {interval}, got {value}")


def _power(args: argparse.Namespace) -> int:
    from endocam.progress import progress_bar
    from endocam.study import power as pw

    for name in ("alpha", "power"):
        _check_fraction(name, getattr(args, name))
    _check_fraction("attrition", args.attrition, low_open=False)
    if args.simulations < 100:
        raise UsageError(f"--simulations must be ≥ 100, got {args.simulations}")
    if args.max_n < pw.MIN_N:
        raise UsageError(f"--max-n must be ≥ {pw.MIN_N}, got {args.max_n}")
    if args.seed < 0:
        raise UsageError(f"--seed must be ≥ 0, got {args.seed}")
    outliers, tukey_k = outlier_options(args)
    out = out_dir(args.out)
    pilot = load_pilot(args)
    try:
        if pilot is None:
            model = pw.paper_model(args.cv, args.rho)
        else:
            model = pw.pilot_model(pilot[1], pilot[0], args.all_videos)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    config = pw.PowerConfig(
        alpha=args.alpha,
        power=args.power,
        simulations=args.simulations,
        seed=args.seed,
        max_n=args.max_n,
        attrition=args.attrition,
        outliers=outliers,
        tukey_k=tukey_k,
    )
    with progress_bar(desc="power", unit="study") as bar:
        result = pw.sample_size(model, config, progress=bar.update)
    doc = json.dumps(pw.power_document(result), indent=2, allow_nan=False) + "\n"
    written = write_files(
        out,
        {
            pw.POWER_JSON: text_writer(doc),
            pw.POWER_MD: text_writer(pw.power_markdown(result)),
            pw.POWER_PNG: lambda path: pw.plot_power(result, path),
        },
    )
    if result.n_required is None:
        print(f"power {args.power:g} not reached with up to {args.max_n} assessors")
    else:
        print(
            f"{result.n_required} assessors analysed reach power {args.power:g} "
            f"({result.primary_test}); recruit {result.n_recruit}"
        )
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0


def _pilot_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--study", metavar="DIR", help="study folder with manifest.json")
    source = p.add_mutually_exclusive_group()
    source.add_argument("--db", metavar="FILE", help="a pilot's study database")
    source.add_argument("--responses", metavar="CSV", help="a pilot's responses CSV")


def add_analysis_arguments(p: argparse.ArgumentParser) -> None:
    """``--outliers`` and ``--tukey-k``: the outlier rule, read by :func:`outlier_options`."""
    p.add_argument(
        "--outliers",
        choices=[r.value for r in OutlierRule],
        default=OutlierRule.TUKEY.value,
        help="per-condition outlier rule of the analysis (default: %(default)s)",
    )
    p.add_argument(
        "--tukey-k",
        type=float,
        default=AnalysisConfig().tukey_k,
        help="IQR multiplier of Tukey's fences (default: %(default)s)",
    )


def outlier_options(args: argparse.Namespace) -> tuple[OutlierRule, float]:
    """The outlier rule and Tukey's k of :func:`add_analysis_arguments` (k finite and > 0)."""
    if not (math.isfinite(args.tukey_k) and args.tukey_k > 0):
        raise UsageError(f"--tukey-k must be a finite number > 0, got {args.tukey_k}")
    return OutlierRule(args.outliers), args.tukey_k


def add_power(sub: argparse._SubParsersAction) -> None:
    """The ``study power`` subcommand."""
    from endocam.study import power as pw

    p = sub.add_parser(
        "power",
        help="assessors needed for the primary test, by simulation",
        description="Sample size of the primary test (Wilcoxon, last condition against the one "
        "before it, Holm over all pairs) at the stated power, simulated with the analysis's own "
        "steps, from a pilot's answers (--study with --db or --responses) or, without a pilot, "
        "the paper's figures with an assumed spread and correlation. Writes power.json, power.md "
        "and power.png into --out.",
    )
    _pilot_arguments(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--alpha", type=float, default=pw.DEFAULT_ALPHA, help="level (default 0.05)")
    p.add_argument("--power", type=float, default=pw.DEFAULT_POWER, help="target (default 0.8)")
    p.add_argument(
        "--simulations",
        type=integer,
        default=pw.DEFAULT_SIMULATIONS,
        help="simulated studies per n (default: %(default)s)",
    )
    p.add_argument("--seed", type=integer, default=0, help="simulation seed (default: 0)")
    p.add_argument(
        "--max-n", type=integer, default=pw.DEFAULT_MAX_N, help="largest n tried (default: 300)"
    )
    p.add_argument(
        "--attrition",
        type=float,
        default=pw.PAPER_ATTRITION,
        help="share of recruited assessors expected to be excluded (default: the paper's 3/30)",
    )
    p.add_argument(
        "--cv",
        type=float,
        default=pw.PAPER_CV,
        help="without a pilot: assumed SD/mean of the reference condition's error "
        "(default: %(default)s)",
    )
    p.add_argument(
        "--rho",
        type=float,
        default=pw.PAPER_RHO,
        help="without a pilot: assumed correlation of an assessor's errors between conditions "
        "(default: %(default)s)",
    )
    p.add_argument(
        "--all-videos",
        action="store_true",
        help="pilot errors averaged over all videos of a condition (as analyze --all-videos)",
    )
    add_analysis_arguments(p)
    p.set_defaults(handler=_power)


def _simulate(args: argparse.Namespace) -> int:
    from endocam.progress import progress_bar
    from endocam.study import simulate as sim
    from endocam.study.manifest import load_manifest

    if args.assessors < 3:
        raise UsageError(f"--assessors must be ≥ 3, got {args.assessors}")
    if args.replications < 1:
        raise UsageError(f"--replications must be ≥ 1, got {args.replications}")
    if args.seed < 0:
        raise UsageError(f"--seed must be ≥ 0, got {args.seed}")
    if args.resamples < 100:
        raise UsageError(f"--resamples must be ≥ 100, got {args.resamples}")
    _check_fraction("alpha", args.alpha)
    outliers, tukey_k = outlier_options(args)
    out = out_dir(args.out)
    try:
        manifest = load_manifest(args.study, check_files=True)
    except ValueError as exc:
        raise UsageError(f"--study: {exc}") from None
    try:
        import fastapi  # noqa: F401
        import httpx  # noqa: F401
    except ModuleNotFoundError as exc:
        raise UsageError(f"'study simulate' needs {exc.name}: {_EXTRA_HINT}") from None
    model = sim.preset(manifest, args.effect == "last", args.assessors)
    config = AnalysisConfig(
        outliers=outliers,
        tukey_k=tukey_k,
        bootstrap_resamples=args.resamples,
    )
    with progress_bar(total=args.replications, desc="replications", unit="study") as bar:
        result = sim.simulate(
            Path(args.study), model, args.replications, args.seed, config, args.alpha, bar.update
        )
    doc = json.dumps(result.model_dump(mode="json"), indent=2, allow_nan=False) + "\n"
    written = write_files(
        out,
        {
            sim.SIMULATE_JSON: text_writer(doc),
            sim.SIMULATE_MD: text_writer(sim.simulate_markdown(result)),
        },
    )
    for key, cov in result.coverage.items():
        rate = "–" if cov.rate is None else f"{cov.rate:.3f}"
        print(f"coverage {key}: {rate} of {cov.replications} (true {cov.true_value:.3f})")
    print(
        f"primary test rejected {result.rejection_rate:.3f} "
        f"(predicted {result.predicted_rate:.3f}): {'agree' if result.agrees else 'DISAGREE'}"
    )
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0 if result.agrees else 1


def add_simulate(sub: argparse._SubParsersAction) -> None:
    """The ``study simulate`` subcommand."""
    from endocam.study import simulate as sim

    p = sub.add_parser(
        "simulate",
        help="check the pipeline with synthetic assessors of known error",
        description="Synthetic assessors with a known counting bias and noise per condition "
        "answer through the app's HTTP API into a fresh database per replication; `study "
        "analyze` must recover the known SDs and SD ratios within its 95 % intervals (coverage) "
        "and reject the primary test as often as the model predicts (with --effect none: the "
        "false-positive rate). Writes simulate.json and simulate.md; exit code 1 if the "
        "rejection rate disagrees with the prediction.",
    )
    p.add_argument("--study", required=True, metavar="DIR", help="study folder with manifest.json")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument(
        "--effect",
        choices=["last", "none"],
        default="last",
        help="last: the last condition's assessors have less bias "
        f"({sim.EFFECT_BIAS:g} against {sim.REFERENCE_BIAS:g} touches) and noise "
        f"({sim.EFFECT_NOISE_SD:g} against {sim.REFERENCE_NOISE_SD:g}); none: every condition "
        "alike (default: %(default)s)",
    )
    p.add_argument(
        "--assessors",
        type=integer,
        default=sim.DEFAULT_ASSESSORS,
        help="assessors per replication (default: %(default)s)",
    )
    p.add_argument(
        "--replications",
        type=integer,
        default=sim.DEFAULT_REPLICATIONS,
        help="replications (default: %(default)s)",
    )
    p.add_argument("--seed", type=integer, default=0, help="seed (default: 0)")
    p.add_argument("--alpha", type=float, default=0.05, help="level (default: 0.05)")
    p.add_argument(
        "--resamples",
        type=integer,
        default=AnalysisConfig().bootstrap_resamples,
        help="bootstrap resamples of the analysis (default: %(default)s)",
    )
    add_analysis_arguments(p)
    p.set_defaults(handler=_simulate, outliers=OutlierRule.NONE.value)


def _preregister(args: argparse.Namespace) -> int:
    from endocam.runner.outputs import write_atomic
    from endocam.study import preregister as pr

    folder = Path(args.study)
    out = folder if args.out is None else out_dir(args.out)
    target = out / pr.PREREGISTRATION_JSON
    if target.exists() and not args.force:
        raise UsageError(f"{target} exists: a registration is frozen (--force replaces it)")
    power = None
    if args.power is not None:
        try:
            power = json.loads(Path(args.power).read_text("utf-8"))
        except (OSError, ValueError) as exc:
            raise UsageError(f"--power: cannot read {args.power}: {exc}") from None
        if not isinstance(power, dict) or "n_required" not in power:
            raise UsageError(f"--power: {args.power} is not a power.json of study power")
    outliers, tukey_k = outlier_options(args)
    config = AnalysisConfig(all_videos=args.all_videos, outliers=outliers, tukey_k=tukey_k)
    try:
        doc = pr.preregistration(folder, config, power)
    except ValueError as exc:
        raise UsageError(f"--study: {exc}") from None
    if args.out is not None:
        write_files(out, {})
    text = json.dumps(doc, indent=2, ensure_ascii=False) + "\n"
    write_atomic(out / pr.PREREGISTRATION_MD, text_writer(pr.preregistration_markdown(doc)))
    write_atomic(target, text_writer(text))
    print(f"plan SHA-256 {doc['plan_sha256']}")
    print(f"wrote {target}, {out / pr.PREREGISTRATION_MD}")
    return 0


def add_preregister(sub: argparse._SubParsersAction) -> None:
    """The ``study preregister`` subcommand."""
    p = sub.add_parser(
        "preregister",
        help="write the pre-registration (plan + hashes) of a study",
        description="Write preregistration.json and preregistration.md: hypotheses, design, "
        "exclusion rules, analysis plan (built from the manifest and the analysis settings "
        "`study analyze` will use), the SHA-256 of manifest.json and every video, the plan's "
        "hash, and the power calculation (--power). `study analyze` compares its own plan with "
        "it and lists every deviation.",
    )
    p.add_argument("--study", required=True, metavar="DIR", help="study folder with manifest.json")
    p.add_argument(
        "--out",
        metavar="DIR",
        help="folder to write to (default: the study folder, where `study analyze` finds it)",
    )
    p.add_argument("--power", metavar="FILE", help="power.json of `study power`")
    p.add_argument("--force", action="store_true", help="replace an existing registration")
    p.add_argument(
        "--all-videos",
        action="store_true",
        help="the analysis will average over all videos of a condition (analyze --all-videos)",
    )
    add_analysis_arguments(p)
    p.set_defaults(handler=_preregister)


def add_preregistration_argument(p: argparse.ArgumentParser) -> None:
    """``study analyze --preregistration FILE``."""
    p.add_argument(
        "--preregistration",
        metavar="FILE",
        help="pre-registration to compare with (default: preregistration.json beside the "
        "manifest, if there is one)",
    )


def load_preregistration(
    args: argparse.Namespace, study: Path
) -> tuple[Path, dict[str, Any]] | None:
    """``study analyze``, before any work: the pre-registration to compare with (path, document).

    ``--preregistration FILE``, else ``preregistration.json`` beside the manifest; None if
    neither exists. An unreadable or foreign file is refused (one line, exit 2).
    """
    from endocam.study import preregister as pr

    path = Path(args.preregistration) if args.preregistration else study / pr.PREREGISTRATION_JSON
    if not path.is_file():
        if args.preregistration:
            raise UsageError(f"--preregistration: no such file: {path}")
        return None
    try:
        doc = json.loads(path.read_text("utf-8"))
    except (OSError, ValueError) as exc:
        raise UsageError(f"--preregistration: cannot read {path}: {exc}") from None
    if not (isinstance(doc, dict) and isinstance(doc.get("plan"), dict)):
        raise UsageError(f"--preregistration: {path} is not a pre-registration (no plan)")
    return path, doc


def report_preregistration(
    registered: tuple[Path, dict[str, Any]] | None,
    study: Path,
    config: AnalysisConfig,
    n_analysed: int,
    out: Path,
) -> None:
    """``study analyze``, after the analysis: compare, print the verdict, write the check."""
    from endocam.runner.outputs import write_atomic
    from endocam.study import preregister as pr

    if registered is None:
        print("pre-registration: none found (endocam study preregister writes one)")
        return
    path, doc = registered
    result = pr.check(doc, study, config, n_analysed)
    text = json.dumps({"preregistration": str(path), **result}, indent=2) + "\n"
    write_atomic(out / pr.CHECK_JSON, text_writer(text))
    if result["follows"]:
        print(
            f"pre-registration: the analysis follows {path} (plan {result['actual_sha256'][:12]})"
        )
        return
    print(f"pre-registration: {len(result['deviations'])} deviation(s) from {path}:")
    for line in result["deviations"]:
        print(f"  deviation: {line}")

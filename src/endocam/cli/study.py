"""``endocam study make``, ``endocam study serve`` and ``endocam study analyze``.

The ``study`` group is registered by :func:`register`; each subcommand is one ``_add_<name>(sub)``
function in ``_SUBCOMMANDS``. ``make`` renders the nine videos with the simulator and writes the
manifest described in :mod:`endocam.study.manifest`. FastAPI and uvicorn (the ``study`` extra) are
imported only when ``serve`` runs; MuJoCo only when ``make`` runs.
"""

from __future__ import annotations

import argparse
import functools
import ipaddress
import math
import os
import socket
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from endocam.cli import study_plan
from endocam.cli.common import UsageError, check_workers, integer, out_dir
from endocam.runner.pool import DEFAULT_WORKERS
from endocam.study.analysis import AnalysisConfig, AnalysisResult
from endocam.study.db import ABANDON_AFTER_S

if TYPE_CHECKING:
    import uvicorn

ADMIN_TOKEN_ENV = "ENDOCAM_ADMIN_TOKEN"
_EXTRA_HINT = "install the study extra: pip install 'endocam[study]'"


def _make(args: argparse.Namespace) -> int:
    from endocam.config import ExperimentConfig, load_config
    from endocam.study.make import check_conditions, check_study_config, make_study

    if args.seed < 0:
        raise UsageError(f"--seed must be ≥ 0, got {args.seed}")
    if args.seeds < 0:
        raise UsageError(f"--seeds must be ≥ 0, got {args.seeds}")
    check_workers(args.workers)
    try:
        conditions = check_conditions([c.strip() for c in args.conditions.split(",")])
    except ValueError as exc:
        raise UsageError(f"--conditions: {exc}") from None
    try:
        config = ExperimentConfig() if args.config is None else load_config(args.config)
        check_study_config(config)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out_dir(args.out)
    manifest = make_study(
        config,
        args.out,
        seed=args.seed,
        extra_seeds=args.seeds,
        practice=args.practice,
        workers=args.workers,
        keep_seed_videos=args.keep_seed_videos,
        conditions=conditions,
    )
    for v in manifest.videos:
        print(f"{v.id}  {v.condition:16s} {v.trajectory:12s} {v.true_touches:3d} touches")
    print(f"study written to {args.out} ({len(manifest.videos)} videos)")
    _print_hypothesis(Path(args.out))
    return 0


def _bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port`` (bound before anything is created on disk)."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        raise UsageError(f"--host: cannot resolve {host!r}: {exc.strerror}") from None
    family, kind, proto, _, address = infos[0]
    sock = socket.socket(family, kind, proto)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
        sock.listen(128)
    except OSError as exc:
        sock.close()
        raise UsageError(f"--port: cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    return sock


# --- study observe (the automatic observer, issue 11) ---------------------------------------
def _print_hypothesis(folder: Path) -> None:
    import json

    from endocam.study.hypothesis import HYPOTHESIS_JSON
    from endocam.study.tables import hypothesis_table

    print(hypothesis_table(json.loads((folder / HYPOTHESIS_JSON).read_text("utf-8"))), end="")


def _observe(args: argparse.Namespace) -> int:
    import json

    from endocam.progress import progress_bar
    from endocam.study.hypothesis import SEEDS_DIR, kept_seeds, recount_study
    from endocam.study.manifest import ManifestError, load_manifest
    from endocam.study.observer import OBSERVER_JSON

    check_workers(args.workers)
    folder = Path(args.study)
    try:
        manifest = load_manifest(folder)
        n_seeds = len(kept_seeds(folder, manifest.conditions))
    except (ManifestError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    total = len(manifest.videos) + len(manifest.conditions) * n_seeds
    with progress_bar(total=total, desc="observer", unit="video") as bar:
        try:
            hypothesis = recount_study(folder, args.workers, progress=bar.update)
        except ValueError as exc:  # a malformed or foreign file in the folder: one line
            raise UsageError(str(exc)) from None
    document = json.loads((folder / OBSERVER_JSON).read_text("utf-8"))
    for v in document["videos"]:
        print(
            f"{v['id']}  {v['condition']:12s} counted {v['counted_touches']:3d}  "
            f"true {v['true_touches']:3d}"
        )
    print(f"wrote {folder / OBSERVER_JSON} ({len(manifest.videos)} videos)")
    if hypothesis is not None:
        extra = hypothesis["extra_seeds"]
        if not extra["recounted"]:
            print(
                f"note: the {extra['n']} extra seeds were not counted again: their videos were "
                f"not kept (study make --keep-seed-videos writes {SEEDS_DIR}/)"
            )
        _print_hypothesis(folder)
    return 0


def _add_observe(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "observe",
        help="count the touches in the study videos automatically",
        description="Count ring-wire touches in every video of a study folder from the video "
        "alone (colour segmentation, image-space gap); write observer.json and observer.html, "
        "and refresh observability.json/.csv (image-space columns) and hypothesis.json "
        "(extra seeds counted again when study make kept their videos).",
    )
    p.add_argument("--study", required=True, metavar="DIR", help="study folder with manifest.json")
    p.add_argument(
        "--workers",
        type=integer,
        default=DEFAULT_WORKERS,
        help="worker processes that count videos (1: in this process; default: %(default)s)",
    )
    p.set_defaults(handler=_observe, runs_episodes=True)


# --- study ideal-observer (a learned observer, issue 27) -------------------------------------
def _ideal_observer(args: argparse.Namespace) -> int:
    import json

    from endocam.progress import progress_bar
    from endocam.runner.outputs import write_atomic
    from endocam.study import ideal_observer_study as ios
    from endocam.study.ideal_observer_report import report_html

    inputs = tuple(dict.fromkeys(i.strip() for i in args.inputs.split(",")))
    unknown = [i for i in inputs if i not in ios.INPUTS]
    if unknown or not inputs:
        raise UsageError(f"--inputs: unknown {unknown[0]!r}; choose from: {', '.join(ios.INPUTS)}")
    if args.threads < 1:
        raise UsageError(f"--threads must be at least 1, got {args.threads}")
    try:
        import sklearn  # noqa: F401
    except ImportError:
        raise UsageError(f"study ideal-observer needs scikit-learn: {_EXTRA_HINT}") from None
    try:
        study = ios.check_study(Path(args.study), inputs, cache=not args.no_cache)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = Path(args.out) if args.out else study.folder / ios.IDEAL_OBSERVER_JSON
    if not out.parent.is_dir():
        raise UsageError(f"--out: no such folder: {out.parent}")
    from threadpoolctl import threadpool_limits

    eyes = 2 if "stereo" in inputs else 1
    n_videos = eyes * len(study.conditions) * len(study.seed_dirs)
    folds = len(inputs) * len(study.conditions) * len(study.seed_dirs)
    with (
        progress_bar(
            total=ios.frames_per_video(study) * n_videos, desc="crops", unit="frame", leave=True
        ) as crops,
        progress_bar(total=folds, desc="folds", unit="fold", leave=True) as fits,
        threadpool_limits(limits=args.threads),
    ):
        try:
            m = ios.measure(study, inputs, crops.update, fits.update)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    rows, estimates = m.rows, m.estimates
    doc = ios.document(study, rows, estimates)
    texts = {
        out: json.dumps(doc, indent=2) + "\n",
        out.with_suffix(".md"): ios.table_md(doc),
        out.with_suffix(".csv"): ios.table_csv(rows),
        out.with_suffix(".html"): report_html(doc),
    }
    for path, text in texts.items():
        write_atomic(path, functools.partial(Path.write_text, data=text, encoding="utf-8"))
    print(ios.table_md(doc), end="")
    print(f"wrote {out} (and .md, .csv, .html)")
    t = m.seconds
    print(
        f"time: crops {t['decode']:.0f} s ({m.cached} of {m.videos} videos from "
        f"{study.folder / ios.CACHE_DIR}), fits {t['fit']:.0f} s "
        f"({args.threads} thread(s)), bootstrap {t['bootstrap']:.0f} s"
    )
    return 0


def _add_ideal_observer(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "ideal-observer",
        help="measure how much information about contact each condition's video carries",
        description="Per condition and input (mono: the left eye; stereo: both eyes), train a "
        "classifier of 'in contact' against '>= 0.5 mm apart' on crops around the ring of the "
        "kept extra seeds' videos (study make --seeds N --keep-seed-videos, N >= 3), tested on "
        "held-out seeds (leave one seed out); write AUC and d' with seed-level bootstrap 95 % "
        "CIs and touch counts to ideal_observer.json/.md/.csv/.html.",
    )
    p.add_argument("--study", required=True, metavar="DIR", help="study folder with manifest.json")
    p.add_argument(
        "--out",
        metavar="FILE",
        help="JSON to write; .md, .csv and .html beside it (default: DIR/ideal_observer.json)",
    )
    p.add_argument(
        "--inputs",
        default="mono,stereo",
        metavar="I1,I2",
        help="inputs, comma-separated: mono (left eye), stereo (both eyes) (default: %(default)s)",
    )
    p.add_argument(
        "--threads",
        type=integer,
        default=1,
        help="OpenMP/BLAS threads of the model fits (default: %(default)s; more threads slow "
        "down badly on a loaded machine)",
    )
    p.add_argument(
        "--no-cache",
        action="store_true",
        help="neither read nor write the crop cache (DIR/ideal_observer_cache/: one .npz per "
        "video, used only while the video's bytes, the log's crop positions and the crop size "
        "match)",
    )
    p.set_defaults(handler=_ideal_observer)


# ---------------------------------------------------------------------------------------------


def trusted_proxies(text: str | None) -> list[str]:
    """The ``--trusted-proxy`` addresses: comma-separated IP addresses or networks (CIDR).

    Raises
    ------
    UsageError
        An entry that is not an IP address or network (``*``, trusting everyone, included).
    """
    if text is None:
        return []
    entries = [e.strip() for e in text.split(",")]
    for entry in entries:
        try:
            ipaddress.ip_network(entry, strict=False)
        except ValueError:
            raise UsageError(
                f"--trusted-proxy: {entry!r} is not an IP address or network (e.g. 127.0.0.1,"
                " 10.0.0.0/8)"
            ) from None
    return entries


def server_config(app: Any, proxies: list[str]) -> uvicorn.Config:
    """The uvicorn configuration of ``study serve``.

    ``X-Forwarded-For`` and ``X-Forwarded-Proto`` are read only from a connection whose peer is
    one of ``proxies`` (none by default: the peer address is the client's).
    """
    import uvicorn

    return uvicorn.Config(
        app,
        log_level="info",
        proxy_headers=bool(proxies),
        forwarded_allow_ips=proxies or None,
        server_header=False,
    )


def _serve(args: argparse.Namespace) -> int:
    study = Path(args.study)
    if not (study / "manifest.json").is_file():
        raise UsageError(f"--study: {study} has no manifest.json")
    if not Path(args.db).parent.is_dir():
        raise UsageError(f"--db: folder {Path(args.db).parent} does not exist")
    if not 0 < args.port < 65536:
        raise UsageError(f"--port must be in 1..65535, got {args.port}")
    if not (math.isfinite(args.abandon_after_min) and args.abandon_after_min > 0):
        raise UsageError(f"--abandon-after-min must be > 0, got {args.abandon_after_min}")
    token = args.admin_token or os.environ.get(ADMIN_TOKEN_ENV) or None
    proxies = trusted_proxies(args.trusted_proxy)
    try:
        import uvicorn

        from endocam.study.app import create_app
    except ModuleNotFoundError as exc:
        raise UsageError(f"'study serve' needs {exc.name}: {_EXTRA_HINT}") from None
    sock = _bind(args.host, args.port)  # a busy port fails here, before the database exists
    try:
        app = create_app(
            study,
            args.db,
            token,
            abandon_after_s=60.0 * args.abandon_after_min,
            secure_cookies=args.secure_cookies,
        )
    except ValueError as exc:
        sock.close()
        raise UsageError(str(exc)) from None
    if token is None:
        print(f"endocam: no admin token (--admin-token or {ADMIN_TOKEN_ENV}): admin disabled")
    print(f"endocam: serving the study on http://{args.host}:{args.port}/ (Ctrl+C stops)")
    server = uvicorn.Server(server_config(app, proxies))
    server.run(sockets=[sock])
    return 0


def _ci(value: float | None, ci95: tuple[float, float] | None) -> str:
    if value is None:
        return "–"
    return f"{value:.2f}" + ("" if ci95 is None else f" ({ci95[0]:.2f} to {ci95[1]:.2f})")


def _assessor_lines(result: AnalysisResult) -> list[str]:
    """The effect size of the Friedman test and the assessor statistics, one line each."""
    lines = []
    if result.tests.kendall_w is not None:
        w = _ci(result.tests.kendall_w, result.tests.kendall_w_ci95)
        lines.append(f"Friedman: Kendall's W {w}")
    a = result.assessors
    if a is None:
        return lines
    for name, g in a.agreement.items():
        icc = _ci(g.icc2_1.value, g.icc2_1.ci95)
        if g.icc2_1.ci95 is None and g.icc_f_ci95 is not None:  # too few videos to bootstrap
            icc = _ci(g.icc2_1.value, g.icc_f_ci95) + " F-interval"
        alpha = _ci(g.alpha_interval.value, g.alpha_interval.ci95)
        lines.append(
            f"agreement, {name} ({g.n_videos} videos, {a.n_assessors} assessors): "
            f"ICC(2,1) {icc}, alpha {alpha}"
        )
    for name, c in a.sd_comparisons.items():
        p = "–" if c.p_value is None else f"{c.p_value:.3g}"
        lines.append(
            f"SD ratio {name.replace('_vs_', ' / ')}: {_ci(c.sd_ratio.value, c.sd_ratio.ci95)} "
            f"(Pitman–Morgan p {p}; paper {c.paper_ratio:g})"
        )
    return lines


def _analyze(args: argparse.Namespace) -> int:
    from endocam.study.analysis import analyze
    from endocam.study.db import StudyDB
    from endocam.study.manifest import MANIFEST_NAME, load_manifest
    from endocam.study.observability import OBSERVABILITY_JSON, load_summary
    from endocam.study.report import write_outputs
    from endocam.study.responses import read_responses_csv

    outliers, tukey_k = study_plan.outlier_options(args)
    out = out_dir(args.out)
    try:
        manifest = load_manifest(args.manifest, check_files=False)
        if args.db is not None:
            try:  # read-only: the analysis never writes into its input
                rows = StudyDB(args.db, read_only=True).export_rows()
            except ValueError as exc:
                raise UsageError(f"--db: {exc}") from None
            if not rows:
                raise UsageError(f"--db: {args.db} has no answers to analyse")
        else:
            rows = read_responses_csv(args.responses)
        config = AnalysisConfig(all_videos=args.all_videos, outliers=outliers, tukey_k=tukey_k)
        manifest_path = Path(args.manifest)
        if manifest_path.is_dir():
            manifest_path = manifest_path / MANIFEST_NAME
        registered = study_plan.load_preregistration(args, manifest_path.parent)
        result = analyze(rows, manifest, config)
        obs_path = manifest_path.parent / OBSERVABILITY_JSON
        observability = load_summary(obs_path) if obs_path.is_file() else None
        written = write_outputs(result, args.out, observability)
    except ModuleNotFoundError as exc:
        raise UsageError(f"'study analyze' needs {exc.name}: {_EXTRA_HINT}") from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    for cond, s in result.conditions.items():
        mean = "–" if s.mean_error is None else f"{s.mean_error:.2f}"
        sd = "–" if s.sd_error is None else f"{s.sd_error:.2f}"
        print(f"{cond:12s} n={s.n:3d}  mean error {mean} touches  SD {sd}")
    for line in _assessor_lines(result):
        print(line)
    print(f"excluded: {len(result.excluded)}; wrote {', '.join(str(p) for p in written.values())}")
    n_analysed = result.tests.n_complete
    study_plan.report_preregistration(registered, manifest_path.parent, config, n_analysed, out)
    return 0


def _add_make(sub: argparse._SubParsersAction) -> None:
    from endocam.registry import POLICIES
    from endocam.study.manifest import DEFAULT_CONDITIONS  # (not study.make: MuJoCo, OpenCV)
    from endocam.task.study_paths import DEFAULT_STUDY_SEED as DEFAULT_SEED

    p = sub.add_parser(
        "make",
        help="render the study videos and write manifest.json",
        description="Simulate three noisy trajectories of increasing difficulty (36 points with "
        "5-10° angle noise, 36 and 71 points with the config's noise) with each camera "
        "condition; write videos/, manifest.json (presentation orders: a Williams design), "
        "design.json, observability.json/.csv, observer.json/.html, hypothesis.json and logs/ "
        "into --out (replaced atomically).",
    )
    p.add_argument(
        "--conditions",
        default=",".join(DEFAULT_CONDITIONS),
        metavar="P1,P2,...",
        help="the camera conditions, two or more distinct policy names, comma-separated "
        f"(choices: {', '.join(POLICIES)}; default: %(default)s, the paper's conditions I-III)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="study folder to write")
    p.add_argument("--config", metavar="FILE", help="TOML or YAML config (see `endocam config`)")
    p.add_argument(
        "--seed",
        type=int,
        default=DEFAULT_SEED,
        help="study seed: trajectory noise and video ids (default: %(default)s)",
    )
    p.add_argument(
        "--seeds",
        type=int,
        default=0,
        metavar="N",
        help="also render and observe N more seeds of the most difficult trajectory for "
        "hypothesis.json (default: %(default)s)",
    )
    p.add_argument(
        "--keep-seed-videos",
        action="store_true",
        help="keep the --seeds videos and true touches in seeds/<seed>/ so that `study observe` "
        "can count them again (default: deleted once counted)",
    )
    p.add_argument(
        "--workers",
        type=integer,
        default=DEFAULT_WORKERS,
        help="worker processes for the --seeds (1: in this process; default: %(default)s)",
    )
    p.add_argument(
        "--no-practice",
        dest="practice",
        action="store_false",
        help="write no practice video (default: videos/practice.mp4, the easiest trajectory "
        "with its own seed and the fixed camera, shown with feedback before the first set)",
    )
    p.set_defaults(handler=_make, runs_episodes=True)


def _add_serve(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "serve",
        help="run the study web app",
        description="Serve the study to participants (FastAPI + SQLite; needs endocam[study]).",
    )
    p.add_argument("--study", required=True, metavar="DIR", help="study folder with manifest.json")
    p.add_argument("--db", required=True, metavar="FILE", help="SQLite file (created if missing)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default: %(default)s)")
    p.add_argument("--port", type=int, default=8000, help="TCP port (default: %(default)s)")
    p.add_argument(
        "--admin-token",
        default=None,
        metavar="TOKEN",
        help=f"token for /admin and its exports (default: ${ADMIN_TOKEN_ENV}; none disables it)",
    )
    p.add_argument(
        "--abandon-after-min",
        type=float,
        default=ABANDON_AFTER_S / 60.0,
        metavar="MIN",
        help="minutes without activity after which an unfinished session is abandoned and no "
        "longer counts for counterbalancing (default: %(default)g)",
    )
    p.add_argument(
        "--secure-cookies",
        action="store_true",
        help="mark the session and admin cookies Secure (HTTPS only): set it when a reverse proxy "
        "serves the study over HTTPS (default: off, for plain http://127.0.0.1 tests)",
    )
    p.add_argument(
        "--trusted-proxy",
        default=None,
        metavar="ADDR[,ADDR]",
        help="reverse proxies (IP addresses or networks) whose X-Forwarded-For names the client, "
        "e.g. 127.0.0.1 for Caddy or nginx on the same machine (default: none, the peer "
        "address is the client)",
    )
    p.set_defaults(handler=_serve)


def _add_analyze(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "analyze",
        help="analyse the responses",
        description="Assessment errors, exclusions, Friedman + Wilcoxon-Holm tests, plot, report.",
    )
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--db", metavar="FILE", help="the study database")
    source.add_argument(
        "--responses",
        metavar="CSV",
        help="CSV with columns participant_id,video_id,reported_touches,attention_passed",
    )
    p.add_argument(
        "--manifest",
        required=True,
        metavar="FILE",
        help="the study's manifest.json (an observability.json beside it adds a report section)",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="output folder (created; an existing one must be empty or endocam's own)",
    )
    p.add_argument(
        "--all-videos",
        action="store_true",
        help="mean error over all videos of a condition (default: most difficult video only)",
    )
    study_plan.add_analysis_arguments(p)
    study_plan.add_preregistration_argument(p)
    p.set_defaults(handler=_analyze)


_SUBCOMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [
    _add_make,
    _add_serve,
    _add_analyze,
    _add_observe,
    _add_ideal_observer,
    study_plan.add_power,
    study_plan.add_simulate,
    study_plan.add_preregister,
]


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``study`` command group (``make``, ``serve``, ``analyze``) to the subparsers."""
    study = subparsers.add_parser(
        "study",
        help="video-based skill-assessment study",
        description="Run and analyse the video-based skill-assessment study (paper Sec. IV-D, V).",
    )
    sub = study.add_subparsers(dest="study_command", metavar="SUBCOMMAND")
    sub.required = True
    for add in _SUBCOMMANDS:
        add(sub)

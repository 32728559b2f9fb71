"""``endocam robot serve`` and ``endocam control``: the arm and the controller over Zenoh.

The library is :mod:`endocam.link` (the ``robot`` extra: ``eclipse-zenoh``, ``rosbags``).
``endocam control`` exits 0 after a whole episode, :data:`EXIT_LINK` (4) when the link failed
mid-episode (the run folder holds the steps done; ``link.json`` and the last line say why), 3
after a safety violation, 2 when no robot answered or it serves another world.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from endocam.cli.common import ARM_CHOICES, UsageError, integer, load_config_arg, out_dir
from endocam.registry import POLICIES
from endocam.robot.actuator import ArmKind
from endocam.runner.episode import DEFAULT_SEED, EpisodeSpec
from endocam.task.config import MAX_CONTROL_POINTS
from endocam.task.trajectory import TrajectoryKind

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
EXIT_LINK = 4
"""``endocam control``: the link failed mid-episode; the run is partial."""
LINK_JSON = "link.json"


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def _require() -> None:
    try:
        import rosbags.typesys  # noqa: F401
        import zenoh  # noqa: F401
    except ImportError:
        raise UsageError(
            "the link needs eclipse-zenoh and rosbags: pip install 'endocam[robot]'"
        ) from None


def _world_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--trajectory",
        default=TrajectoryKind.NOISY.value,
        choices=[k.value for k in TrajectoryKind],
        help="ring trajectory (default noisy)",
    )
    p.add_argument("--control-points", type=integer, default=71, help="control points (default 71)")
    p.add_argument(
        "--seed", type=integer, default=DEFAULT_SEED, help=f"noise seed (default {DEFAULT_SEED})"
    )
    p.add_argument("--config", help="TOML or YAML config file (see `endocam config`)")


def _spec(args: argparse.Namespace, policy: str) -> EpisodeSpec:
    if not 2 <= args.control_points <= MAX_CONTROL_POINTS:
        raise UsageError(
            f"--control-points must be in 2..{MAX_CONTROL_POINTS}, got {args.control_points}"
        )
    if args.seed < 0:
        raise UsageError(f"--seed must be ≥ 0, got {args.seed}")
    return EpisodeSpec(policy, TrajectoryKind(args.trajectory), args.control_points, args.seed)


def _endpoint(text: str) -> str:
    if (
        not text.startswith(("tcp/", "udp/", "unixsock-stream/"))
        or ":" not in text.split("/", 1)[1]
    ):
        raise UsageError(f"not a Zenoh endpoint (e.g. {DEFAULT_ENDPOINT}): {text!r}")
    return text


def _serve(args: argparse.Namespace) -> int:
    endpoint = _endpoint(args.endpoint)  # the cheap checks first
    spec = _spec(args, "fixed")
    _require()
    cfg = load_config_arg(args.config)
    kind = ArmKind(args.arm)
    from endocam.link.server import serve

    def ready() -> None:
        print(f"robot: {kind.value} serving on {endpoint}, waiting for a controller", flush=True)

    try:
        stats = serve(
            cfg,
            spec,
            kind,
            endpoint,
            watchdog=args.watchdog,
            wait=args.wait,
            ready=ready,
        )
    except TimeoutError as exc:
        print(f"robot: {exc}", file=sys.stderr)
        return 1
    print(
        f"robot: episode ended: {stats.steps} steps ({stats.commanded} commanded, "
        f"{stats.held} held), {stats.dropped} commands dropped, {len(stats.refused)} refused, "
        f"{stats.watchdog_trips} watchdog trips",
        flush=True,
    )
    return 0


def _control(args: argparse.Namespace) -> int:
    from endocam.link.client import LinkLostError, ZenohArm, run_remote
    from endocam.runner.episode import episode_arm
    from endocam.runner.outputs import write_run

    _require()
    robot = args.robot
    if robot != "zenoh" and not robot.startswith("zenoh:"):
        raise UsageError(f"--robot must be zenoh or zenoh:ENDPOINT, got {robot!r}")
    endpoint = _endpoint(robot.partition(":")[2] or DEFAULT_ENDPOINT)
    cfg = load_config_arg(args.config)
    if args.arm is not None:
        cfg = cfg.model_copy(
            update={"episode": cfg.episode.model_copy(update={"arm": ArmKind(args.arm)})}
        )
    spec = _spec(args, args.policy)
    out = out_dir(args.out)
    kind = episode_arm(cfg, args.policy)
    arm = ZenohArm(kind, endpoint, 1.0 / cfg.episode.control_rate, args.timeout)
    try:
        run = run_remote(cfg, spec, arm, args.wait)
    except LinkLostError as exc:
        raise UsageError(f"no episode over {endpoint}: {exc}") from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    finally:
        arm.close()
    write_run(run.result, out, video=not args.no_video)
    link = {
        "endpoint": endpoint,
        "steps": run.steps,
        "complete": run.lost is None,
        "lost": run.lost,
    }
    (Path(out) / LINK_JSON).write_text(json.dumps(link, indent=2) + "\n", encoding="utf-8")
    print(f"{spec.policy} over {endpoint}: {run.steps} steps -> {out}", flush=True)
    if run.lost is not None:
        print(f"link: {run.lost}", flush=True)
        return EXIT_LINK
    from endocam.cli.run import safety_exit

    return safety_exit(out)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``robot serve`` and ``control`` to the CLI."""
    r = sub.add_parser("robot", help="the simulated arm as a robot process (CRTK over Zenoh)")
    rsub = r.add_subparsers(dest="robot_command", metavar="COMMAND")
    rsub.required = True
    s = rsub.add_parser(
        "serve",
        help="serve one episode: the arm and the world, CRTK topics over Zenoh",
        description="Run the simulated arm and the wire-chaser world as a robot that speaks "
        "CRTK over Zenoh (ROS 2 CDR payloads, keys as zenoh-bridge-ros2dds maps topics). "
        "Waits for a controller, ends when the trajectory ends.",
    )
    s.add_argument("--arm", choices=ARM_CHOICES, required=True, help="the camera's carrier")
    _world_args(s)
    s.add_argument(
        "--endpoint", default=DEFAULT_ENDPOINT, help=f"listen here (default {DEFAULT_ENDPOINT})"
    )
    s.add_argument(
        "--watchdog",
        type=_number,
        default=0.1,
        help="hold after this many s without a command (default 0.1)",
    )
    s.add_argument(
        "--wait", type=_number, default=60.0, help="wait this many s for a controller (default 60)"
    )
    s.set_defaults(handler=_serve, runs_episodes=True)

    c = sub.add_parser(
        "control",
        help="run a policy against a robot over Zenoh and write the run folder",
        description="Run one episode of --policy against `endocam robot serve` (or a robot "
        "behind zenoh-bridge-ros2dds). Writes the same run folder as `endocam run`, plus "
        "link.json.",
    )
    c.add_argument(
        "--robot", default="zenoh", help=f"zenoh[:ENDPOINT] (default {DEFAULT_ENDPOINT})"
    )
    c.add_argument("--policy", required=True, choices=list(POLICIES), help="camera policy")
    c.add_argument(
        "--arm",
        choices=ARM_CHOICES,
        default=None,
        help="the robot's carrier (default: the config's)",
    )
    _world_args(c)
    c.add_argument("--out", required=True, help="output folder (replaced atomically)")
    c.add_argument("--no-video", action="store_true", help="skip rendering video.mp4")
    c.add_argument(
        "--timeout",
        type=_number,
        default=0.5,
        help="the robot is silent after this many s (default 0.5)",
    )
    c.add_argument(
        "--wait", type=_number, default=30.0, help="wait this many s for the robot (default 30)"
    )
    c.set_defaults(handler=_control, runs_episodes=True)

"""How much an episode's tracking errors move when its observed poses lose float64 round-off.

No link here: the same in-process episode twice, the second with the camera and ring poses the
policy observes and the pose it commands rounded through a quaternion and back (``Codec.pose``
/ ``decode_pose``: what the link's ``measured_cp``, ``ring/measured_cp`` and ``servo_cp`` do to
them, ~1e-16 relative; ``link_tracking.link_rounding``). A policy
whose decisions flip on such a difference (a planner's threshold) gives a different, equally
valid episode; the tracking errors of the two show how far a link run can differ from the
in-process one for that reason alone (``bench/link_tracking.py``).

Run::

    MUJOCO_GL=egl OMP_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/link_roundoff.py \\
        --arm psm --policy orientation --seeds 1 2 3
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from endocam.config import load_config
from endocam.link.client import registration
from endocam.robot.actuator import ArmKind
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.task.trajectory import TrajectoryKind
from link_tracking import errors, link_rounding  # bench/: as in the link's table


def main() -> None:
    """Parse the options, run each seed both ways, print the errors and their change."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--arm", default="psm", choices=[k.value for k in ArmKind])
    p.add_argument("--policy", default="orientation")
    p.add_argument("--duration", type=float, default=60.0, help="s (default 60)")
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    args = p.parse_args()
    config_file = Path(tempfile.mkdtemp()) / "c.toml"
    config_file.write_text(
        f'[task.trajectory]\nduration = {args.duration}\n[episode]\narm = "{args.arm}"\n',
        encoding="utf-8",
    )
    cfg = load_config(config_file)
    print(
        "seed | image_px exact rounded % | center_mm exact rounded % | orient_deg exact rounded %"
    )
    for seed in args.seeds:
        spec = EpisodeSpec(args.policy, TrajectoryKind.NOISY, 71, seed)
        rows = [tuple(errors(run_episode(cfg, spec)).values())]  # image px, centre mm, deg
        with link_rounding(registration(cfg, cfg.episode.arm)):
            rows.append(tuple(errors(run_episode(cfg, spec)).values()))
        cells = " | ".join(
            f"{a:.3f} {b:.3f} {100 * (b - a) / a:+.1f}" for a, b in zip(*rows, strict=True)
        )
        print(f"{seed} | {cells}", flush=True)


if __name__ == "__main__":
    main()

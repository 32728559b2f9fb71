"""Latency of the controller-robot link on this machine: round trip, cycle time, messages lost.

Starts ``endocam robot serve`` (a PSM by default) as a second process and drives it from this
one with a policy, paced at the control rate (the robot's lock-stepped clock then runs at wall
speed, as a real arm's would). Per control cycle:

- **round trip**: ``servo_cp`` sent → the next state received (the command's effect in
  ``measured_cp``: both serialisations, Zenoh both ways, the robot's carrier step);
- **cycle (own)**: the controller's own time — the policy's step plus the client's
  (de)serialisation — the cycle's time minus the time blocked waiting for the robot;
- **cycle (own CPU)**: the same, as the controller thread's CPU time (``time.thread_time``):
  endocam's own work without the time the OS gave other processes (a shared machine);
- **lost**: states that never arrived (the controller timed out) plus commands the robot
  dropped or refused (its last line).

A robot that stalls longer than the watchdog (or a controller timeout) ends the episode (the
link's safety rule); on a machine shared with other CPU-heavy work, measure with a watchdog and
timeout longer than the OS's scheduling stalls (``--watchdog 2 --timeout 3``) so the stalls show
as late cycles (``rt_over_10ms``, ``rt_max``) instead of ending the run.

Run (30 s at each rate; the issue's figure is 10 minutes: ``--duration 600``)::

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python bench/link_latency.py --duration 30 \\
        --rates 100 200 --arm psm --policy endocam
"""

from __future__ import annotations

import argparse
import os
import queue
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from endocam.config import load_config
from endocam.control.types import Observation, PolicyContext
from endocam.link.client import LinkLostError, ZenohArm, registration
from endocam.registry import make_policy
from endocam.robot.actuator import ArmKind
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.task.trajectory import TrajectoryKind
from endocam.view import look_distance

WAIT_S = 120.0  # s: the robot's start-up on a loaded machine
RT_TARGET_MS = 10.0  # ms: the round-trip p99 target (cycles above it are counted)


class TimedQueue(queue.Queue[Any]):
    """A queue that adds up the time its consumer spent blocked in ``get`` (s)."""

    blocked = 0.0

    def get(self, block: bool = True, timeout: float | None = None) -> Any:
        t0 = time.perf_counter()
        try:
            return super().get(block, timeout)
        finally:
            self.blocked += time.perf_counter() - t0


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (the robot's Zenoh endpoint)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def serve_robot(
    arm: str, config: Path, control_points: int, seed: int, limits: tuple[float, float]
) -> tuple[subprocess.Popen[str], str]:
    """``endocam robot serve`` as a second process on a free port: (the process, its endpoint).

    ``limits``: how long it waits for a controller and its watchdog (silence timeout), s
    (wall). Its standard output is a pipe (its last line says how the episode ended).
    """
    wait, watchdog = limits
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[1] / "src")}
    robot = subprocess.Popen(
        [
            *(sys.executable, "-m", "endocam.cli", "robot", "serve", "--arm", arm),
            *("--config", str(config), "--control-points", str(control_points)),
            *("--seed", str(seed), "--endpoint", endpoint),
            *("--wait", str(wait), "--watchdog", str(watchdog)),
        ],
        env=env,
        stdout=subprocess.PIPE,
        text=True,
    )
    return robot, endpoint


def run(
    rate: float, duration: float, arm_name: str, policy_name: str, limits: tuple[float, float]
) -> dict[str, Any]:
    """One paced episode at ``rate`` Hz for ``duration`` s; the figures of the module doc.

    ``limits``: the robot's watchdog and the controller's silence timeout, s (wall).
    """
    watchdog, timeout = limits
    folder = Path(tempfile.mkdtemp())
    config = folder / "link.toml"
    config.write_text(
        f"[task.trajectory]\nduration = {duration}\n[episode]\ncontrol_rate = {rate}\n"
        f'arm = "{arm_name}"\n',
        encoding="utf-8",
    )
    cfg = load_config(config)
    spec = EpisodeSpec(policy_name, TrajectoryKind.NOISY, 71, 1)
    warm = cfg.task.model_copy(
        update={"trajectory": cfg.task.trajectory.model_copy(update={"duration": 5.0})}
    )
    run_episode(cfg.model_copy(update={"task": warm}), spec)  # numba: load every kernel path
    robot, endpoint = serve_robot(
        arm_name, config, spec.control_points, spec.seed, (WAIT_S, watchdog)
    )
    kind = ArmKind(arm_name)
    dt = 1.0 / rate
    arm = ZenohArm(kind, endpoint, dt, timeout=timeout)
    arm.register(registration(cfg, kind))
    arm.inbox = TimedQueue()
    policy = make_policy(policy_name, cfg.controller)
    rt, own, cpu = [], [], []
    lost = 0
    failure = ""
    try:
        s = arm.connect(WAIT_S)
        from endocam.link.world import link_world

        lw = link_world(cfg, spec)
        policy.reset(
            PolicyContext(
                lw.camera,
                s.T_world_cam,
                s.T_world_ring,
                np.array(cfg.task.scene.rcm_position),
                dt,
                cfg.episode.sensing_latency,
                future=lw.trajectory.poses,
                future_duration=float(lw.trajectory.duration),
                follows_twist=arm.follows_twist,
                wire=lw.wire,
                ring=cfg.task.ring,
            )
        )
        jointed = bool(arm.joint_names)
        reach = None
        tick = time.perf_counter()
        for k in range(lw.world.n - 1):
            s = arm.state
            assert s is not None
            arm.inbox.blocked = 0.0
            t0 = time.perf_counter()
            c0 = time.thread_time()
            obs = Observation(
                k * dt, s.T_world_ring, s.T_world_cam, s.p_world_tips, reach, s.t_ring
            )
            cmd = policy.step(obs)
            look = look_distance(cmd.T_world_cam, s.T_world_ring, cmd.d_f) if jointed else cmd.d_f
            t1 = time.perf_counter()
            try:
                out = arm.step(cmd.T_world_cam, look, cmd.twist)
            except LinkLostError as exc:
                lost += 1
                t3 = time.perf_counter()
                failure = (
                    f"{exc} (that cycle: policy {1e3 * (t1 - t0):.1f} ms, then "
                    f"{1e3 * (t3 - t1):.1f} ms sending and waiting; "
                    f"{arm.received} messages received in all)"
                )
                break
            t2 = time.perf_counter()
            cpu.append(time.thread_time() - c0)
            if jointed:
                reach = out.T_world_target[:3, 3] - cmd.T_world_cam[:3, 3]
            rt.append(t2 - t1)
            own.append((t2 - t0) - arm.inbox.blocked)
            tick += dt
            pause = tick - time.perf_counter()
            if pause > 0:
                time.sleep(pause)
            else:
                tick = time.perf_counter()  # overran: the next cycle starts now
        else:
            arm.step(cmd.T_world_cam, look, cmd.twist)  # the last step: the robot ends
    finally:
        arm.close()
        if failure:
            robot.kill()
        out_text, _ = robot.communicate(timeout=60)
    last = out_text.strip().splitlines()[-1] if out_text.strip() else ""
    dropped = _count(last, "commands dropped") + _count(last, "refused")
    return {
        "rate": rate,
        "cycles": len(rt),
        "rt": np.array(rt),
        "own": np.array(own),
        "cpu": np.array(cpu),
        "lost": lost + dropped,
        "robot": last,
        "failure": failure,
    }


def _count(line: str, what: str) -> int:
    head = line.split(what)[0].rstrip().rsplit(" ", 1)[-1] if what in line else "0"
    return int(head) if head.isdigit() else 0


def main() -> None:
    """Parse the options, run each rate, print a table (ms)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=30.0, help="s per rate (default 30)")
    p.add_argument("--rates", type=float, nargs="+", default=[100.0, 200.0], help="Hz")
    p.add_argument("--arm", default="psm", choices=[k.value for k in ArmKind])
    p.add_argument("--policy", default="endocam")
    p.add_argument("--watchdog", type=float, default=0.1, help="the robot's, s (default 0.1)")
    p.add_argument(
        "--timeout", type=float, default=0.5, help="the controller's silence timeout, s (0.5)"
    )
    args = p.parse_args()
    print(
        "rate_hz cycles rt_p50_ms rt_p99_ms rt_max_ms own_p50_ms own_p99_ms own_max_ms "
        "own_cpu_p50_ms own_cpu_p99_ms rt_over_10ms lost"
    )
    for rate in args.rates:
        load0 = Path("/proc/loadavg").read_text().split()[:3]
        r = run(rate, args.duration, args.arm, args.policy, (args.watchdog, args.timeout))
        load1 = Path("/proc/loadavg").read_text().split()[:3]
        rt, own, cpu = r["rt"] * 1e3, r["own"] * 1e3, r["cpu"] * 1e3
        print(
            f"{rate:g} {r['cycles']} {np.median(rt):.2f} {np.percentile(rt, 99):.2f} "
            f"{rt.max():.2f} {np.median(own):.2f} {np.percentile(own, 99):.2f} "
            f"{own.max():.2f} {np.median(cpu):.2f} {np.percentile(cpu, 99):.2f} "
            f"{int((rt > RT_TARGET_MS).sum())} {r['lost']}",
            flush=True,
        )
        print(f"  robot: {r['robot'] or 'killed after the failure'}", flush=True)
        print(f"  /proc/loadavg (1, 5, 15 min) before {load0}, after {load1}", flush=True)
        if r["failure"]:
            print(f"  controller: {r['failure']}", flush=True)


if __name__ == "__main__":
    main()

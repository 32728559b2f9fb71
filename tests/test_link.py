"""The arm and the controller in two real processes over Zenoh (no transport mocks).

One robot process (``endocam robot serve``, free camera, a 2 s trajectory, its own localhost
port: peer to peer, no scouting) and this process as its controller, in one scenario (a robot
process costs seconds to start: one is shared):

1. while the robot waits for a controller: a malformed payload, a non-finite pose, a
   non-finite look distance and joints for the jointless free camera are refused, the robot
   stays up;
2. ``run_remote`` drives the episode: every step is the in-process episode's, to round-off;
3. at step :data:`STALL_AT` the controller stops commanding: the robot's watchdog holds the
   camera at rest, the controller's late command is dropped, and the controller holds too,
   saying the robot held;
4. the robot process is killed: the controller's next command finds it silent and holds.
"""

from __future__ import annotations

import itertools
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from endocam.config import ExperimentConfig, load_config
from endocam.link.client import LinkLostError, ZenohArm, run_remote
from endocam.link.messages import PAUSED, Codec, Keys
from endocam.link.server import LOOK_KEY
from endocam.robot.actuator import ActuatorStep, ArmKind
from endocam.runner.episode import EpisodeLog, EpisodeSpec, run_episode
from endocam.task.trajectory import TrajectoryKind

SHORT_TOML = "[task.trajectory]\nduration = 2.0\n"
SPEC = EpisodeSpec("orientation", TrajectoryKind.NOISY, 10, 3)
STALL_AT = 100  # the step the controller stops at (of 201)
HELD_STEPS = 45  # held states read: the free camera brakes to rest within ~30 (0.3 s)
DT = 0.01  # s: the default control period (100 Hz)
WAIT_S = 60.0  # s (wall) the robot may take to start (imports, numba's cache) on a loaded machine
TIMEOUT_S = 0.5  # s (wall): the controller's silence timeout
WATCHDOG_S = 0.1  # s (wall): the robot's
ATOL_M = 1e-12  # m: poses through a quaternion and back differ by float64 round-off only
ATOL_RAD = 1e-12  # rad


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _serve(config: Path, endpoint: str) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[1] / "src")}
    args = [sys.executable, "-m", "endocam.cli", "robot", "serve", "--arm", "free"]
    args += ["--config", str(config), "--control-points", "10", "--seed", "3"]
    args += ["--endpoint", endpoint, "--watchdog", str(WATCHDOG_S), "--wait", str(WAIT_S)]
    return subprocess.Popen(
        args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def _nan_pose(codec: Codec) -> bytes:
    """A ``PoseStamped`` with a NaN position, serialised as any ROS 2 sender would."""
    t = codec.t
    msg = t["geometry_msgs/msg/PoseStamped"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="world"
        ),
        pose=t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=float("nan"), y=0.0, z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
    )
    return bytes(codec.store.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped"))


class StallingArm(ZenohArm):
    """A controller that stops commanding for a while at step :data:`STALL_AT`."""

    def step(
        self, T_world_cmd: np.ndarray, look_distance: float, twist: np.ndarray | None = None
    ) -> ActuatorStep:
        assert self.state is not None
        if self.state.k == STALL_AT:
            time.sleep(3 * WATCHDOG_S)
        return super().step(T_world_cmd, look_distance, twist)


def _held_poses(arm: ZenohArm, keys: Keys, codec: Codec, count: int) -> list[np.ndarray]:
    """The next ``count`` camera poses the robot publishes while ``PAUSED`` (world, m)."""
    held: list[np.ndarray] = []
    paused = False
    while len(held) < count:
        key, data = arm.inbox.get(timeout=1.0)
        if key == keys.operating_state:
            paused = codec.decode_operating_state(data)[0] == PAUSED
        elif key == keys.measured_cp and paused:
            held.append(codec.decode_pose(data)[0])
    return held


def test_link_episode_refusals_watchdog_and_robot_killed(tmp_path: Path) -> None:
    config = tmp_path / "short.toml"
    config.write_text(SHORT_TOML, encoding="utf-8")
    endpoint = f"tcp/127.0.0.1:{_port()}"
    proc = _serve(config, endpoint)
    try:
        cfg = load_config(config)
        cfg = cfg.model_copy(
            update={"episode": cfg.episode.model_copy(update={"arm": ArmKind.FREE})}
        )
        local = run_episode(cfg, SPEC)  # while the robot starts
        _scenario(cfg, endpoint, proc, local.log)
    finally:
        if proc.poll() is None:
            proc.kill()
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL, err
    assert err.count("robot: refused") == 4, err
    assert "servo_jp: the free camera has no joints" in err
    assert "watchdog: no command" in err


def _scenario(
    cfg: ExperimentConfig, endpoint: str, proc: subprocess.Popen[str], local: EpisodeLog
) -> None:
    keys, codec = Keys.of(ArmKind.FREE), Codec()
    arm = StallingArm(ArmKind.FREE, endpoint, DT, TIMEOUT_S)
    try:
        # 1. bad messages while the robot waits: refused (counted on its stderr at the end)
        arm.connect(WAIT_S)
        arm.session.put(keys.servo_cp, b"\x00\x01\x00\x00garbage")
        arm.session.put(keys.servo_cp, _nan_pose(codec))
        arm.session.put(LOOK_KEY, codec.float64(float("inf")))
        arm.session.put(LOOK_KEY, codec.float64(0.05))  # a good look distance, then joints
        arm.session.put(keys.servo_jp, codec.joints(("j",), np.zeros(1), 0))  # for no joints
        # 2-3. the episode, stalled at STALL_AT by the controller
        remote = run_remote(cfg, SPEC, arm, WAIT_S)
        assert remote.steps == STALL_AT
        assert remote.lost is not None and "watchdog held the arm" in remote.lost
        a = remote.result.log
        n = remote.steps
        np.testing.assert_array_equal(a.t, local.t[:n])
        np.testing.assert_allclose(a.T_world_cam, local.T_world_cam[:n], rtol=0, atol=ATOL_M)
        np.testing.assert_allclose(a.T_world_cmd, local.T_world_cmd[:n], rtol=0, atol=ATOL_M)
        np.testing.assert_array_equal(a.state, local.state[:n])
        assert a.reason == list(local.reason[:n])
        # the robot holds: PAUSED, the camera brakes to rest
        held = _held_poses(arm, keys, codec, count=HELD_STEPS)
        moved = [np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in itertools.pairwise(held)]
        assert moved[0] > ATOL_M  # it was moving when the controller stopped ...
        assert max(moved[-10:]) <= ATOL_M  # ... and stands still now
        # 4. the robot dies mid-episode: the controller's next command finds it silent
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        while not arm.inbox.empty():  # what it said before it died
            arm.inbox.get()
        t0 = time.monotonic()
        with pytest.raises(LinkLostError, match="silent"):
            arm.step(held[-1], 0.05, None)
        assert time.monotonic() - t0 < TIMEOUT_S + 0.5
    finally:
        arm.close()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["robot", "serve", "--arm", "free", "--endpoint", "127.0.0.1:7447"], "Zenoh endpoint"),
        (["control", "--robot", "ros2", "--policy", "fixed", "--out", "x"], "--robot"),
        (["control", "--robot", "zenoh:tcp/nohost", "--policy", "fixed", "--out", "x"], "endpoint"),
    ],
)
def test_bad_link_options_are_one_line_and_exit_2(
    args: list[str],
    message: str,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from endocam.cli import main

    monkeypatch.chdir(tmp_path)  # nothing may be written: checked below
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not any(tmp_path.iterdir())

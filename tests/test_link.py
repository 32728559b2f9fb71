"""The arm and the controller in two real processes over Zenoh (no transport mocks).

One robot process (``endocam robot serve``, free camera, a 2 s trajectory, its own localhost
port: peer to peer, no scouting) and this process as its controller, in one scenario (a robot
process costs seconds to start: one is shared):

1. while the robot waits for a controller: a malformed payload, a non-finite pose, a
   non-finite look distance and joints for the jointless free camera are refused, the robot
   stays up;
2. ``run_remote`` drives the episode: every step is the in-process episode's, to round-off;
3. at step :data:`STALL_AT` the link pauses for :data:`LINK_PAUSE_S` (0.5 s: nothing is sent
   and what the robot says is lost): the robot's watchdog holds the camera at rest, the
   controller's late command is dropped, and the controller holds too, saying the robot held;
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
from endocam.link.client import LinkLostError, ZenohArm, registration, run_remote
from endocam.link.messages import PAUSED, Codec, Keys
from endocam.link.server import LOOK_KEY
from endocam.robot.actuator import ActuatorStep, ArmKind
from endocam.runner.episode import EpisodeLog, EpisodeSpec, run_episode
from endocam.task.trajectory import TrajectoryKind

SHORT_TOML = "[task.trajectory]\nduration = 2.0\n"
SPEC = EpisodeSpec("orientation", TrajectoryKind.NOISY, 10, 3)
STALL_AT = 100  # the step the link pauses at (of 201)
LINK_PAUSE_S = 0.5  # s (wall): the link is down this long
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


class PausedLinkArm(ZenohArm):
    """A controller whose link pauses for :data:`LINK_PAUSE_S` at step :data:`STALL_AT`.

    Nothing is sent during the pause and what the robot says in it never reaches the
    controller (kept aside in ``lost_in_pause`` for the test to read).
    """

    lost_in_pause: list[tuple[str, bytes]]

    def step(
        self, T_world_cmd: np.ndarray, look_distance: float, twist: np.ndarray | None = None
    ) -> ActuatorStep:
        assert self.state is not None
        if self.state.k == STALL_AT and not hasattr(self, "lost_in_pause"):  # once
            time.sleep(LINK_PAUSE_S)
            self.lost_in_pause = []
            while not self.inbox.empty():
                self.lost_in_pause.append(self.inbox.get())
        return super().step(T_world_cmd, look_distance, twist)


def _held_poses(arm: PausedLinkArm, keys: Keys, codec: Codec, count: int) -> list[np.ndarray]:
    """The first ``count`` camera poses the robot published while ``PAUSED`` (world, m)."""
    held: list[np.ndarray] = []
    paused = False
    said = iter(arm.lost_in_pause)
    while len(held) < count:
        key, data = next(said, None) or arm.inbox.get(timeout=1.0)
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
    arm = PausedLinkArm(ArmKind.FREE, endpoint, DT, TIMEOUT_S)
    try:
        # 1. bad messages while the robot waits: refused (counted on its stderr at the end)
        arm.connect(WAIT_S)
        arm.session.put(keys.servo_cp, b"\x00\x01\x00\x00garbage")
        arm.session.put(keys.servo_cp, _nan_pose(codec))
        arm.session.put(LOOK_KEY, codec.float64(float("inf")))
        arm.session.put(LOOK_KEY, codec.float64(0.05))  # a good look distance, then joints
        arm.session.put(keys.servo_jp, codec.joints(("j",), np.zeros(1), 0))  # for no joints
        # 2-3. the episode, the link paused at STALL_AT
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


JOINT_ATOL = 1e-6  # rad / m: the arm's IK converges to the joints of the commanded pose
SERVO_JP_STEPS = 60  # control periods to reach joints a few hundredths away (speed limits)


def test_an_arm_follows_servo_jp_and_refuses_joints_beyond_its_limits() -> None:
    """The robot's path for ``servo_jp`` (its gate and its carrier), on real CDR payloads."""
    from endocam.link.messages import stamp_ns
    from endocam.link.server import CommandGate, JointCommand, Verdict
    from endocam.robot.camera_arm import arm_model
    from endocam.robot.carriers import make_actuator
    from endocam.workspace.cone import ConeWorkspace
    from endocam.workspace.region import Workspace

    cfg = ExperimentConfig()
    scene = cfg.task.scene
    cone = ConeWorkspace.from_rcm(np.array(scene.rcm_position), [0.0, 0.0, 0.04], 0.3, 0.25)
    workspace = Workspace(cone, cfg.controller.min_camera_height)
    ep = cfg.episode
    arm = make_actuator(ArmKind.PSM, ep.limits, ep.T_tip_cam, scene.T_world_rcm, DT, workspace)
    arm.reset(*arm.start_view(cfg.task, cfg.camera.stereo()))
    keys, codec = Keys.of(ArmKind.PSM), Codec()
    gate = CommandGate(keys, JointCommand(ArmKind.PSM, arm), registration(cfg, ArmKind.PSM), DT)
    model = arm_model(ArmKind.PSM)
    q_cmd = np.clip(
        arm.q + np.array([0.03, -0.03, 0.004, 0.05, -0.05, 0.05]), model.lower, model.upper
    )
    measured = np.array(arm.q)
    for k in range(SERVO_JP_STEPS):
        gate.admit(LOOK_KEY, codec.float64(cfg.controller.d_f), k)
        a = gate.admit(keys.servo_jp, codec.joints(arm.joint_names, q_cmd, stamp_ns(k * DT)), k)
        assert a.verdict is Verdict.ACCEPTED and a.command is not None
        out = arm.step(a.command.T_world_cmd, a.command.look, a.command.twist)
        measured = codec.decode_joints(codec.joints(arm.joint_names, out.q, 0))  # measured_js
    np.testing.assert_allclose(measured, q_cmd, rtol=0, atol=JOINT_ATOL)
    beyond = q_cmd.copy()
    beyond[1] = model.upper[1] + 0.01
    k = SERVO_JP_STEPS
    gate.admit(LOOK_KEY, codec.float64(cfg.controller.d_f), k)
    refused = gate.admit(keys.servo_jp, codec.joints(arm.joint_names, beyond, stamp_ns(k * DT)), k)
    assert refused.verdict is Verdict.REFUSED and "joints [1] beyond limits" in refused.why

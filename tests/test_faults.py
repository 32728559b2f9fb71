"""Fault injection: seeded schedules, the observation gate, the carriers' workspace guard, and a
property test: random fault schedules on every carrier leave ``endocam check`` nothing to report."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from endocam.config import ExperimentConfig
from endocam.control.config import ControllerConfig
from endocam.control.gate import outlier_detected
from endocam.faults import (
    FAULT_NAMES,
    FaultsConfig,
    apply_observation_faults,
    fault_names,
    fault_schedule,
)
from endocam.robot.actuator import ArmKind
from endocam.robot.carriers import make_actuator
from endocam.runner.check import ARRIVED_TOL_M, check_run
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.runner.outputs import write_run
from endocam.task.trajectory import TrajectoryKind, make_trajectory
from endocam.workspace.cone import ConeWorkspace
from endocam.workspace.region import Workspace

DT = 0.01  # s: the default control period
N = 1000  # control steps of a 10 s schedule
PROPERTY_DURATION_S = 3.0  # s: the property test's short episodes
SHORT_EPISODE_S = 8.0  # s: a ring slow enough for a 15° outlier to stand out step to step
MM = 1e-3  # m
MAX_REFUSED_TRUE = 0.15  # fraction of fault-free steps refused (a 15° burst: 13 % measured)


def _faults(**on: dict[str, float]) -> FaultsConfig:
    return FaultsConfig.model_validate({"seed": 5, **on})


def test_schedule_is_seeded_and_starts_after_start_after() -> None:
    cfg = _faults(ring_dropout={"rate": 2.0, "burst": 0.1}, tip_dropout={"rate": 1.0})
    a = fault_schedule(cfg, N, DT, arm=False).labels()
    b = fault_schedule(cfg, N, DT, arm=False).labels()
    assert (a == b).all()
    other = fault_schedule(cfg.model_copy(update={"seed": 6}), N, DT, arm=False).labels()
    assert (a != other).any()
    first = min(k for k, label in enumerate(a) if label)
    assert first * DT >= cfg.start_after
    assert {name for label in a for name in fault_names(label)} == {"ring_dropout", "tip_dropout"}


def test_arm_faults_only_on_an_arm() -> None:
    cfg = _faults(joint_stall={"rate": 2.0}, goal_beyond_reach={"rate": 2.0})
    assert fault_schedule(cfg, N, DT, arm=False).empty
    labels = fault_schedule(cfg, N, DT, arm=True, joints=6).labels()
    stalled = {label.split("joint_stall:")[1][0] for label in labels if "joint_stall" in label}
    assert stalled and stalled <= set("012345")


def test_observation_faults_rewrite_the_sensed_poses() -> None:
    t = np.arange(N) * DT
    T = np.tile(np.eye(4), (N, 1, 1))
    T[:, 0, 3] = 0.01 * t  # a ring moving 10 mm/s along x
    tips = np.zeros((N, 2, 3))
    cfg = _faults(
        ring_dropout={"rate": 1.0, "burst": 0.1},
        ring_outlier={"rate": 1.0, "burst": 0.1, "distance": 2.0, "angle": math.pi},
        tracker_frozen={"rate": 1.0, "burst": 0.3},
        tip_dropout={"rate": 1.0, "burst": 0.2},
    )
    schedule = fault_schedule(cfg, N, DT, arm=False)
    T_f, tips_f, t_ring = apply_observation_faults(schedule, t, T, tips, lambda ts: T[:1], 0.05)
    drop, out = schedule.mask("ring_dropout"), schedule.mask("ring_outlier")
    frozen = schedule.mask("tracker_frozen") & ~drop & ~out
    assert np.isnan(T_f[drop]).all() and np.isfinite(T_f[~drop]).all()
    wild = out & ~drop & ~schedule.mask("tracker_frozen")  # an outlier of the true pose
    assert wild.any()
    gap = np.linalg.norm(T_f[wild, :3, 3] - T[wild, :3, 3], axis=1)
    assert np.allclose(gap, 2.0)
    trace = np.einsum("nij,nij->n", T_f[wild, :3, :3], T[wild, :3, :3])  # tr(R_f^T R)
    assert np.allclose(trace, -1.0)  # turned half a turn: 1 + 2 cos π
    assert frozen.any()
    for b in schedule.bursts["tracker_frozen"]:  # one pose repeated through each burst
        x = T_f[b.start : b.stop, 0, 3][frozen[b.start : b.stop]]
        assert np.all(x == T[b.start, 0, 3])
    assert np.isnan(tips_f[schedule.mask("tip_dropout")]).all()
    untouched = ~(drop | out | schedule.mask("tracker_frozen"))
    assert np.array_equal(T_f[untouched], T[untouched])
    # capture stamps: the sensing delay, except that a frozen tracker keeps its pose's stamp
    on_time = ~schedule.mask("tracker_frozen")
    assert np.array_equal(t_ring[on_time], np.clip(t - 0.05, 0.0, None)[on_time])
    for b in schedule.bursts["tracker_frozen"]:
        assert np.all(t_ring[b.start : b.stop] == t_ring[b.start])
        assert t[b.stop - 1] - t_ring[b.stop - 1] >= 0.05 + (b.stop - 1 - b.start) * DT - 1e-12


def test_gate_rejects_a_wild_pose_and_reacquires_a_moved_ring() -> None:
    cfg = ControllerConfig()
    gate = cfg.ring_gate()
    n = (0.0, 0.0, 1.0)
    assert gate.accept(0.0, (0.0, 0.0, 0.05), n)
    assert gate.accept(DT, (0.0001, 0.0, 0.05), n)  # 10 mm/s: plausible
    assert not gate.accept(2 * DT, (1.0, 0.0, 0.05), n)  # a metre away
    assert not gate.accept(3 * DT, (0.0003, 0.0, 0.05), (0.0, 0.0, -1.0))  # turned 180°
    assert gate.accept(4 * DT, (0.0004, 0.0, 0.05), n)  # back on the predicted track
    # lost: the ring seen 0.2 m away, steadily; taken once that run lasted ring_reacquire
    far = (0.2, 0.0, 0.05)
    steps = round(cfg.ring_reacquire / DT)
    answers = [gate.accept((5 + k) * DT, far, n) for k in range(steps + 1)]
    assert not any(answers[:-1]) and answers[-1]


OUTLIER_SIZES = [(0.01, 0.0), (0.02, 0.0), (0.05, 0.0), (0.0, 5.0), (0.0, 15.0)]  # m, deg


@pytest.mark.parametrize(("distance", "angle_deg"), OUTLIER_SIZES)
def test_small_outliers_are_refused_however_long_they_last(
    distance: float, angle_deg: float
) -> None:
    """The issue's faults (bursts of 0.3 s, 0.5/s) on a 20 s ring trajectory: no outlier is
    accepted (the allowance does not grow with the time refused), and the true ring is taken
    back after nearly every burst."""
    cfg = ExperimentConfig()
    data = cfg.task.model_dump(mode="json")
    data["trajectory"]["duration"] = 20.0  # the fault matrix's pace
    task = type(cfg.task).model_validate(data)
    latency = cfg.episode.sensing_latency
    acted = refused_true = 0
    for seed in (1, 2):
        trajectory = make_trajectory(task, TrajectoryKind.NOISY, 36, seed)
        t = np.arange(round(20.0 / DT) + 1) * DT
        T = trajectory.poses(np.clip(t - latency, 0.0, None))
        faults = _faults(
            ring_outlier={
                "rate": 0.5,
                "burst": 0.3,
                "distance": distance,
                "angle": math.radians(angle_deg),
            }
        ).model_copy(update={"seed": seed})
        schedule = fault_schedule(faults, len(t), DT, arm=False)
        T_f, _, t_ring = apply_observation_faults(
            schedule, t, T, np.zeros((len(t), 0, 3)), trajectory.poses, latency
        )
        outlier = schedule.mask("ring_outlier")
        gate = cfg.controller.ring_gate()
        gate.reset()
        ok = np.array([gate.accept(t_ring[k], T_f[k, :3, 3], T_f[k, :3, 2]) for k in range(len(t))])
        acted += int(np.sum(ok & outlier))
        refused_true += int(np.sum(~ok & ~outlier))
    assert acted == 0
    assert refused_true <= MAX_REFUSED_TRUE * 2 * len(t)


def test_check_and_gate_share_the_outlier_definition() -> None:
    """An outlier within the gate's caps is not one the check requires a hold on."""
    limits = ControllerConfig().ring_limits
    assert outlier_detected(0.01, 0.0, limits) and outlier_detected(0.0, math.radians(5), limits)
    assert not outlier_detected(0.5 * limits.position_gate, 0.5 * limits.angle_gate, limits)


@pytest.mark.parametrize("kind", [ArmKind.FREE, ArmKind.PSM])
def test_carrier_never_takes_the_camera_below_the_floor(kind: ArmKind) -> None:
    cfg = ExperimentConfig()
    floor = cfg.controller.min_camera_height
    scene = cfg.task.scene
    p_rcm = np.array(scene.rcm_position)
    cone = ConeWorkspace.from_rcm(p_rcm, [0.0, 0.0, 0.04], 0.3, 0.25)
    actuator = make_actuator(
        kind,
        cfg.episode.limits,
        cfg.episode.T_tip_cam,
        scene.T_world_rcm,
        DT,
        Workspace(cone, floor),
    )
    T = actuator.reset(*actuator.start_view(cfg.task, cfg.camera.stereo()))
    assert T[2, 3] > floor
    goal = np.array(T)
    goal[2, 3] = floor - 20 * MM  # commanded 2 cm under the floor, straight down
    z = [actuator.step(goal, 0.05).T_world_cam[2, 3] for _ in range(300)]
    assert min(z) >= floor
    assert min(z) < floor + 20 * MM  # it did go down, as far as the floor allowed


_rates = st.sampled_from([0.0, 0.0, 0.5, 2.0])
_bursts = st.floats(min_value=0.01, max_value=0.5)


@st.composite
def fault_sections(draw: st.DrawFn) -> FaultsConfig:
    data: dict[str, Any] = {"seed": draw(st.integers(0, 2**16)), "start_after": 0.5}
    for name in FAULT_NAMES:
        data[name] = {"rate": draw(_rates), "burst": draw(_bursts)}
    return FaultsConfig.model_validate(data)


# Found by this test (round 5): ruckig refused a joint state of the ECM whose braking distance
# equalled the distance to its target (robot.arm.SimulatedArm._retry).
RUCKIG_EDGE = FaultsConfig.model_validate(
    {
        "seed": 368,
        "start_after": 0.5,
        "ring_nan": {"rate": 2.0, "burst": 0.46875},
        "ring_outlier": {"rate": 2.0, "burst": 0.078125, "distance": 1.0, "angle": math.pi},
        "latency_spike": {"rate": 0.5, "burst": 0.1015625, "extra_delay": 0.2},
        "tip_dropout": {"rate": 0.5, "burst": 0.5},
    }
)


@pytest.mark.parametrize("arm", [k.value for k in ArmKind])
@settings(
    max_examples=3,
    deadline=None,
    derandomize=True,  # the same schedules on every run (CI stays reproducible)
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(faults=fault_sections())
@example(faults=RUCKIG_EDGE)
def test_random_fault_schedules_leave_no_violation(
    arm: str, faults: FaultsConfig, tmp_path: Path
) -> None:
    data = ExperimentConfig().model_dump(mode="json")
    data["task"]["trajectory"]["duration"] = PROPERTY_DURATION_S
    data["episode"]["arm"] = arm
    data["faults"] = faults.model_dump(mode="json")
    cfg = ExperimentConfig.model_validate(data)
    result = run_episode(cfg, EpisodeSpec("endocam", TrajectoryKind.NOISY, 36, 1))
    out = tmp_path / f"run-{faults.seed}"
    write_run(result, out, video=False)
    check = check_run(out)
    assert check.ok, check.summary() + "".join(f"\n{v.line()}" for v in check.violations[:5])


def test_gate_reacquires_only_inside_the_workspace() -> None:
    cfg = ControllerConfig()
    gate = cfg.ring_gate()
    gate.reset(lambda p: abs(p[0]) < 0.3)  # a workspace 0.3 m wide along x
    n = (0.0, 0.0, 1.0)
    assert gate.accept(0.0, (0.0, 0.0, 0.05), n)
    t = 2 * cfg.ring_reacquire  # lost for long; then a self-consistent pose 1 m away
    steps = round(cfg.ring_reacquire / DT) + 1
    assert not any(gate.accept(t + k * DT, (1.0, 0.0, 0.05), n) for k in range(2 * steps))
    t += 2 * steps * DT  # agreeing for long, but outside: not the ring; then 0.2 m away
    answers = [gate.accept(t + k * DT, (0.2, 0.0, 0.05), n) for k in range(steps)]
    assert not any(answers[:-1]) and answers[-1]  # inside and agreeing: re-acquired


def test_latency_spikes_stamp_older_poses() -> None:
    t = np.arange(N) * DT
    T = np.tile(np.eye(4), (N, 1, 1))
    cfg = _faults(latency_spike={"rate": 1.0, "burst": 0.3, "extra_delay": 0.2})
    schedule = fault_schedule(cfg, N, DT, arm=False)
    _, _, t_ring = apply_observation_faults(
        schedule, t, T, np.zeros((N, 2, 3)), lambda ts: T[:1], 0.05
    )
    spike = schedule.mask("latency_spike")
    assert spike.any()
    np.testing.assert_allclose(t[spike] - t_ring[spike], 0.25, atol=1e-12)
    assert np.array_equal(t_ring[~spike], np.clip(t - 0.05, 0.0, None)[~spike])


@pytest.mark.parametrize("arm", ["free", "psm"])
def test_a_frozen_tracker_is_held_once_its_pose_is_too_old(arm: str, tmp_path: Path) -> None:
    """The tracker repeats one pose for 1 s: the camera acts on it only while it is fresh."""
    data = ExperimentConfig().model_dump(mode="json")
    data["task"]["trajectory"]["duration"] = PROPERTY_DURATION_S
    data["episode"]["arm"] = arm
    data["faults"] = {"seed": 3, "tracker_frozen": {"rate": 0.5, "burst": 1.0}}
    cfg = ExperimentConfig.model_validate(data)
    result = run_episode(cfg, EpisodeSpec("endocam", TrajectoryKind.NOISY, 36, 1))
    schedule = fault_schedule(cfg.faults, len(result.log.t), DT, arm=arm != "free")
    max_age, latency = cfg.controller.ring_max_age, cfg.episode.sensing_latency
    stale_steps = 0
    for b in schedule.bursts["tracker_frozen"]:
        for k in range(b.start, b.stop):
            age = result.log.t[k] - (result.log.t[b.start] - latency)
            if age > max_age + 1e-9:
                assert result.log.state[k] == "lost_tracking", (k, age)
                stale_steps += 1
    assert stale_steps > 0  # the schedule has a burst longer than ring_max_age
    out = tmp_path / "run"
    write_run(result, out, video=False)
    assert check_run(out).ok


def test_sensing_latency_must_be_below_the_ring_max_age() -> None:
    data = ExperimentConfig().model_dump(mode="json")
    data["episode"]["sensing_latency"] = data["controller"]["ring_max_age"]
    with pytest.raises(ValueError, match="ring_max_age"):
        ExperimentConfig.model_validate(data)


def test_small_outliers_in_a_short_episode_never_move_the_command(tmp_path: Path) -> None:
    """A short free-camera episode under 2 cm and 15° outliers: the command stands still at
    every outlier step (the camera only ever follows the true ring), and the check is clean."""
    data = ExperimentConfig().model_dump(mode="json")
    data["task"]["trajectory"]["duration"] = SHORT_EPISODE_S
    data["episode"]["arm"] = "free"
    data["faults"] = {
        "seed": 1,
        "start_after": 0.5,
        "ring_outlier": {"rate": 2.0, "burst": 0.3, "distance": 0.02, "angle": math.radians(15)},
    }
    cfg = ExperimentConfig.model_validate(data)
    result = run_episode(cfg, EpisodeSpec("endocam", TrajectoryKind.NOISY, 36, 1))
    out = tmp_path / "run"
    write_run(result, out, video=False)
    check = check_run(out)
    assert check.ok, check.summary()
    cmd = result.log.T_world_cmd[:, :3, 3]
    jump = np.r_[0.0, np.linalg.norm(np.diff(cmd, axis=0), axis=1)]
    outlier = np.array(["ring_outlier" in fault_names(f) for f in result.log.fault])
    assert outlier.sum() >= 2 * round(0.3 / DT)  # at least two bursts
    assert np.all(jump[outlier] <= ARRIVED_TOL_M)

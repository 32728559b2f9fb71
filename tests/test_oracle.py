"""The oracle: no sensing delay, the true future, a side plan; it keeps the safety rules."""

from __future__ import annotations

import math

import numpy as np
import pytest

from endocam.config import CameraConfig, ExperimentConfig
from endocam.control.config import ControllerConfig, TrackerConfig
from endocam.control.policies import EndocamPolicy
from endocam.control.policies.oracle import OracleConfig, OraclePolicy, plan_sides
from endocam.control.types import Observation, PolicyContext, TrackingState
from endocam.robot.actuator import ArmKind
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.task.trajectory import TrajectoryKind
from endocam.workspace.cone import ConeWorkspace

DT = 0.01  # s, control period
LATENCY = 0.05  # s, the causal policies' sensing delay (the episode's default)
DURATION = 3.0  # s, span of the synthetic future
V_RING = np.array([0.05, 0.01, 0.0])  # m/s, constant ring velocity
ORACLE_TOL_M = 1e-5  # m: the oracle's goal error on a constant-velocity ring (interpolation)
LAG_MIN_M = 0.5 * float(np.linalg.norm(V_RING)) * LATENCY  # m: a delayed causal goal lags v·τ
CONE_TOL_M = 1e-6  # m: round-off on the cone margin of a commanded position
HEIGHT_TOL_M = 1e-6  # m: round-off on the commanded height
NO_TIPS = np.zeros((0, 3))  # no instrument known: the working distance holds
P0 = np.array([0.0, 0.0, 0.06])  # m, ring start
N_RING = np.array([1.0, 0.0, 0.6])  # ring normal (tilted up)


def ring_pose(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(4, 4) ring pose with unit normal ``n`` as its z axis at ``p`` (m)."""
    z = n / np.linalg.norm(n)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = p
    return T


def true_poses(ts: np.ndarray) -> np.ndarray:
    """(N, 4, 4) the constant-velocity ring at times ``ts`` (N,), s (clamped to the span)."""
    t = np.clip(np.asarray(ts, dtype=float), 0.0, DURATION)
    return np.stack([ring_pose(P0 + V_RING * ti, N_RING) for ti in t])


def context(future: bool = True) -> PolicyContext:
    T_cam = np.eye(4)
    T_cam[:3, 3] = P0 + np.array([0.05, 0.0, 0.03])
    return PolicyContext(
        CameraConfig().stereo(),
        T_cam,
        true_poses(np.zeros(1))[0],
        P0 + np.array([0.0, 0.0, 0.25]),
        DT,
        LATENCY,
        future=true_poses if future else None,
        future_duration=DURATION if future else 0.0,
    )


def run(policy: EndocamPolicy, sensed: bool = True) -> list[np.ndarray]:
    """Commands over 2 s with a perfect carrier; the sensed pose is 50 ms late (or missing)."""
    policy.reset(context())
    T_cam = policy._last_cmd
    assert T_cam is not None
    cmds = []
    for k in range(200):
        t = k * DT
        ring = true_poses(np.array([t - LATENCY]))[0] if sensed else None
        cmd = policy.step(Observation(t, ring, T_cam, NO_TIPS))
        assert cmd.state is TrackingState.TRACKING
        T_cam = cmd.T_world_cam
        cmds.append(T_cam)
    return cmds


def goal_error(policy: EndocamPolicy, cmds: list[np.ndarray], lead: float) -> float:
    """Distance of the last command from the goal of the true ring ``lead`` s later, m."""
    t = 199 * DT + lead
    ref = EndocamPolicy(policy.config)
    ref.reset(context())
    p = P0 + V_RING * t
    n = N_RING / np.linalg.norm(N_RING)
    errors = []
    for s in (1.0, -1.0):  # either side of the ring: the camera at p + s d n
        want = ref._pose(tuple(p), tuple(s * n), policy.d_f, cmds[-1])
        errors.append(float(np.linalg.norm(cmds[-1][:3, 3] - want[:3, 3])))
    return min(errors)


def test_oracle_has_no_sensing_delay_and_uses_the_future() -> None:
    oracle = OraclePolicy()
    cmds = run(oracle)
    assert goal_error(oracle, cmds, oracle.tracker.carrier_lead) < ORACLE_TOL_M
    causal = EndocamPolicy(ControllerConfig(tracker=TrackerConfig(predict=False)))
    lagging = run(causal)
    assert goal_error(causal, lagging, 0.0) > LAG_MIN_M


def test_oracle_ignores_the_sensed_pose() -> None:
    with_sensing = run(OraclePolicy())
    without = run(OraclePolicy(), sensed=False)
    np.testing.assert_array_equal(with_sensing[-1], without[-1])


def test_oracle_needs_the_future() -> None:
    with pytest.raises(ValueError, match="future"):
        OraclePolicy().reset(context(future=False))


def test_side_plan_switches_only_when_it_pays() -> None:
    cost = np.ones((30, 2))
    cost[:10, 0] = cost[20:, 0] = 0.0  # side +1 is free at the ends (20 steps)
    cost[10:20, 1] = 0.0  # side −1 is free in the middle (10 steps)
    assert plan_sides(cost, 100.0) == [1.0] * 30  # two switches cost more than 10
    plan = plan_sides(cost, 2.0)
    assert plan[:10] == [1.0] * 10 and plan[10:20] == [-1.0] * 10 and plan[20:] == [1.0] * 10


def test_oracle_config_rejects_a_zero_lead() -> None:
    with pytest.raises(ValueError, match="lead"):
        OracleConfig(lead=0.0)


@pytest.mark.parametrize("arm", [ArmKind.FREE, ArmKind.PSM])
def test_oracle_commands_stay_in_the_cone_and_above_the_board(arm: ArmKind) -> None:
    data = ExperimentConfig().model_dump()
    data["task"]["trajectory"]["duration"] = 8.0
    data["episode"]["arm"] = arm.value
    cfg = ExperimentConfig.model_validate(data)
    result = run_episode(cfg, EpisodeSpec("oracle", TrajectoryKind.NOISY, 36, 3))
    log = result.log
    ctl = cfg.controller
    cone = ConeWorkspace.from_rcm(
        np.array(cfg.task.scene.rcm_position),
        log.T_world_ring_sensed[0][:3, 3],
        ctl.cone_height,
        ctl.cone_base_radius,
    )
    moving = np.isin(log.state, ["tracking", "planning", "unreachable"])
    assert moving.mean() > 0.5  # the check below covers most of the episode
    for T in log.T_world_cmd[moving]:
        assert cone.margin(T[:3, 3]) >= -CONE_TOL_M
        assert T[2, 3] >= ctl.min_camera_height - HEIGHT_TOL_M
    assert math.isfinite(float(np.mean(result.center_error)))

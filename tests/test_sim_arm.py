"""The camera carried by a dVRK arm in the episode runner (endocam.robot.camera_arm, issue 4)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from endocam.config import ExperimentConfig
from endocam.geometry import invert_pose, make_pose
from endocam.registry import POLICIES
from endocam.robot import PSM_MAX_VELOCITY
from endocam.robot.actuator import ActuatorStatus, ArmKind
from endocam.robot.arm_guard import stop_point
from endocam.robot.arm_targets import VIEW_BISECTIONS, view_towards_port
from endocam.robot.camera_arm import CameraArm, natural_pose
from endocam.robot.carriers import arm_mount
from endocam.robot.dh import chain_frames
from endocam.robot.kinematics import LIMIT_SLACK
from endocam.runner.episode import UNREACHABLE, EpisodeResult, EpisodeSpec, episode_arm, run_episode
from endocam.runner.outputs import episode_columns
from endocam.task.trajectory import TrajectoryKind
from endocam.workspace.cone import ConeWorkspace
from endocam.workspace.region import Workspace

ATOL_M = 1e-9  # m: logged camera position vs FK(logged q), round-off only
ATOL_R = 1e-9  # 1: logged rotation-matrix entries vs FK(logged q)
RESIDUAL_ZERO_RAD = 1e-7  # rad: the ECM IK's tolerance for "orientation reached"
ROUNDOFF_RAD = 1e-9  # rad: angles computed two ways on the same poses, round-off only
ACOS_RESOLUTION_RAD = 1e-7  # rad: acos of a cosine within round-off of 1 (≈ 1.5e-8 rad)
REST_SPEED = 1e-12  # rad/s or m/s: ruckig's round-off on a joint at rest
IK_TOL = 1e-7  # m / rad: the IK tolerance (endocam.robot.ik.IK_POSITION_TOL_M)
SPEED_RTOL = 1e-6  # relative slack on a joint speed limit (round-off of ruckig's profiles)
DURATION_S = 3.0  # s: short episodes keep the file fast
# A 3 s pass turns the ring's normal faster than the observation gate's bounds allow (they
# cover ~8 s episodes and longer, docs/safety.md): these arm tests open the gate wide.
GATE_OPEN = {
    "ring_max_speed": 10.0,
    "ring_max_rate": 1000.0,
    "ring_max_acceleration": 1e6,
    "ring_max_angular_acceleration": 1e8,
    "ring_gate_position": 10.0,
    "ring_gate_angle": math.pi,
}


def _config(arm: str = "free", **scene: object) -> ExperimentConfig:
    data: dict[str, object] = {
        "task": {"trajectory": {"duration": DURATION_S}},
        "episode": {"arm": arm},
        "controller": GATE_OPEN,
    }
    if scene:
        data["task"] = {"trajectory": {"duration": DURATION_S}, "scene": scene}
    return ExperimentConfig.model_validate(data)


def _run(policy: str, arm: str, kind: str = "noisy", **scene: object) -> EpisodeResult:
    return run_episode(_config(arm, **scene), EpisodeSpec(policy, TrajectoryKind(kind), 71, 1))


def _arm_for(result: EpisodeResult) -> CameraArm:
    cfg = result.config
    kind = ArmKind(result.log.arm)
    T_rcm, T_tip_cam = arm_mount(kind, cfg.episode.T_tip_cam, cfg.task.scene.T_world_rcm)
    dt = 1.0 / cfg.episode.control_rate
    return CameraArm(kind, T_rcm, T_tip_cam, dt)


@pytest.fixture(scope="module")
def psm_result() -> EpisodeResult:
    return _run("orientation", "psm")


@pytest.fixture(scope="module")
def ecm_result() -> EpisodeResult:
    return _run("orientation-ecm", "free")


@pytest.mark.parametrize("which", ["psm_result", "ecm_result"])
def test_logged_camera_pose_is_fk_of_logged_joints(which: str, request: pytest.FixtureRequest):
    result = request.getfixturevalue(which)
    log = result.log
    assert log.joints is not None and log.joints.shape == (len(log.t), len(log.joint_names))
    T_fk = _arm_for(result).camera_poses(log.joints)
    np.testing.assert_allclose(T_fk[:, :3, 3], log.T_world_cam[:, :3, 3], rtol=0, atol=ATOL_M)
    np.testing.assert_allclose(T_fk[:, :3, :3], log.T_world_cam[:, :3, :3], rtol=0, atol=ATOL_R)
    assert np.ptp(log.joints, axis=0).max() > 1e-3  # the arm actually moved


@pytest.mark.parametrize("which", ["psm_result", "ecm_result"])
def test_joint_limits_never_exceeded(which: str, request: pytest.FixtureRequest):
    result = request.getfixturevalue(which)
    model = _arm_for(result).model
    q = result.log.joints
    assert q is not None
    assert np.all(q >= model.lower - LIMIT_SLACK) and np.all(q <= model.upper + LIMIT_SLACK)


def test_joint_speeds_within_the_arm_limits(psm_result: EpisodeResult):
    q = psm_result.log.joints
    assert q is not None
    qd = np.abs(np.diff(q, axis=0)) / np.diff(psm_result.log.t)[:, None]
    assert np.all(qd <= np.array(PSM_MAX_VELOCITY) * (1.0 + SPEED_RTOL))
    assert qd.max() > 0.0


def test_joint_columns_in_episode_csv(psm_result: EpisodeResult):
    cols = episode_columns(psm_result)
    names = [f"q_{n}" for n in psm_result.log.joint_names]
    assert names == [c for c in cols if c.startswith("q_")]
    assert "q_outer_insertion" in names


def test_orientation_ecm_forces_the_ecm(ecm_result: EpisodeResult):
    assert POLICIES["orientation-ecm"].arm is ArmKind.ECM
    assert episode_arm(_config("psm"), "orientation-ecm") is ArmKind.ECM
    assert episode_arm(_config("psm"), "orientation") is ArmKind.PSM
    assert episode_arm(_config(), "orientation") is ArmKind.FREE
    assert ecm_result.log.arm == "ecm"
    assert ecm_result.log.joint_names == ("yaw", "pitch", "insertion", "roll")
    assert np.all(np.isfinite(ecm_result.orientation_error))
    with pytest.raises(ValueError, match="unknown policy"):
        episode_arm(_config(), "nope")


def test_free_camera_logs_no_joints():
    result = run_episode(
        _config().model_copy(
            update={"task": _config().task.model_copy(update={"trajectory": _short(1.0)})}
        ),
        EpisodeSpec("orientation", TrajectoryKind.IDEAL, 36),
    )
    assert result.log.joints is None and result.log.arm == "free"
    assert UNREACHABLE not in set(result.log.state)


def _short(duration: float):  # type: ignore[no-untyped-def]
    return ExperimentConfig().task.trajectory.model_copy(update={"duration": duration})


def _ecm_arm() -> CameraArm:
    cfg = ExperimentConfig()
    T_rcm, T_tip_cam = arm_mount(ArmKind.ECM, np.eye(4), cfg.task.scene.T_world_rcm)
    return CameraArm(ArmKind.ECM, T_rcm, T_tip_cam, 0.01)


LOOK_DISTANCE_M = 0.05  # m: the controller's default working distance
MOVING_STEPS = 20  # count: 0.2 s towards a far goal, the joints still accelerating
BRAKE_STEPS = 300  # count: 3 s, ample to brake from the PSM's joint speeds
N_VIEW_CASES = 60  # count: random view goals per check


def _look_from(p_world: np.ndarray, z_world: np.ndarray) -> np.ndarray:
    z = z_world / np.linalg.norm(z_world)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return make_pose(np.column_stack([x, np.cross(z, x), z]), p_world)


def test_ecm_residual_zero_iff_axis_through_rcm():
    arm = _ecm_arm()
    p_rcm = arm.T_world_rcm[:3, 3]
    # a reachable point on the scope's mid-range axis, looking away from the RCM
    T_nat = arm.camera_pose(natural_pose(arm.model))
    p = T_nat[:3, 3]
    on_axis = _look_from(p, p - p_rcm)
    out = arm.step(on_axis, LOOK_DISTANCE_M)
    assert out.reachable and out.status is ActuatorStatus.EXACT
    assert out.orientation_error <= RESIDUAL_ZERO_RAD
    tilt = math.radians(10.0)
    R_tilt = np.array(
        [[1, 0, 0], [0, math.cos(tilt), -math.sin(tilt)], [0, math.sin(tilt), math.cos(tilt)]]
    )
    off_axis = on_axis.copy()
    off_axis[:3, :3] = on_axis[:3, :3] @ R_tilt
    out = arm.step(off_axis, LOOK_DISTANCE_M)
    # the 4-DoF scope takes the port view of the same point: only orientation is missing
    assert out.reachable and out.status is ActuatorStatus.VIEW
    assert out.orientation_error == pytest.approx(
        _port_view_angle(off_axis, p_rcm), abs=ROUNDOFF_RAD
    )
    assert out.orientation_error > 0.0  # the tilted axis misses the RCM: a residual remains
    _assert_looks_at_same_point(out.T_world_target, off_axis, LOOK_DISTANCE_M)


def _port_view_angle(T: np.ndarray, p_rcm: np.ndarray, d: float = 0.0) -> float:
    """Angle between the optical axis and the direction from the RCM to the look-at point."""
    d = d or LOOK_DISTANCE_M
    c = T[:3, 3] + d * T[:3, 2]
    v = (c - p_rcm) / np.linalg.norm(c - p_rcm)
    return math.acos(np.clip(v @ T[:3, 2], -1.0, 1.0))


def _assert_looks_at_same_point(T_target: np.ndarray, T_goal: np.ndarray, d: float) -> None:
    c_goal = T_goal[:3, 3] + d * T_goal[:3, 2]
    c_target = T_target[:3, 3] + d * T_target[:3, 2]
    np.testing.assert_allclose(c_target, c_goal, atol=ATOL_M)


def _psm_arm() -> CameraArm:
    cfg = ExperimentConfig()
    return CameraArm(ArmKind.PSM, cfg.task.scene.T_world_rcm, cfg.episode.T_tip_cam, 0.01)


def test_psm_concedes_the_smallest_view_angle_it_can_reach():
    arm = _psm_arm()
    p_rcm = arm.T_world_rcm[:3, 3]
    T_nat = arm.camera_pose(natural_pose(arm.model))
    rng = np.random.default_rng(11)
    conceded = 0
    for _ in range(N_VIEW_CASES):
        # look at a point ahead of the mid-range camera from a direction up to 150° off the port
        c = T_nat[:3, 3] + LOOK_DISTANCE_M * T_nat[:3, 2]
        z = rng.normal(size=3)
        z /= np.linalg.norm(z)
        v_port = (c - p_rcm) / np.linalg.norm(c - p_rcm)
        if v_port @ z < math.cos(math.radians(150.0)):
            continue
        goal = _look_from(c - LOOK_DISTANCE_M * z, z)
        q, T_target, approach = arm.target(goal, LOOK_DISTANCE_M)
        assert arm.model.within_limits(np.array(q))
        np.testing.assert_allclose(arm.camera_pose(q), T_target, atol=IK_TOL)
        if approach is ActuatorStatus.EXACT:
            np.testing.assert_array_equal(T_target, goal)
            continue
        assert approach is ActuatorStatus.VIEW
        conceded += 1
        _assert_looks_at_same_point(T_target, goal, LOOK_DISTANCE_M)
        # the turn is towards the port, and a turn one bisection step smaller is unreachable
        assert _port_view_angle(T_target, p_rcm) < _port_view_angle(goal, p_rcm)
        # the view angle to the port falls linearly along the turn: (1 - fraction) · total
        fraction = 1.0 - _port_view_angle(T_target, p_rcm) / _port_view_angle(goal, p_rcm)
        smaller = view_towards_port(goal, LOOK_DISTANCE_M, p_rcm, fraction - 2.0**-VIEW_BISECTIONS)
        assert (
            arm.model.exact_unchecked(
                invert_pose(arm.T_world_rcm) @ smaller @ invert_pose(arm.T_tip_cam), arm.q
            )
            is None
        )
    assert conceded >= N_VIEW_CASES // 10  # the cases exercised the view search


def test_view_towards_port_ends_on_the_port_axis():
    rng = np.random.default_rng(12)
    p_rcm = np.array([0.2, 0.0, 0.12])
    for _ in range(N_VIEW_CASES):
        z = rng.normal(size=3)
        goal = _look_from(rng.uniform(-0.1, 0.1, 3), z)
        T1 = view_towards_port(goal, LOOK_DISTANCE_M, p_rcm, 1.0)
        assert _port_view_angle(T1, p_rcm) <= ACOS_RESOLUTION_RAD
        _assert_looks_at_same_point(T1, goal, LOOK_DISTANCE_M)
        T0 = view_towards_port(goal, LOOK_DISTANCE_M, p_rcm, 0.0)
        np.testing.assert_allclose(T0, goal, rtol=0, atol=ATOL_M)
        half = view_towards_port(goal, LOOK_DISTANCE_M, p_rcm, 0.5)
        assert _port_view_angle(half, p_rcm) == pytest.approx(
            0.5 * _port_view_angle(goal, p_rcm), abs=ROUNDOFF_RAD
        )
        # the horizon stays level (image x horizontal) wherever it is defined
        if abs(half[2, 2]) < math.cos(math.radians(30.0)):
            assert abs(half[2, 0]) <= ROUNDOFF_RAD


def test_unreachable_goal_is_approached_and_reported():
    arm = _psm_arm()
    T0 = arm.reset(np.eye(4))
    far = T0.copy()
    far[:3, 3] += np.array([0.0, 0.0, 1.0])  # 1 m away: beyond the insertion stroke
    dists = []
    for _ in range(20):
        out = arm.step(far, LOOK_DISTANCE_M)
        assert not out.reachable and np.all(np.isfinite(out.T_world_cam))
        assert out.status is ActuatorStatus.NEAREST
        assert out.position_error > 0.5  # m: the 1 m goal stays far beyond the ~0.3 m reach
        assert arm.model.within_limits(out.q)
        dists.append(np.linalg.norm(out.T_world_cam[:3, 3] - far[:3, 3]))
    assert dists[-1] < dists[0]  # approaching the nearest feasible pose


def test_non_finite_command_brakes_where_it_is():
    arm = _psm_arm()
    q0 = natural_pose(arm.model)
    arm.reset(arm.camera_pose(q0))
    goal = arm.camera_pose(q0 + np.array([0.3, 0.2, 0.03, 0.5, 0.4, 0.4]))
    for _ in range(MOVING_STEPS):  # on the way: the joints are moving
        arm.step(goal, LOOK_DISTANCE_M)
    assert np.abs(arm.arm.measured_js()[1]).max() > 0.0
    T_at_nan = arm.camera_pose(arm.q)
    outs = [arm.step(np.full((4, 4), np.nan), float("nan")) for _ in range(BRAKE_STEPS)]
    assert all(np.all(np.isfinite(o.T_world_cam)) for o in outs)
    np.testing.assert_allclose(arm.arm.measured_js()[1], 0.0, atol=REST_SPEED)  # at rest
    # it stopped near where the command was lost, not at the goal
    travelled = np.linalg.norm(outs[-1].T_world_cam[:3, 3] - T_at_nan[:3, 3])
    remaining = np.linalg.norm(goal[:3, 3] - T_at_nan[:3, 3])
    assert travelled < 0.5 * remaining


def test_absurd_finite_command_brakes_too():
    arm = _psm_arm()
    T0 = arm.reset(arm.camera_pose(natural_pose(arm.model)))
    absurd = T0.copy()
    absurd[:3, 3] = 1e160  # m: finite, but not a camera pose
    out = arm.step(absurd, LOOK_DISTANCE_M)
    assert np.all(np.isfinite(out.T_world_cam)) and arm.model.within_limits(out.q)
    np.testing.assert_allclose(out.T_world_cam, T0, atol=IK_TOL)


def test_reset_rejects_a_bad_look_distance():
    arm = _psm_arm()
    for bad in (float("nan"), -0.05, 0.0):
        with pytest.raises(ValueError, match="look_distance"):
            arm.reset(np.eye(4), bad)


def test_runner_marks_unreachable_steps(psm_result: EpisodeResult):
    # the wrist cannot bend far enough for every orientation goal (docs/robot.md)
    result = psm_result
    state = result.log.state
    assert UNREACHABLE in set(state)
    assert np.all(np.isfinite(result.log.T_world_cam))
    hit = np.flatnonzero(state == UNREACHABLE)
    assert all("the PSM" in result.log.reason[k] for k in hit)
    assert all(
        "view turned" in result.log.reason[k] or "nearest feasible" in result.log.reason[k]
        for k in hit
    )
    assert result.log.goal_position_error is not None
    assert result.log.goal_orientation_error is not None
    err = np.maximum(result.log.goal_position_error, result.log.goal_orientation_error)
    assert np.all(err[hit] > 0.0)
    # the policy's own safety states are never overwritten
    frozen = result.log.state == "frozen_outside_cone"
    assert all("the cone workspace" in result.log.reason[k] for k in np.flatnonzero(frozen))


def test_episode_is_deterministic(psm_result: EpisodeResult):
    again = _run("orientation", "psm")
    assert again.log.joints is not None and psm_result.log.joints is not None
    np.testing.assert_array_equal(again.log.joints, psm_result.log.joints)
    np.testing.assert_array_equal(again.log.T_world_cam, psm_result.log.T_world_cam)
    assert list(again.log.state) == list(psm_result.log.state)


def test_bad_mount_rejected():
    cfg = ExperimentConfig()
    with pytest.raises(ValueError, match="T_tip_cam"):
        CameraArm(ArmKind.PSM, cfg.task.scene.T_world_rcm, np.zeros((4, 4)), 0.01)
    with pytest.raises(ValueError, match="kind"):
        CameraArm(ArmKind.FREE, np.eye(4), np.eye(4), 0.01)


def test_goal_looking_at_the_port_itself_is_handled():
    # the look-at point is the RCM: no port view exists (no direction), the arm falls back to
    # the nearest feasible configuration, within limits, finite, and says so
    arm = _psm_arm()
    p_rcm = arm.T_world_rcm[:3, 3]
    goal = _look_from(p_rcm + np.array([0.0, -LOOK_DISTANCE_M, 0.0]), np.array([0.0, 1.0, 0.0]))
    out = arm.step(goal, LOOK_DISTANCE_M)
    assert not out.reachable and out.status is ActuatorStatus.NEAREST
    assert np.all(np.isfinite(out.T_world_cam)) and arm.model.within_limits(out.q)


N_STOP_CHECKS = 3000  # count: random joint states per arm, compiled vs interpreted floats


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM], ids=["psm", "ecm"])
def test_compiled_pose_and_stop_point_are_numpys(kind: ArmKind) -> None:
    """The camera pose and the braking's stopping point, slide, turn, lever and margin.

    Against numpy: FK (``model.forward``) between the arm's mounts, ``v·|v|/2a`` per joint
    clipped into the limits, the sums, ``np.linalg.norm`` and ``Workspace.margin``.
    """
    cfg = ExperimentConfig()
    T_tip_cam = cfg.episode.T_tip_cam if kind is ArmKind.PSM else np.eye(4)
    arm = CameraArm(kind, cfg.task.scene.T_world_rcm, T_tip_cam, 0.01)
    g = arm.guard.consts
    rng = np.random.default_rng(21)
    span = arm.model.upper - arm.model.lower
    p_rcm = arm.p_world_rcm
    feature = arm.camera_pose(natural_pose(arm.model))[:3, 3]
    workspaces = [  # about the arm's reach: points inside, outside, below the floor
        Workspace(ConeWorkspace.from_rcm(p_rcm, feature + shift, height, radius), floor)
        for shift, height, radius, floor in (
            ((0.0, 0.0, 0.0), 0.3, 0.15, -math.inf),
            ((0.02, -0.01, 0.0), 0.2, 0.1, float(feature[2])),
            ((0.0, 0.05, -0.03), 0.5, 0.3, float(feature[2]) - 0.05),
        )
    ]
    prismatic = np.array(arm.model.prismatic)
    inside = 0
    for i in range(N_STOP_CHECKS):
        q = rng.uniform(arm.model.lower - 0.1 * span, arm.model.upper + 0.1 * span)
        qd = rng.normal(0.0, 1.0, len(q)) * (rng.random(len(q)) < 0.7)
        if i % 50 == 0:
            qd[:] = 0.0 if i % 100 else math.nan
        T = arm.T_world_rcm @ _forward(arm, q) @ arm.T_tip_cam
        delta = qd * np.abs(qd) * g.half_inv_acc
        stop = np.clip(q + delta, arm.model.lower, arm.model.upper)
        ws = workspaces[i % len(workspaces)]
        stop_row, T_now = np.empty(len(q)), np.empty((4, 4))
        got = stop_point(g, ws.kernel_state, True, q, qd, stop_row, T_now)
        np.testing.assert_allclose(stop_row, stop, atol=ATOL_M)  # NaN: a NaN velocity's stop
        np.testing.assert_allclose(T_now, T, atol=ATOL_M)
        assert got.moving == bool(np.any(qd != 0.0))
        np.testing.assert_allclose(
            [got.slide, got.turn, got.to_rcm],
            [np.abs(delta[prismatic]).sum(), np.abs(delta[~prismatic]).sum(),
             np.linalg.norm(T[:3, 3] - p_rcm)],
            atol=ATOL_M,
        )  # fmt: skip
        margin = ws.margin(T[:3, 3])
        np.testing.assert_allclose(got.margin, margin, atol=ATOL_M)
        unasked = stop_point(g, ws.kernel_state, False, q, qd, stop_row, T_now)
        assert math.isnan(unasked.margin)
        inside += margin >= 0.0
    assert 0 < inside < N_STOP_CHECKS


def _forward(arm: CameraArm, q: np.ndarray) -> np.ndarray:
    """The tool tip in the RCM frame for joints ``q`` beyond the limits too (numpy FK)."""
    return chain_frames(arm.model.chain, q)[-1]

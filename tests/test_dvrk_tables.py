"""endocam's PSM and ECM against the dVRK's own published kinematic tables (issue 25 §2).

The tables below are copied, numbers only, from jhu-dvrk/sawIntuitiveResearchKit:
``share/kinematic/ecm.json`` (commit 09fdffe8), ``share/kinematic/psm.json`` (commit
bb73358d; its first three joints) with the tool ``share/tool/PROGRASP_FORCEPS_420093.json``
(commit 23f23dbe; the last three joints and ``tooltip_offset``), and the straight scope's
tool-tip offset from ``core/components/code/mtsIntuitiveResearchKitECM.cpp`` (commit 0210eb1a,
``set_endoscope_type``). Forward kinematics is the modified-DH (Craig) product written out
here, with the files' ±1.5708 read as ±π/2 as cisst's ``robManipulator`` parser does.

The last test holds the robot process (``endocam robot serve``) to the same tables: its
``measured_cp`` is the dVRK's tip in the arm's base frame, its ``servo_cp`` a pose there.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from endocam.robot import ECM, ECM_CHAIN, PSM, PSM_CHAIN, DHChain
from endocam.robot.dvrk_frames import (
    ECM_TOOLTIP_OFFSET_STRAIGHT,
    T_TIP_CAM_ECM,
    dvrk_ecm_tip,
    ecm_camera_from_dvrk_tip,
)

ATOL_M = 1e-12  # m: FK of a 0.5 m chain agrees to round-off
ATOL_RAD = 1e-12  # rad
N_SAMPLES = 50  # count: random joint vectors per arm
DVRK_HALF_PI = 1.5708  # the files' right angle, read as π/2

# name, alpha, A (m), theta, D (m), offset (rad or m), type, qmin, qmax — as in the files
DVRK_ECM = [
    ("yaw", 1.5708, 0.0, 0.0, 0.0, 1.5708, "revolute", -1.5708, 1.5708),
    ("pitch", -1.5708, 0.0, 0.0, 0.0, -1.5708, "revolute", -0.76794, 1.1344),
    ("insertion", 1.5708, 0.0, 0.0, 0.0, -0.3822, "prismatic", 0.0, 0.255),
    ("roll", 0.0, 0.0, 0.0, 0.3829, 0.0, "revolute", -1.552, 1.552),
]
DVRK_PSM = [
    ("outer_yaw", 1.5708, 0.0, 0.0, 0.0, 1.5708, "revolute", -1.588, 1.588),
    ("outer_pitch", -1.5708, 0.0, 0.0, 0.0, -1.5708, "revolute", -0.925025, 0.925025),
    ("outer_insertion", 1.5708, 0.0, 0.0, 0.0, -0.4318, "prismatic", 0.0, 0.24),
    ("roll", 0.0, 0.0, 0.0, 0.4670, 0.0, "revolute", -4.53786, 4.53786),
    ("wrist_pitch", -1.5708, 0.0, 0.0, 0.0, -1.5708, "revolute", -1.39626, 1.39626),
    ("wrist_yaw", -1.5708, 0.0107, 0.0, 0.0, -1.5708, "revolute", -1.39626, 1.39626),
]
DVRK_PSM_TOOLTIP = np.array([[0, -1, 0, 0], [0, 0, 1, 0], [-1, 0, 0, 0], [0, 0, 0, 1]], float)
DVRK_ECM_TOOLTIP_STRAIGHT = np.array(
    [[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], float
)


def _angle(x: float) -> float:
    """A table angle as cisst reads it: ±1.5708 is ±π/2."""
    return math.copysign(math.pi / 2, x) if abs(x) == DVRK_HALF_PI else x


def _table_fk(table: list[tuple], q: np.ndarray) -> np.ndarray:
    """T_base_last (4, 4): the product of RotX(alpha)·TransX(A)·RotZ(theta)·TransZ(D)."""
    T = np.eye(4)
    for (_name, alpha, a, theta, d, offset, kind, _lo, _hi), qi in zip(table, q, strict=True):
        alpha = _angle(alpha)
        if kind == "revolute":
            theta = theta + _angle(offset) + qi
        else:
            d = d + offset + qi
        ca, sa, ct, st = math.cos(alpha), math.sin(alpha), math.cos(theta), math.sin(theta)
        T = T @ np.array(
            [
                [ct, -st, 0.0, a],
                [st * ca, ct * ca, -sa, -sa * d],
                [st * sa, ct * sa, ca, ca * d],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
    return T


def _samples(table: list[tuple], seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lo = np.array([row[7] for row in table])
    hi = np.array([row[8] for row in table])
    return rng.uniform(lo, hi, size=(N_SAMPLES, len(table)))


@pytest.mark.parametrize(("chain", "table"), [(ECM_CHAIN, DVRK_ECM), (PSM_CHAIN, DVRK_PSM)])
def test_chain_names_and_limits_are_the_tables(chain: DHChain, table: list[tuple]) -> None:
    assert chain.names == tuple(row[0] for row in table)
    np.testing.assert_array_equal(chain.lower, [row[7] for row in table])
    np.testing.assert_array_equal(chain.upper, [row[8] for row in table])


def test_psm_tip_is_the_dvrk_tip() -> None:
    psm = PSM()
    for q in _samples(DVRK_PSM, seed=11):
        expected = _table_fk(DVRK_PSM, q) @ DVRK_PSM_TOOLTIP
        np.testing.assert_allclose(psm.forward(q), expected, atol=ATOL_M, rtol=0.0)


def test_ecm_tip_is_the_dvrk_tip_and_its_camera_the_isi_frame_in_opencv_terms() -> None:
    ecm = ECM()
    for q in _samples(DVRK_ECM, seed=12):
        T_rcm_tip = _table_fk(DVRK_ECM, q) @ DVRK_ECM_TOOLTIP_STRAIGHT  # the dVRK's at q
        np.testing.assert_allclose(ecm.forward(q), T_rcm_tip, atol=ATOL_M, rtol=0.0)
        T_rcm_cam = ecm_camera_from_dvrk_tip(T_rcm_tip)
        np.testing.assert_allclose(dvrk_ecm_tip(T_rcm_cam), T_rcm_tip, atol=ATOL_M, rtol=0.0)
        # OpenCV's x right, y down are the ISI tip's −x, −y; both look along the tip's z
        np.testing.assert_allclose(T_rcm_cam[:3, 0], -T_rcm_tip[:3, 0], atol=ATOL_RAD)
        np.testing.assert_allclose(T_rcm_cam[:3, 1], -T_rcm_tip[:3, 1], atol=ATOL_RAD)
        np.testing.assert_allclose(T_rcm_cam[:3, 2:], T_rcm_tip[:3, 2:], atol=ATOL_M)
    np.testing.assert_array_equal(ECM_TOOLTIP_OFFSET_STRAIGHT, DVRK_ECM_TOOLTIP_STRAIGHT)
    np.testing.assert_array_equal(T_TIP_CAM_ECM, np.diag([-1.0, -1.0, 1.0, 1.0]))


# -- the link speaks the dVRK's frames: what `endocam robot serve` puts on the wire ----------

WIRE_ATOL_M = 1e-12  # m: a pose through a quaternion and the frames' products, round-off
SERVO_ATOL_M = 1e-6  # m: the arm's IK converges on the commanded tip to well under a micron
SERVO_STEPS = 95  # control periods to reach joints a few hundredths away (speed limits)
LINK_DT = 0.01  # s: the default control period (100 Hz)
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"


class _Recorder:
    """A Zenoh session's publishers, kept: what the robot puts on each key, in order."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, bytes]] = []

    def declare_publisher(self, key: str, **_: object) -> object:
        sent = self.sent

        class Publisher:
            def put(self, data: bytes) -> None:
                sent.append((key, data))

        return Publisher()

    def latest(self, key: str) -> bytes:
        return next(data for k, data in reversed(self.sent) if k == key)


@pytest.mark.parametrize(
    ("kind", "table", "tooltip"),
    [("psm", DVRK_PSM, DVRK_PSM_TOOLTIP), ("ecm", DVRK_ECM, DVRK_ECM_TOOLTIP_STRAIGHT)],
)
def test_the_robot_process_speaks_the_dvrk_tip_in_the_base_frame(
    kind: str, table: list[tuple], tooltip: np.ndarray, tmp_path: Path
) -> None:
    """``measured_cp`` on the wire is FK(``measured_js``) of the tables, a ``servo_cp`` of a
    tip pose takes the arm there, and the controller's edge turns it back into its camera."""
    from endocam.config import load_config
    from endocam.link.client import ZenohArm, registration
    from endocam.link.messages import ENABLED, Codec, stamp_ns
    from endocam.link.server import LOOK_KEY, CommandGate, JointCommand, Robot, Verdict
    from endocam.robot.actuator import ArmKind
    from endocam.runner.episode import EpisodeSpec
    from endocam.task.trajectory import TrajectoryKind

    config = tmp_path / "short.toml"
    config.write_text("[task.trajectory]\nduration = 1.0\n", encoding="utf-8")
    cfg = load_config(config)
    arm_kind = ArmKind(kind)
    session = _Recorder()
    robot = Robot(cfg, EpisodeSpec("orientation", TrajectoryKind.NOISY, 10, 3), arm_kind, session)
    robot.publish(ENABLED, None)
    codec, keys = Codec(), robot.keys

    def wire() -> tuple[np.ndarray, np.ndarray]:
        T_tip, _ = codec.decode_pose(session.latest(keys.measured_cp))
        return T_tip, codec.decode_joints(session.latest(keys.measured_js))

    # measured_cp is the dVRK's tip in the base (RCM) frame at measured_js: not the camera,
    # and its header names that frame as the dVRK does (PSM3_base, ECM_base)
    T_tip, q = wire()
    np.testing.assert_allclose(T_tip, _table_fk(table, q) @ tooltip, atol=WIRE_ATOL_M, rtol=0)
    header = codec.store.deserialize_cdr(session.latest(keys.measured_cp), POSE_STAMPED).header
    assert header.frame_id == f"{keys.measured_cp.split('/')[0]}_base"
    # the controller's edge, registered from the same config, sees the robot's camera
    client = ZenohArm(arm_kind, "tcp/127.0.0.1:7447", LINK_DT)
    client.register(registration(cfg, arm_kind))
    for message in session.sent:
        client.inbox.put(message)
    state = client.receive(0, 1.0, first=True)
    np.testing.assert_allclose(state.T_world_cam, robot.T_cam, atol=WIRE_ATOL_M, rtol=0)
    # a servo_cp of a known tip pose (the tables' FK of nearby joints) takes the arm there
    lower, upper = np.array([r[7] for r in table]), np.array([r[8] for r in table])
    q_goal = np.clip(q + np.resize([0.03, -0.03, 0.004, 0.05, -0.05, 0.05], q.size), lower, upper)
    T_goal = _table_fk(table, q_goal) @ tooltip
    gate = CommandGate(keys, JointCommand(arm_kind, robot.arm), robot.frames, LINK_DT)
    for k in range(SERVO_STEPS):
        gate.admit(LOOK_KEY, codec.float64(cfg.controller.d_f), k)
        T_cp = codec.pose(T_goal, stamp_ns(k * LINK_DT), robot.frames.frame_id)
        a = gate.admit(keys.servo_cp, T_cp, k)
        assert a.verdict is Verdict.ACCEPTED and a.command is not None
        robot.step(a.command.T_world_cmd, a.command.look, a.command.twist, ENABLED)
    T_tip, q = wire()
    np.testing.assert_allclose(T_tip, T_goal, atol=SERVO_ATOL_M, rtol=0)
    np.testing.assert_allclose(q, q_goal, atol=SERVO_ATOL_M, rtol=0)


SHEAR_INSIDE = 0.45e-12  # unitless: R Rᵀ's off-diagonal 0.9e-12, inside scipy's atol 1e-12
SHEAR_OUTSIDE = 1.0e-12  # unitless: 2e-12, outside it


def test_the_fast_paths_validity_test_is_scipys_on_both_sides_of_its_tolerance() -> None:
    """``crtk_pose_fields`` repeats scipy's validity test to take ``assume_valid`` for valid
    rotations. Just inside scipy's tolerance scipy's general conversion equals its
    ``assume_valid`` one (scipy took the matrix as valid), just outside it does not (scipy
    orthogonalised it); ``crtk_pose_fields`` equals the general conversion on both sides. If
    scipy's tolerance moves either way, this fails (and ``dvrk_frames._GRAM_ATOL`` with it)."""
    from scipy.spatial.transform import Rotation

    from endocam.robot.dvrk_frames import crtk_pose_fields

    rng = np.random.default_rng(23)
    shear = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])  # R Rᵀ ≈ I + 2 δ shear
    for delta, valid in ((SHEAR_INSIDE, True), (SHEAR_OUTSIDE, False)):
        for _ in range(50):
            T = np.eye(4)
            T[:3, :3] = (np.eye(3) + delta * shear) @ Rotation.random(rng=rng).as_matrix()
            general = Rotation.from_matrix(T[:3, :3]).as_quat()
            fast = Rotation.from_matrix(T[:3, :3], assume_valid=True).as_quat()
            assert np.array_equal(general, fast) is valid, delta
            assert crtk_pose_fields(T)[3:] == tuple(general)


def test_crtk_pose_fields_are_scipys_conversion_for_every_matrix() -> None:
    """Its fast path for valid rotations gives scipy's general ``from_matrix`` to the bit.

    Valid rotations (products of random ones, as the link's frame conversions make), a matrix
    just off orthonormal (scipy orthogonalises it) and a left-handed one (scipy refuses it).
    """
    from scipy.spatial.transform import Rotation

    from endocam.robot.dvrk_frames import crtk_pose_fields

    rng = np.random.default_rng(17)
    for _ in range(500):
        T = np.eye(4)
        R = Rotation.random(3, rng=rng).as_matrix()
        T[:3, :3] = R[0] @ R[1] @ R[2]
        T[:3, 3] = rng.normal(size=3)
        expected = Rotation.from_matrix(T[:3, :3]).as_quat()
        assert crtk_pose_fields(T) == (*T[:3, 3], *expected)
    T[:3, :3] *= 1.0 + 1e-9  # not orthonormal: |R Rᵀ − I| ~ 2e-9 > scipy's 1e-12
    assert crtk_pose_fields(T)[3:] == tuple(Rotation.from_matrix(T[:3, :3]).as_quat())
    T[:3, 0] *= -1.0  # left-handed
    with pytest.raises(ValueError, match="determinant"):
        crtk_pose_fields(T)

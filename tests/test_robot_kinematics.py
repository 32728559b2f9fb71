"""Tests of the dVRK PSM / ECM kinematics (endocam.robot)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from endocam.geometry import invert_pose, so3_log
from endocam.robot import ECM, PSM, IKStatus, UnreachableError
from endocam.robot.dh import (
    DHLink,
    JointType,
    Pose12,
    chain_forward,
    chain_frames,
    chain_points,
    compose_links,
    geometric_jacobian,
    link_transform,
    pose12_from_matrix,
    pose12_point,
    pose12_times,
    pose12_to_matrix,
)
from endocam.robot.ecm import ECM_IK_MIN_INSERTION
from endocam.robot.ik import (
    IK_ORIENTATION_TOL_RAD,
    IK_POSITION_TOL_M,
    pose12_error,
    pose_error,
    within_tolerance,
)
from endocam.robot.kinematics import (
    LIMIT_SLACK,
    ORIENTATION_WEIGHT_M_PER_RAD,
    branch_in_limits,
)
from endocam.robot.psm import PSM_CHAIN

EPS = np.finfo(np.float64).eps
ATOL_M = 1e-9  # m: FK / IK agreement on positions (sub-nanometre)
ATOL_RAD = 1e-9  # rad: FK / IK agreement on orientations
FD_STEP = 1e-6  # rad or m: central-difference step
FD_ATOL = 1e-8  # Jacobian entries: O(FD_STEP**2) truncation + round-off / FD_STEP

PSM_ARM = PSM()
ECM_ARM = ECM()
SHAFT_AT_ZERO_INSERTION = 0.4670 - 0.4318  # m, wrist point beyond the RCM at insertion 0
WRIST_LENGTH = 0.0107  # m


def _rot_x(a: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("x", a).as_matrix()
    return T


def _rot_z(a: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", a).as_matrix()
    return T


def _trans(axis: int, d: float) -> np.ndarray:
    T = np.eye(4)
    T[axis, 3] = d
    return T


def _random_q(arm: PSM | ECM, rng: np.random.Generator, margin: float = 0.0) -> np.ndarray:
    span = arm.upper - arm.lower
    return rng.uniform(arm.lower + margin * span, arm.upper - margin * span)


def _random_ecm_ik_q(rng: np.random.Generator, margin: float = 0.0) -> np.ndarray:
    """ECM joints the IK reaches: within the limits, insertion ≥ 40 mm (``ECM.ik_lower``)."""
    lower, upper = ECM_ARM.ik_lower, ECM_ARM.upper
    span = upper - lower
    return rng.uniform(lower + margin * span, upper - margin * span)


def _shaft_direction(q1: float, q2: float) -> np.ndarray:
    return np.array([math.sin(q1) * math.cos(q2), -math.sin(q2), -math.cos(q1) * math.cos(q2)])


# ---------------------------------------------------------------------------- DH / FK
def test_link_transform_is_craig_product() -> None:
    rng = np.random.default_rng(0)
    for joint_type in JointType:
        for _ in range(20):
            alpha, a_len, d, theta, offset, q = rng.uniform(-2.0, 2.0, 6)
            link = DHLink("j", alpha, a_len, d, theta, offset, joint_type, -10.0, 10.0)
            if joint_type is JointType.REVOLUTE:
                th, dd = q + offset, d
            else:
                th, dd = theta, q + offset
            expected = _rot_x(alpha) @ _trans(0, a_len) @ _rot_z(th) @ _trans(2, dd)
            np.testing.assert_allclose(link_transform(link, q), expected, atol=10 * EPS)


@pytest.mark.parametrize("arm", [PSM_ARM, ECM_ARM], ids=["psm", "ecm"])
def test_fast_fk_equals_link_product(arm: PSM | ECM) -> None:
    rng = np.random.default_rng(1)
    for _ in range(50):
        q = _random_q(arm, rng)
        T = np.eye(4)
        for link, qi in zip(arm.chain.links, q, strict=True):
            T = T @ link_transform(link, float(qi))
        T = T @ arm.chain.T_last_tip
        np.testing.assert_allclose(chain_forward(arm.chain, q), T, atol=ATOL_M)
        np.testing.assert_allclose(arm.frames(q)[-1], T, atol=ATOL_M)


N_COMPILED = 2000  # count: random products, compiled vs numpy
ATOL_FK_M = 1e-12  # m (and unitless rotation entries): a compiled product vs numpy's, round-off


@pytest.mark.parametrize("arm", [PSM_ARM, ECM_ARM], ids=["psm", "ecm"])
def test_compiled_compose_is_the_numpy_link_product(arm: PSM | ECM) -> None:
    """The compiled link product is ``T0 @ link_transform(...) @ ...`` within round-off."""
    rng = np.random.default_rng(7)
    chain, n = arm.chain, arm.n_joints
    for _ in range(N_COMPILED):
        q = rng.uniform(-4.0, 4.0, n).tolist()
        T0 = np.eye(4)
        T0[:3, :3] = Rotation.random(random_state=rng.integers(2**32)).as_matrix()
        T0[:3, 3] = rng.normal(size=3)
        start = int(rng.integers(0, n))
        stop = int(rng.integers(start, n + 1))
        expected = T0
        for i in range(start, stop):
            expected = expected @ link_transform(chain.links[i], q[i])
        got = compose_links(chain, q, start, stop, pose12_from_matrix(T0))
        np.testing.assert_allclose(pose12_to_matrix(got), expected, atol=ATOL_FK_M)
    assert compose_links(chain, [0] * n) == compose_links(chain, [0.0] * n)  # ints: floats


def _numpy_jacobian(arm: PSM | ECM, q: np.ndarray) -> np.ndarray:
    """The geometric Jacobian (6, n) from ``chain_frames`` (numpy): rows v, then ω."""
    frames = chain_frames(arm.chain, q)
    p_tip = frames[-1, :3, 3]
    J = np.zeros((6, arm.n_joints))
    for i, link in enumerate(arm.chain.links):
        z = frames[i, :3, 2]
        if link.joint_type is JointType.REVOLUTE:
            J[:3, i] = np.cross(z, p_tip - frames[i, :3, 3])
            J[3:, i] = z
        else:
            J[:3, i] = z
    return J


@pytest.mark.parametrize("arm", [PSM_ARM, ECM_ARM], ids=["psm", "ecm"])
def test_compiled_jacobian_and_residuals_are_numpys(arm: PSM | ECM) -> None:
    """The nearest-feasible solve's compiled callbacks against numpy and ``geometry.so3_log``.

    ``geometric_jacobian`` (``dh.jacobian_into``) and ``RcmArm._pose_residual`` /
    ``_pose_residual_jac``, on random joints (inside and beyond the limits), goal poses and
    weights.
    """
    rng = np.random.default_rng(11)
    chain, n = arm.chain, arm.n_joints
    for k in range(N_COMPILED):
        q = _random_q(arm, rng) if k % 2 else rng.uniform(-4.0, 4.0, n)
        T_goal = np.eye(4)
        T_goal[:3, :3] = Rotation.random(random_state=rng.integers(2**32)).as_matrix()
        T_goal[:3, 3] = rng.normal(scale=0.1, size=3)
        if k % 7 == 0:  # the goal at the current pose: zero orientation error
            T_goal = chain_frames(chain, q)[-1]
        weight = float(rng.uniform(0.0, 1.0)) if k % 3 else ORIENTATION_WEIGHT_M_PER_RAD
        J = _numpy_jacobian(arm, q)
        np.testing.assert_allclose(geometric_jacobian(chain, q), J, atol=ATOL_FK_M)
        T = chain_frames(chain, q)[-1]
        rot = so3_log(T_goal[:3, :3].T @ T[:3, :3])
        expected = np.concatenate([T[:3, 3] - T_goal[:3, 3], weight * rot])
        if np.linalg.norm(rot) < math.pi - 1e-6:  # (at π the log's sign is either)
            np.testing.assert_allclose(arm._pose_residual(q, T_goal, weight), expected, atol=1e-9)
        expected_jac = np.vstack([J[:3], weight * (T_goal[:3, :3].T @ J[3:])])
        got = arm._pose_residual_jac(q, T_goal, weight)
        np.testing.assert_allclose(got, expected_jac, atol=ATOL_FK_M)


@pytest.mark.parametrize("arm", [PSM_ARM, ECM_ARM], ids=["psm", "ecm"])
def test_chain_points_are_the_per_point_floats(arm: PSM | ECM) -> None:
    """A whole path's points (one compiled call) are the per-point FK's, within round-off."""
    rng = np.random.default_rng(8)
    chain, n = arm.chain, arm.n_joints
    q_rows = rng.uniform(-4.0, 4.0, (N_COMPILED, n))
    T0 = tuple(rng.normal(size=12).tolist())
    rows = tuple(tuple(r) for r in rng.normal(size=(3, 4)).tolist())
    point = (rows[0][3], rows[1][3], rows[2][3])
    got = chain_points(chain, q_rows.tolist(), T0, point)
    assert got.shape == (N_COMPILED, 3)
    for k, q in enumerate(q_rows.tolist()):
        expected = pose12_point(compose_links(chain, q, T0=T0), rows)
        np.testing.assert_allclose(got[k], expected, rtol=1e-12, atol=ATOL_FK_M)
    assert chain_points(chain, np.zeros((0, n)), T0, point).shape == (0, 3)


def test_psm_zero_pose() -> None:
    T = PSM_ARM.forward(np.zeros(6))
    # shaft straight down (-z of the RCM frame); wrist point 0.0352 m past the RCM and the
    # jaw link (0.0107 m) straight on; tip z along the shaft, x/y from the ISI tool-tip offset
    expected = np.array(
        [
            [0.0, 1.0, 0.0, 0.0],
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, -1.0, -(SHAFT_AT_ZERO_INSERTION + WRIST_LENGTH)],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )
    np.testing.assert_allclose(T, expected, atol=ATOL_M)


def test_psm_pure_insertion_moves_tip_along_shaft() -> None:
    rng = np.random.default_rng(2)
    for _ in range(30):
        q = _random_q(PSM_ARM, rng, margin=0.1)
        dq = rng.uniform(-0.02, 0.02)
        q2 = q.copy()
        q2[2] += dq
        T1, T2 = PSM_ARM.forward(q), PSM_ARM.forward(q2)
        shaft = _shaft_direction(q[0], q[1])
        np.testing.assert_allclose(T2[:3, 3] - T1[:3, 3], dq * shaft, atol=ATOL_M)
        np.testing.assert_allclose(T2[:3, :3], T1[:3, :3], atol=ATOL_RAD)


def test_psm_shaft_passes_through_rcm() -> None:
    rng = np.random.default_rng(3)
    for _ in range(30):
        q = _random_q(PSM_ARM, rng)
        frames = PSM_ARM.frames(q)
        p_wrist = frames[3, :3, 3]  # roll frame origin = wrist-pitch point
        shaft = frames[2, :3, 2]
        np.testing.assert_allclose(np.cross(p_wrist, shaft), 0.0, atol=ATOL_M)
        assert np.linalg.norm(p_wrist) == pytest.approx(q[2] + SHAFT_AT_ZERO_INSERTION)
        np.testing.assert_allclose(shaft, _shaft_direction(q[0], q[1]), atol=ATOL_RAD)


def test_ecm_zero_pose_and_axis_through_rcm() -> None:
    T = ECM_ARM.forward(np.zeros(4))
    np.testing.assert_allclose(T[:3, 2], [0.0, 0.0, -1.0], atol=ATOL_RAD)
    np.testing.assert_allclose(T[:3, 3], [0.0, 0.0, -(0.3829 - 0.3822)], atol=ATOL_M)
    rng = np.random.default_rng(4)
    for _ in range(30):
        T = ECM_ARM.forward(_random_q(ECM_ARM, rng))
        np.testing.assert_allclose(np.cross(T[:3, 3], T[:3, 2]), 0.0, atol=ATOL_M)


# ---------------------------------------------------------------------------- PSM IK
def test_psm_ik_round_trip_random() -> None:
    rng = np.random.default_rng(5)
    for _ in range(200):
        q = _random_q(PSM_ARM, rng)
        T = PSM_ARM.forward(q)
        res = PSM_ARM.solve(T, q_seed=q)
        assert res.status is IKStatus.OK
        np.testing.assert_allclose(res.q, q, atol=1e-7)
        np.testing.assert_allclose(PSM_ARM.forward(res.q), T, atol=ATOL_M)
        assert res.position_error < ATOL_M
        assert res.orientation_error < ATOL_RAD
        q_any = PSM_ARM.inverse(T)  # default seed: pose must still match
        np.testing.assert_allclose(PSM_ARM.forward(q_any), T, atol=ATOL_M)


@settings(max_examples=60, deadline=None)
@given(
    st.tuples(
        *[
            st.floats(lo, hi)
            for lo, hi in zip(PSM_ARM.lower * 0.999, PSM_ARM.upper * 0.999, strict=True)
        ]
    )
)
def test_psm_ik_round_trip_property(q_tuple: tuple[float, ...]) -> None:
    q = np.array(q_tuple)
    T = PSM_ARM.forward(q)
    q_sol = PSM_ARM.inverse(T, q_seed=q)
    np.testing.assert_allclose(PSM_ARM.forward(q_sol), T, atol=ATOL_M)


def _branch_reference(angle: float, reference: float, lower: float, upper: float) -> float:
    """``branch_in_limits`` as the interpreter ran it before it was compiled (the reference)."""
    two_pi = 2.0 * math.pi
    best = angle + 2.0 * math.pi * round((reference - angle) / (2.0 * math.pi))
    if lower - LIMIT_SLACK <= best <= upper + LIMIT_SLACK:
        return best
    k_lo = math.ceil((lower - LIMIT_SLACK - angle) / two_pi)
    k_hi = math.floor((upper + LIMIT_SLACK - angle) / two_pi)
    candidates = [angle + two_pi * k for k in range(k_lo, k_hi + 1)]
    if not candidates:
        return best
    return min(candidates, key=lambda a: abs(a - reference))


ANGLES = st.floats(-40.0, 40.0) | st.sampled_from([0.0, -0.0, math.pi, -math.pi, 3 * math.pi])


@settings(max_examples=600, deadline=None)
@given(ANGLES, ANGLES, ANGLES, st.floats(0.0, 20.0), st.integers(-3, 3))
def test_compiled_branch_choice_is_pythons(
    angle: float, reference: float, lower: float, width: float, half_turns: int
) -> None:
    """The compiled ``branch_in_limits`` picks Python's branch, ties to even included.

    ``half_turns`` puts the reference exactly an odd or even number of half turns away (the
    ties of ``round``).
    """
    upper = lower + width
    for ref in (reference, angle + half_turns * math.pi):
        assert branch_in_limits(angle, ref, lower, upper) == pytest.approx(
            _branch_reference(angle, ref, lower, upper), abs=ATOL_RAD
        )
    for bad, error in ((math.nan, ValueError), (math.inf, OverflowError)):  # round()'s errors
        with pytest.raises(error):
            _branch_reference(bad, reference, lower, upper)
        with pytest.raises(error):
            branch_in_limits(bad, reference, lower, upper)


def _closed_form_reference(goal: Pose12, seed: np.ndarray) -> tuple[list[float], Pose12] | None:
    """``PSM._closed_form`` as the interpreter ran it before it was compiled (the reference)."""
    links = PSM_CHAIN.links
    rows = tuple(tuple(row) for row in invert_pose(PSM_CHAIN.T_last_tip)[:3].tolist())
    x0, _, z0, x1, _, z1, x2, _, z2, p0, p1, p2 = pose12_times(goal, rows)
    pz = p0 * z0 + p1 * z1 + p2 * z2
    e0, e1, e2 = p0 - pz * z0, p1 - pz * z1, p2 - pz * z2
    n_perp = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    L = links[5].A
    if n_perp - L <= 1e-9:
        return None
    k = L / n_perp
    w0, w1, w2 = p0 - k * e0, p1 - k * e1, p2 - k * e2
    r = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if r <= 1e-9:
        return None
    q3 = r - (links[3].D + links[2].offset)
    q2 = -math.asin(max(-1.0, min(1.0, w1 / r)))
    q1 = _branch_reference(math.atan2(w0, -w2), float(seed[0]), links[0].lower, links[0].upper)
    q = [q1, q2, q3, 0.0, 0.0, 0.0]
    T_rcm_3 = compose_links(PSM_CHAIN, q, 0, 3)
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = T_rcm_3[:9]
    v0 = a00 * z0 + a10 * z1 + a20 * z2
    v1 = a01 * z0 + a11 * z1 + a21 * z2
    v2 = a02 * z0 + a12 * z1 + a22 * z2
    theta5 = math.atan2(-math.hypot(v0, v1), -v2)
    theta4 = math.atan2(v1, v0)
    q[3] = _branch_reference(
        theta4 - links[3].offset, float(seed[3]), links[3].lower, links[3].upper
    )
    q[4] = _branch_reference(theta5 - links[4].offset, 0.0, links[4].lower, links[4].upper)
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = compose_links(PSM_CHAIN, q, 3, 5)[:9]
    c0 = a00 * x0 + a10 * x1 + a20 * x2
    c1 = a01 * x0 + a11 * x1 + a21 * x2
    c2 = a02 * x0 + a12 * x1 + a22 * x2
    u0 = b00 * c0 + b10 * c1 + b20 * c2
    u1 = b01 * c0 + b11 * c1 + b21 * c2
    u2 = b02 * c0 + b12 * c1 + b22 * c2
    ca6, sa6 = math.cos(links[5].alpha), math.sin(links[5].alpha)
    theta6 = math.atan2(ca6 * u1 + sa6 * u2, u0)
    q[5] = _branch_reference(theta6 - links[5].offset, 0.0, links[5].lower, links[5].upper)
    T_rcm_6 = compose_links(PSM_CHAIN, q, 3, 6, T_rcm_3)
    return q, pose12_times(T_rcm_6, PSM_CHAIN._tip_rows)


N_CLOSED_FORM = 4000  # count: random goals, compiled closed form vs the Python one


def test_compiled_psm_closed_form_is_the_python_one() -> None:
    """The compiled closed form: the Python form's joints and pose, within round-off.

    Goals from joints inside and beyond the limits, with random seeds, and arbitrary rigid
    poses (many singular or unreachable: both sides must say None together).
    """
    rng = np.random.default_rng(11)
    span = PSM_ARM.upper - PSM_ARM.lower
    found = set()
    for i in range(N_CLOSED_FORM):
        if i % 4 == 3:  # any rigid pose within 0.3 m of the RCM
            T = np.eye(4)
            T[:3, :3] = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
            T[:3, 3] = rng.uniform(-0.3, 0.3, 3)
        else:
            T = PSM_ARM.forward(rng.uniform(PSM_ARM.lower - 0.2 * span, PSM_ARM.upper + 0.2 * span))
        goal = pose12_from_matrix(T)
        seed = rng.uniform(-6.0, 6.0, 6)
        want = _closed_form_reference(goal, seed)
        got = PSM_ARM._closed_form(goal, seed)
        assert (got is None) == (want is None)
        exact = None  # exact12_unchecked in Python
        if want is not None and got is not None:
            np.testing.assert_allclose(got[0], want[0], atol=ATOL_RAD)
            np.testing.assert_allclose(got[1], want[1], atol=ATOL_M)
            if within_tolerance(*pose12_error(goal, want[1])):
                q_in, inside = PSM_ARM.clamp_floats(want[0])
                exact = q_in if inside else None
        got_exact = PSM_ARM.exact12_unchecked(goal, seed)
        assert (got_exact is None) == (exact is None)
        if exact is not None and got_exact is not None:
            np.testing.assert_allclose(got_exact, exact, atol=ATOL_RAD)
            np.testing.assert_allclose(PSM_ARM.forward(got_exact), T, atol=ATOL_M)
        found.add(exact is not None)
    assert found == {True, False}  # exact and not
    singular = pose12_from_matrix(np.eye(4))  # the tip at the RCM
    assert PSM_ARM._closed_form(singular, np.zeros(6)) is None
    assert _closed_form_reference(singular, np.zeros(6)) is None


N_ECM_GOALS = 1500  # count: random goals for the ECM IK's promises


def test_ecm_ik_keeps_its_promises() -> None:
    """The compiled ECM IK: joints in limits, its pose and errors FK's, its status honest.

    Goals from joints inside and beyond the limits (the axis out of its limits takes the
    nearest-position solve), off-axis goals (unreachable orientation), arbitrary rigid poses
    and goals at the RCM, with random roll seeds. ``exact12_unchecked`` answers exactly when
    the full solve says ``OK``, with its joints.
    """
    rng = np.random.default_rng(12)
    span = ECM_ARM.upper - ECM_ARM.lower
    outcomes = set()
    for i in range(N_ECM_GOALS):
        q0 = rng.uniform(ECM_ARM.lower - 0.3 * span, ECM_ARM.upper + 0.3 * span)
        T = ECM_ARM.forward(q0)
        if i % 3 == 1:  # turned off the axis through the RCM
            T = T @ _rot_x(float(rng.normal(0.0, 10.0 ** rng.uniform(-9, -1))))
        elif i % 3 == 2:  # any rigid pose within 0.3 m of the RCM, a few at it
            T[:3, :3] = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
            T[:3, 3] = rng.uniform(-0.3, 0.3, 3) * (0.0 if i % 97 == 2 else 1.0)
        seed = rng.uniform(-4.0, 4.0, 4)
        got = ECM_ARM.solve_unchecked(T, seed)
        assert ECM_ARM.within_limits(got.q)
        assert got.q[2] >= ECM_IK_MIN_INSERTION  # the dVRK IK's least insertion
        np.testing.assert_allclose(
            got.T_rcm_tip, chain_frames(ECM_ARM.chain, got.q)[-1], atol=ATOL_M
        )
        pos, ang = pose_error(T, got.T_rcm_tip)
        assert got.position_error == pytest.approx(pos, abs=ATOL_M)
        assert got.orientation_error == pytest.approx(ang, abs=1e-7)
        if got.status is IKStatus.OK:
            assert pos <= IK_POSITION_TOL_M and ang <= IK_ORIENTATION_TOL_RAD
        ik_reach = bool(np.all((q0 >= ECM_ARM.ik_lower) & (q0 <= ECM_ARM.upper)))
        if i % 3 == 0 and ik_reach:  # a goal at joints the IK allows: reached
            assert got.status is IKStatus.OK
        exact = ECM_ARM.exact12_unchecked(pose12_from_matrix(T), seed)
        assert (exact is not None) == (got.status is IKStatus.OK)
        if exact is not None:
            np.testing.assert_allclose(exact, got.q, atol=ATOL_RAD)
        outcomes.add(got.status)
    assert outcomes == set(IKStatus)  # every status was exercised


def test_psm_ik_picks_branch_closest_to_seed() -> None:
    # roll beyond ±π (its limit is ±260°); the outer yaw's ±91° leaves it a single branch
    q = np.array([1.0, 0.2, 0.1, -4.0, 0.3, -0.2])
    T = PSM_ARM.forward(q)
    np.testing.assert_allclose(PSM_ARM.inverse(T, q_seed=q), q, atol=1e-7)
    q_alt = q.copy()
    q_alt[3] += 2 * math.pi
    np.testing.assert_allclose(PSM_ARM.inverse(T, q_seed=q_alt), q_alt, atol=1e-7)


def test_psm_unreachable_insertion_raises_with_nearest_feasible() -> None:
    q_far = np.array([0.2, -0.1, 0.30, 0.4, 0.2, -0.1])  # insertion beyond 0.24 m
    T = chain_forward(PSM_ARM.chain, q_far)
    with pytest.raises(UnreachableError) as info:
        PSM_ARM.inverse(T)
    err = info.value
    assert isinstance(err, ValueError)
    assert err.result.status is IKStatus.CLAMPED_TO_LIMITS
    assert PSM_ARM.within_limits(err.q)
    assert err.q[2] == pytest.approx(PSM_ARM.upper[2])
    np.testing.assert_allclose(err.T_rcm_tip, PSM_ARM.forward(err.q), atol=ATOL_M)
    # the shortfall is about the missing insertion (the weighted optimum may trade a little)
    shortfall = 0.30 - 0.24
    assert 0.9 * shortfall < err.position_error <= shortfall + ATOL_M
    assert _cost(err.position_error, err.orientation_error) <= shortfall + ATOL_M
    res = PSM_ARM.solve(T)
    assert res.status is IKStatus.CLAMPED_TO_LIMITS
    np.testing.assert_allclose(res.q, err.q, atol=1e-9)


def test_psm_unreachable_wrist_limit_gives_nearest_feasible() -> None:
    q_far = np.array([0.1, 0.1, 0.1, 0.2, 1.5, 0.0])  # wrist pitch beyond 1.396 rad
    T = chain_forward(PSM_ARM.chain, q_far)
    res = PSM_ARM.solve(T, q_seed=np.zeros(6))
    assert res.status is IKStatus.CLAMPED_TO_LIMITS
    assert PSM_ARM.within_limits(res.q)
    assert res.position_error > 0.0 or res.orientation_error > 0.0
    # nearest feasible is no worse than simply clamping the exact solution
    clamped = PSM_ARM.clamp(q_far)
    clamp_cost = _cost(*_errors(T, PSM_ARM.forward(clamped)))
    assert _cost(res.position_error, res.orientation_error) <= clamp_cost + ATOL_M


def _cost(position_error: float, orientation_error: float) -> float:
    """The weighted residual norm the nearest-feasible solve minimises, m."""
    return math.hypot(position_error, ORIENTATION_WEIGHT_M_PER_RAD * orientation_error)


def _errors(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    pos = float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))
    ang = float(Rotation.from_matrix(T_a[:3, :3].T @ T_b[:3, :3]).magnitude())
    return pos, ang


def test_psm_pose_at_rcm_is_unreachable() -> None:
    T = np.eye(4)  # tip at the RCM: the wrist point cannot get there
    res = PSM_ARM.solve(T)
    assert res.status is IKStatus.UNREACHABLE
    assert PSM_ARM.within_limits(res.q)
    assert res.position_error > 0.01


def test_solve_camera_round_trip() -> None:
    rng = np.random.default_rng(6)
    T_tip_cam = np.eye(4)
    T_tip_cam[:3, :3] = Rotation.from_rotvec([0.1, -0.3, 0.2]).as_matrix()
    T_tip_cam[:3, 3] = [0.002, -0.001, 0.005]
    for _ in range(30):
        q = _random_q(PSM_ARM, rng)
        T_rcm_cam = PSM_ARM.forward(q) @ T_tip_cam
        res = PSM_ARM.solve_camera(T_rcm_cam, T_tip_cam, q_seed=q)
        assert res.ok
        np.testing.assert_allclose(PSM_ARM.forward_camera(res.q, T_tip_cam), T_rcm_cam, atol=ATOL_M)


# ---------------------------------------------------------------------------- Jacobian
def _fd_jacobian_error(arm: PSM | ECM, J: np.ndarray, q: np.ndarray) -> float:
    """Max |J - J_fd| using central differences of position and rotation."""
    worst = 0.0
    for i in range(arm.n_joints):
        dq = np.zeros(arm.n_joints)
        dq[i] = FD_STEP
        Tp, Tm = arm.forward(q + dq), arm.forward(q - dq)
        v = (Tp[:3, 3] - Tm[:3, 3]) / (2 * FD_STEP)
        w = Rotation.from_matrix(Tp[:3, :3] @ Tm[:3, :3].T).as_rotvec() / (2 * FD_STEP)
        worst = max(worst, float(np.abs(J[:, i] - np.concatenate([v, w])).max()))
    return worst


@pytest.mark.parametrize("arm", [PSM_ARM, ECM_ARM], ids=["psm", "ecm"])
def test_jacobian_matches_finite_differences(arm: PSM | ECM) -> None:
    rng = np.random.default_rng(7)
    for _ in range(20):
        q = _random_q(arm, rng, margin=0.01)
        J = arm.jacobian(q)
        assert J.shape == (6, arm.n_joints)
        assert _fd_jacobian_error(arm, J, q) < FD_ATOL


def test_wrong_jacobian_is_caught() -> None:
    rng = np.random.default_rng(8)
    q = _random_q(PSM_ARM, rng, margin=0.05)
    J = PSM_ARM.jacobian(q)
    swapped = J.copy()
    swapped[:, [3, 4]] = swapped[:, [4, 3]]
    perturbed = J.copy()
    perturbed[0, 5] += 1e-4
    angular_first = np.vstack([J[3:], J[:3]])
    for wrong in (swapped, perturbed, angular_first):
        assert _fd_jacobian_error(PSM_ARM, wrong, q) > FD_ATOL


# ---------------------------------------------------------------------------- ECM IK
def _look_pose(p: np.ndarray, z: np.ndarray, roll: float) -> np.ndarray:
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z]) @ Rotation.from_euler("z", roll).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def test_ecm_ik_raises_a_shallow_insertion_to_40_mm_and_says_so() -> None:
    """The dVRK's ``mtsIntuitiveResearchKitECM::InverseKinematics`` rule: insertion ≥ 40 mm.

    A goal on the axis at 10 mm is met at 40 mm on the same axis, ``CLAMPED_TO_LIMITS``; the
    joint limit itself (``clamp``, ``servo_jp``) stays 0 m.
    """
    q = np.array([0.2, -0.1, 0.01, 0.3])  # rad, rad, m, rad
    res = ECM_ARM.solve(ECM_ARM.forward(q), q_seed=q)
    assert res.status is IKStatus.CLAMPED_TO_LIMITS
    assert res.q[2] == pytest.approx(ECM_IK_MIN_INSERTION, abs=ATOL_M)  # bounded lsq: 1e-9 span
    np.testing.assert_allclose(res.q[[0, 1, 3]], q[[0, 1, 3]], atol=ATOL_RAD)
    assert res.position_error == pytest.approx(ECM_IK_MIN_INSERTION - q[2], abs=ATOL_M)
    assert ECM_ARM.clamp(q)[2] == q[2]


def test_ecm_round_trip() -> None:
    rng = np.random.default_rng(9)
    for _ in range(100):
        q = _random_ecm_ik_q(rng)  # a depth the dVRK's IK allows
        res = ECM_ARM.solve(ECM_ARM.forward(q), q_seed=q)
        assert res.status is IKStatus.OK
        np.testing.assert_allclose(res.q, q, atol=1e-7)


def test_ecm_residual_zero_iff_axis_through_rcm() -> None:
    rng = np.random.default_rng(10)
    for _ in range(50):
        q = _random_ecm_ik_q(rng, margin=0.1)  # a depth the dVRK's IK allows
        on_axis = ECM_ARM.forward(q)
        p = on_axis[:3, 3]
        # the optical axis (z) passes through the RCM: z = p / |p|
        np.testing.assert_allclose(on_axis[:3, 2], p / np.linalg.norm(p), atol=ATOL_RAD)
        res = ECM_ARM.solve(on_axis, q_seed=np.zeros(4))
        assert res.status is IKStatus.OK
        assert res.position_error < ATOL_M
        assert res.orientation_error < ATOL_RAD
        # tilt the optical axis by `tilt` about an axis ⟂ to it: the residual is the tilt
        tilt = rng.uniform(0.05, 0.5)
        tilt_axis = np.cross(p, rng.normal(size=3))
        R_tilt = Rotation.from_rotvec(tilt * tilt_axis / np.linalg.norm(tilt_axis)).as_matrix()
        off_axis = on_axis.copy()
        off_axis[:3, :3] = R_tilt @ on_axis[:3, :3]
        res_off = ECM_ARM.solve(off_axis)
        assert res_off.status is IKStatus.UNREACHABLE
        assert res_off.position_error < ATOL_M  # position first
        assert res_off.orientation_error == pytest.approx(tilt, abs=1e-9)


def test_ecm_exact_agrees_with_the_full_solve() -> None:
    """The control loop's early-exit exact solve says yes exactly when ``solve_unchecked`` is OK.

    Goals: reachable poses (and poses beyond the joint limits) with their orientation turned by
    0 or by 1e-12 … 1e-2 rad, across the early exit's 1e-6 rad threshold and the 1e-9 rad
    orientation tolerance.
    """
    rng = np.random.default_rng(12)
    for _ in range(400):
        q = _random_q(ECM_ARM, rng, margin=-0.2)  # also beyond the limits (clamped)
        goal = ECM_ARM.forward(q)
        turn = 0.0 if rng.random() < 0.25 else 10.0 ** rng.uniform(-12.0, -2.0)
        axis = rng.normal(size=3)
        goal[:3, :3] = (
            Rotation.from_rotvec(turn * axis / np.linalg.norm(axis)).as_matrix() @ (goal[:3, :3])
        )
        full = ECM_ARM.solve_unchecked(goal, q)
        fast = ECM_ARM.exact12_unchecked(pose12_from_matrix(goal), q)
        assert (fast is not None) == full.ok
        if fast is not None:
            assert fast == full.q.tolist()


def test_ecm_goal_outside_limits_is_clamped() -> None:
    goal = ECM_ARM.forward([0.0, 0.0, 0.2, 0.3])
    goal[:3, 3] = [0.0, 0.0, -0.4]  # 0.4 m deep on the same axis: beyond 0.255 m insertion
    res = ECM_ARM.solve(goal)
    assert res.status is IKStatus.CLAMPED_TO_LIMITS
    assert ECM_ARM.within_limits(res.q)
    assert res.position_error == pytest.approx(0.4 - 0.255 - 0.0007, abs=1e-6)
    assert res.orientation_error < ATOL_RAD  # the axis still points at the goal
    # axis through the RCM but beyond the yaw limit: still a limit problem, not a DoF one
    p_side = 0.2 * np.array([0.0, 0.0, 1.0])  # straight up: cos(yaw) cos(pitch) < 0
    res_side = ECM_ARM.solve(_look_pose(p_side, p_side, 0.0))
    assert res_side.status is IKStatus.CLAMPED_TO_LIMITS
    assert ECM_ARM.within_limits(res_side.q)


# ---------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_input_rejected(bad: float) -> None:
    q = np.zeros(6)
    q[2] = bad
    for fn in (PSM_ARM.forward, PSM_ARM.jacobian):
        with pytest.raises(ValueError, match="q"):
            fn(q)
    T = np.eye(4)
    T[0, 3] = bad
    with pytest.raises(ValueError, match="T_rcm_tip"):
        PSM_ARM.solve(T)
    with pytest.raises(ValueError, match="T_rcm_tip"):
        ECM_ARM.inverse(T)
    with pytest.raises(ValueError, match="q_seed"):
        PSM_ARM.solve(PSM_ARM.forward(np.zeros(6)), q_seed=q)


def test_malformed_pose_rejected() -> None:
    with pytest.raises(ValueError, match="T_rcm_tip"):
        PSM_ARM.solve(2.0 * np.eye(4))
    with pytest.raises(ValueError, match="T_rcm_tip"):
        PSM_ARM.solve(np.eye(3))
    with pytest.raises(ValueError, match="q"):
        PSM_ARM.forward(np.zeros(5))

"""Property tests of the orientation-aware goal pose (paper Sec. III-B)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from endocam import goal_pose, look_at_pose
from endocam.control.goal import SIDE_HYSTERESIS
from endocam.view import ROLL_HOLD_ANGLE, ROLL_LEVEL_ANGLE

ATOL_M = 1e-9  # m, float round-off on positions of order 0.1 m
ATOL_UNIT = 1e-9  # unitless, round-off on unit-vector products
UP = np.array([0.0, 0.0, 1.0])

coord = st.floats(-0.5, 0.5, allow_nan=False)
component = st.floats(-1.0, 1.0, allow_nan=False)
normals = st.tuples(component, component, component).filter(lambda v: np.linalg.norm(v) > 1e-3)
distances = st.floats(1e-3, 0.3, allow_nan=False)


def _check_rigid(T: np.ndarray) -> None:
    R = T[:3, :3]
    assert np.all(np.isfinite(T))
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=ATOL_UNIT)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=ATOL_UNIT)
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])


@settings(max_examples=300, deadline=None)
@given(p=st.tuples(coord, coord, coord), n=normals, d_f=distances)
@example(p=(0.0, 0.0, 0.05), n=(0.0, 0.0, 1.0), d_f=0.05)  # normal parallel to up
@example(p=(0.0, 0.0, 0.05), n=(0.0, 0.0, -1.0), d_f=0.05)  # anti-parallel
@example(p=(0.0, 0.0, 0.05), n=(1.0, 0.0, 0.0), d_f=0.05)  # exactly horizontal
@example(p=(0.0, 0.0, 0.05), n=(1.0, 0.0, 1e-7), d_f=0.05)  # near-horizontal
@example(p=(0.0, 0.0, 0.05), n=(1e-7, 0.0, 1.0), d_f=0.05)  # near-vertical
def test_goal_pose_invariants(p: tuple, n: tuple, d_f: float) -> None:
    T = goal_pose(p, n, d_f)
    _check_rigid(T)
    p_c = np.array(p)
    n_u = np.array(n) / np.linalg.norm(n)
    p_g, x, y, z = T[:3, 3], T[:3, 0], T[:3, 1], T[:3, 2]
    # On the normal, at the working distance, above the tissue.
    assert np.linalg.norm(p_g - p_c) == pytest.approx(d_f, abs=ATOL_M)
    assert abs(abs(z @ n_u) - 1.0) < ATOL_UNIT
    assert (p_g - p_c) @ UP >= -ATOL_M
    # Looks at the feature: the feature is on the optical axis, in front.
    assert (p_c - p_g) @ z == pytest.approx(d_f, abs=ATOL_M)
    np.testing.assert_allclose(np.cross(p_c - p_g, z), 0.0, atol=ATOL_M)
    # Image upright; horizon exactly level outside the singular band.
    assert y @ UP <= ATOL_UNIT
    if np.linalg.norm(np.cross(z, UP)) >= math.sin(ROLL_LEVEL_ANGLE):
        assert abs(x @ UP) < ATOL_UNIT


def test_horizon_formula_matches_paper() -> None:
    """With z = −n, the paper's x = up × n equals normalize(z × up)."""
    n = np.array([0.3, -0.5, 0.8])
    n /= np.linalg.norm(n)
    T = goal_pose([0, 0, 0], n, 0.05)
    paper_x = np.cross(UP, n)
    np.testing.assert_allclose(T[:3, 0], paper_x / np.linalg.norm(paper_x), atol=ATOL_UNIT)


def _roll_reference(T: np.ndarray) -> np.ndarray:
    return T[:3, 0]


def test_singularity_keeps_previous_roll() -> None:
    rng = np.random.default_rng(7)
    for _ in range(20):
        yaw = rng.uniform(-np.pi, np.pi)
        prev = np.eye(4)
        prev[:3, :3] = Rotation.from_euler("xz", [np.pi, yaw]).as_matrix()  # looking down
        T = goal_pose([0, 0, 0.05], [0, 0, 1], 0.05, previous=prev)
        _check_rigid(T)
        np.testing.assert_allclose(T[:3, 0], prev[:3, 0], atol=ATOL_UNIT)


def test_singularity_without_previous_uses_documented_default() -> None:
    T = goal_pose([0, 0, 0.05], [0, 0, 1], 0.05)
    _check_rigid(T)
    np.testing.assert_allclose(T[:3, 0], [1, 0, 0], atol=ATOL_UNIT)  # world x points right


def _sweep(tilts_rad: np.ndarray, azimuth: float) -> list[np.ndarray]:
    """Goals for a normal tilting through vertical in the plane at ``azimuth``."""
    goals = []
    prev = None
    for a in tilts_rad:
        n = [math.sin(a) * math.cos(azimuth), math.sin(a) * math.sin(azimuth), math.cos(a)]
        T = goal_pose([0, 0, 0.05], n, 0.05, previous=prev)
        goals.append(T)
        prev = T
    return goals


@pytest.mark.parametrize("azimuth", [0.0, 0.7, 2.5])
def test_tilting_through_vertical_has_no_sudden_roll(azimuth: float) -> None:
    step = math.radians(0.05)  # rad of normal tilt per control step
    tilts = np.arange(math.radians(30.0), -math.radians(30.0), -step)
    goals = _sweep(tilts, azimuth)
    # The roll unwinds at most ~1.5 π / (level − hold) rad per rad of tilt (smoothstep slope 1.5).
    max_roll_rate = 1.5 * math.pi / (ROLL_LEVEL_ANGLE - ROLL_HOLD_ANGLE)
    bound = (max_roll_rate + 1.0) * step
    rot = [Rotation.from_matrix(T[:3, :3]) for T in goals]
    jumps = [float((a.inv() * b).magnitude()) for a, b in itertools.pairwise(rot)]
    assert max(jumps) <= bound
    # Both ends are level and upright, so the camera did roll about 180° in total, smoothly.
    for T in (goals[0], goals[-1]):
        assert abs(T[:3, 0] @ UP) < ATOL_UNIT
        assert T[:3, 1] @ UP < 0
    assert goals[0][:3, 0] @ goals[-1][:3, 0] < -0.99


def test_naive_horizon_rule_would_fail_the_roll_check() -> None:
    """The sweep check is able to fail: the memoryless rule flips 180° in one step."""
    step = math.radians(0.05)
    before = goal_pose([0, 0, 0.05], [math.sin(step), 0, math.cos(step)], 0.05)
    after = goal_pose([0, 0, 0.05], [-math.sin(step), 0, math.cos(step)], 0.05)
    # Without `previous`, each call is level and upright on its own: x flips by π.
    assert before[:3, 0] @ after[:3, 0] < -0.99


def test_side_hysteresis_near_horizontal() -> None:
    p_c = [0.0, 0.0, 0.05]
    below = math.radians(5.0)  # normal 5° below horizontal: inside the hysteresis band
    n = np.array([math.cos(below), 0.0, -math.sin(below)])
    # No memory: camera on the side with n·up ≥ 0, i.e. along −n.
    T_fresh = goal_pose(p_c, n, 0.05)
    assert (T_fresh[:3, 3] - p_c) @ n < 0
    # Coming from the +n side (normal was slightly above horizontal): stay there.
    n_prev = np.array([math.cos(below), 0.0, math.sin(below)])
    prev = goal_pose(p_c, n_prev, 0.05)
    assert (prev[:3, 3] - p_c) @ n_prev > 0
    T_kept = goal_pose(p_c, n, 0.05, previous=prev)
    assert (T_kept[:3, 3] - p_c) @ n > 0
    # Past the band the camera changes side to stay above the tissue.
    far = SIDE_HYSTERESIS + math.radians(1.0)
    n_far = np.array([math.cos(far), 0.0, -math.sin(far)])
    T_switched = goal_pose(p_c, n_far, 0.05, previous=T_kept)
    assert (T_switched[:3, 3] - p_c) @ UP > 0


def test_side_does_not_hop_under_noise() -> None:
    rng = np.random.default_rng(3)
    p_c = [0.0, 0.0, 0.05]
    prev = None
    sides = []
    for _ in range(500):
        tilt = rng.normal(0.0, math.radians(3.0))  # noisy near-horizontal normal
        n = [math.cos(tilt), 0.0, math.sin(tilt)]
        T = goal_pose(p_c, n, 0.05, previous=prev)
        sides.append(np.sign(T[0, 3]))
        prev = T
    assert len(set(sides)) == 1


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"p_c": [0, 0, 0], "n": [0, 0, 0], "d_f": 0.05}, "n"),
        ({"p_c": [0, 0, 0], "n": [np.nan, 0, 1], "d_f": 0.05}, "n"),
        ({"p_c": [0, 0, 0], "n": [np.inf, 0, 1], "d_f": 0.05}, "n"),
        ({"p_c": [0, np.nan, 0], "n": [0, 0, 1], "d_f": 0.05}, "p_c"),
        ({"p_c": [0, 0, np.inf], "n": [0, 0, 1], "d_f": 0.05}, "p_c"),
        ({"p_c": [0, 0], "n": [0, 0, 1], "d_f": 0.05}, "p_c"),
        ({"p_c": [0, 0, 0], "n": [0, 0, 1], "d_f": 0.0}, "d_f"),
        ({"p_c": [0, 0, 0], "n": [0, 0, 1], "d_f": -0.01}, "d_f"),
        ({"p_c": [0, 0, 0], "n": [0, 0, 1], "d_f": float("nan")}, "d_f"),
    ],
)
def test_bad_input_names_the_argument(kwargs: dict, name: str) -> None:
    with pytest.raises(ValueError, match=rf"^{name}\b"):
        goal_pose(kwargs["p_c"], kwargs["n"], kwargs["d_f"])


def test_bad_previous_is_rejected() -> None:
    with pytest.raises(ValueError, match="previous"):
        goal_pose([0, 0, 0], [0, 0, 1], 0.05, previous=np.full((4, 4), np.nan))


def test_look_at_pose_centres_the_target() -> None:
    rng = np.random.default_rng(11)
    for _ in range(50):
        p_cam = rng.uniform(-0.2, 0.2, 3)
        target = rng.uniform(-0.2, 0.2, 3)
        T = look_at_pose(p_cam, target)
        _check_rigid(T)
        d = target - p_cam
        np.testing.assert_allclose(T[:3, 2], d / np.linalg.norm(d), atol=ATOL_UNIT)
    with pytest.raises(ValueError, match="p_target - p_cam"):
        look_at_pose([0, 0, 0], [0, 0, 0])


PORT = np.array([0.2, 0.0, 0.12])  # m: a camera port above and beside the features


@settings(max_examples=300, deadline=None)
@given(p=st.tuples(coord, coord, coord), n=normals, d_f=distances)
@example(p=(0.0, 0.0, 0.05), n=(1.0, 0.0, 0.0), d_f=0.05)  # normal pointing at the port side
@example(p=(0.0, 0.0, 0.05), n=(0.0, 1.0, 0.0), d_f=0.05)  # normal across the port direction
def test_port_side_faces_the_port(p: tuple, n: tuple, d_f: float) -> None:
    p_c = np.array(p)
    if np.linalg.norm(PORT - p_c) < 1e-3:
        return
    T = goal_pose(p, n, d_f, port=PORT)
    _check_rigid(T)
    toward = (PORT - p_c) / np.linalg.norm(PORT - p_c)
    # the camera sits on the port side of the feature, so it looks away from the port
    assert (T[:3, 3] - p_c) @ toward >= -ATOL_M
    assert T[:3, 2] @ toward <= ATOL_UNIT
    assert (p_c - T[:3, 3]) @ T[:3, 2] == pytest.approx(d_f, abs=ATOL_M)


def test_port_side_keeps_the_camera_above_min_height() -> None:
    # normal tipping down towards the port: the port side would put the camera under the board
    p_c = np.array([0.0, 0.0, 0.03])
    n = np.array([1.0, 0.0, -1.0]) / math.sqrt(2.0)
    d_f = 0.05
    T = goal_pose(p_c, n, d_f, port=PORT)
    assert T[2, 3] < 0.0  # no floor given: the port side, below the board
    T_floor = goal_pose(p_c, n, d_f, port=PORT, min_height=0.015)
    assert T_floor[2, 3] >= 0.015  # with a floor: the other side, above it
    np.testing.assert_allclose(T_floor[:3, 3], p_c - d_f * n, atol=ATOL_M)


def test_port_side_hysteresis_keeps_the_previous_side() -> None:
    p_c = np.array([0.0, 0.0, 0.05])
    toward = (PORT - p_c) / np.linalg.norm(PORT - p_c)
    side = np.cross(toward, UP)
    side /= np.linalg.norm(side)
    tipped = math.radians(5.0)  # normal 5° past perpendicular to the port direction
    n = math.cos(tipped) * side - math.sin(tipped) * toward
    previous = goal_pose(p_c, side, 0.05, port=PORT)  # camera on the +side half-space
    on_prev = (previous[:3, 3] - p_c) @ side > 0.0
    T = goal_pose(p_c, n, 0.05, port=PORT, previous=previous, side_hysteresis=math.radians(10))
    assert ((T[:3, 3] - p_c) @ side > 0.0) == on_prev  # kept within the hysteresis
    T = goal_pose(p_c, n, 0.05, port=PORT, previous=previous, side_hysteresis=math.radians(2))
    assert (T[:3, 3] - p_c) @ toward >= 0.0  # beyond it: the port side


def test_port_at_the_feature_is_rejected() -> None:
    with pytest.raises(ValueError, match="port"):
        goal_pose((0.0, 0.0, 0.05), (1.0, 0.0, 0.0), 0.05, port=(0.0, 0.0, 0.05))

"""The ``endocam-visible`` camera: what the wire and the rim hide, the side it takes, hysteresis.

The scorer's pieces (``control.occlusion``: numpy, and its compiled loop
``control.sightline.view_shares``) on constructed scenes, the side rule (``choose_side``) and
the policy on a scene built so that one side of the ring sees the contact and the other does
not: a straight wire through the ring's hole, leaning over the contact on one side. The
policy's safety invariants are the tracker's, checked in ``test_tracker_kernel.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from endocam import StereoCamera, look_at_pose
from endocam.control.config import ControllerConfig
from endocam.control.occlusion import (
    WEIGHT_FLOOR,
    RingShape,
    contact_points,
    direction_table,
    eye_positions,
    gap_points,
    gap_points_along,
    hidden,
    occluders,
    segment_distances,
    sight,
    view_directions,
    view_scores,
)
from endocam.control.policies.visible import (
    SideScore,
    VisibleConfig,
    VisiblePolicy,
    choose_side,
    closing_fraction,
    pose_between,
    predicted_pose,
)
from endocam.control.sightline import view_shares
from endocam.control.types import Observation, PolicyContext, TrackingState
from endocam.task.config import RingConfig, WireConfig
from endocam.task.wire import Wire

RING = RingShape.of(RingConfig())
WIRE_R = 1.0e-3  # m, the wire's radius
CAMERA = StereoCamera()
FOCAL_PX = float(CAMERA.intrinsics.K[1, 1])
DT = 0.01  # s, control period
ATOL_M = 1e-12  # m: two formulas for the same distance
ATOL_ANGLE = 1e-6  # rad: an axis on the normal up to round-off
ATOL_SHARE = 1e-12  # unitless: the compiled and the numpy share of the same sight lines
RATE_RTOL = 1e-9  # relative: ruckig's limits hold to round-off
P_RING = np.array([0.0, 0.0, 0.06])  # m, the constructed scene's ring centre
N_RING = np.array([1.0, 0.0, 0.1]) / math.hypot(1.0, 0.1)  # its normal: the first side is +1
E_CONTACT = np.array([0.0, 1.0, 0.0])  # ⟂ N_RING: the wire sits towards the rim on this side


def ring_pose(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(4, 4) ring pose at ``p`` (m) with unit normal ``n`` as its z axis."""
    z = n / np.linalg.norm(n)
    x = np.cross([0.0, 0.0, 1.0], z)
    x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-6 else np.array([1.0, 0.0, 0.0])
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = p
    return T


def leaning_wire(lean: float) -> np.ndarray:
    """(K, 3) a straight wire through the hole 2 mm towards ``E_CONTACT`` from the centre,
    leaning ``lean`` (tan) towards it on the normal's side: from ``+n`` it covers the contact."""
    d = N_RING + lean * E_CONTACT
    d /= np.linalg.norm(d)
    q = P_RING + 2.0e-3 * E_CONTACT
    return q + np.linspace(-0.08, 0.08, 81)[:, None] * d


def test_segment_distances_are_the_sampled_minimum() -> None:
    """Ericson's clamped closest points against a dense sampling of both segments."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(6, 3)), rng.normal(size=(6, 3))
    p, q = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    p[0], q[0] = p[1], p[1]  # a zero-length segment
    b[1] = a[1] + 2.0 * (q[2] - p[2])  # a parallel pair
    got = segment_distances(a, b, p, q)
    s = np.linspace(0.0, 1.0, 201)
    for i in range(6):
        x = a[i] + s[:, None] * (b[i] - a[i])
        for j in range(5):
            y = p[j] + s[:, None] * (q[j] - p[j])
            sampled = np.min(np.linalg.norm(x[:, None] - y[None], axis=2))
            step = (np.linalg.norm(b[i] - a[i]) + np.linalg.norm(q[j] - p[j])) / 200
            assert got[i, j] <= sampled + ATOL_M
            assert got[i, j] >= sampled - step  # the sampling's resolution


def test_a_point_behind_the_wire_or_the_rim_is_hidden() -> None:
    """Behind a wire segment: hidden; beside it: not; through the rim's tube: hidden."""
    T = ring_pose(P_RING, np.array([0.0, 0.0, 1.0]))
    window = np.array([[-0.03, 0.0, 0.08], [0.03, 0.0, 0.08]])  # a wire 20 mm above the ring
    target = P_RING + np.array([0.0, 0.0, 0.0])
    eyes = np.array(
        [
            [0.0, 0.0, 0.12],  # straight above: through the wire
            [0.0, 0.02, 0.12],  # beside it
            [0.05, 0.0, P_RING[2]],  # edge-on from +x: through the rim's tube
        ]
    )
    got = hidden(eyes, target[None], window, WIRE_R, T, RING)[:, 0]
    assert got.tolist() == [True, False, True]


def test_the_compiled_sight_lines_are_the_numpy_ones() -> None:
    """``view_shares`` (compiled, coarse-to-fine rim test) against ``view_scores`` (numpy)."""
    rng = np.random.default_rng(1)
    mask_rng = np.random.default_rng(2)  # its own stream: the scenes stay those of rng
    table = direction_table(np.radians([15.0]), 5)
    agree = 0
    for lean in rng.uniform(-1.0, 1.0, size=4):
        n = N_RING + rng.normal(scale=0.2, size=3)
        T = ring_pose(P_RING, n / np.linalg.norm(n))
        window = leaning_wire(float(lean))[::2]
        gaps = gap_points(T, window, RING, WIRE_R, 12, 1.5e-3)
        dirs = np.vstack([view_directions(T[:3, 2], table), -view_directions(T[:3, 2], table)])
        eyes = eye_positions(P_RING, dirs, 0.045, CAMERA.baseline)
        ref = view_scores(eyes, -dirs, gaps, window, T, RING, WIRE_R, FOCAL_PX, 2.0)
        args = (np.vstack(eyes), np.vstack([-dirs, -dirs]), sight(gaps, FOCAL_PX, 2.0),
                occluders(window, WIRE_R, T, RING))  # fmt: skip
        got = view_shares(*args, np.ones(2 * len(dirs), dtype=bool))
        np.testing.assert_allclose(got, np.concatenate([ref[:, 0], ref[:, 1]]), atol=ATOL_SHARE)
        agree += int(np.ptp(got) > 0.0)
        scored = mask_rng.random(2 * len(dirs)) < 0.5  # not scored: 0; the others as before
        np.testing.assert_array_equal(view_shares(*args, scored), np.where(scored, got, 0.0))
    assert agree >= 2  # the scenes tell views apart


def test_the_clear_side_scores_higher() -> None:
    """From ``+n`` the leaning wire covers the contact; from ``−n`` it leans away."""
    T = ring_pose(P_RING, N_RING)
    window = leaning_wire(0.6)
    gaps = gap_points(T, window, RING, WIRE_R, 12, 1.5e-3)
    heaviest = gaps.points[np.argmax(gaps.weights)]
    assert (heaviest - P_RING) @ E_CONTACT > 0.9 * 2.0e-3  # the contact: towards E_CONTACT
    dirs = np.array([N_RING, -N_RING])
    eyes = eye_positions(P_RING, dirs, 0.045, CAMERA.baseline)
    scores = view_scores(eyes, -dirs, gaps, window, T, RING, WIRE_R, FOCAL_PX, 2.0)
    assert scores[1].min() > 0.95 and scores[0].max() < 0.7  # (C, eyes)
    blocked = hidden(np.vstack(eyes), heaviest[None], window, WIRE_R, T, RING)[:, 0]
    assert blocked.tolist() == [True, False, True, False]  # left +n, left -n, right +n, right -n


def score(utility: float) -> SideScore:
    return SideScore(utility, (0.0, 0.0, 0.0))


def test_side_hysteresis_holds_against_a_flicker() -> None:
    """The other side is taken only after beating this one by ``side_margin`` for
    ``side_hold`` s at every scoring; a one-scoring flicker resets the wait."""
    cfg = VisibleConfig()
    better = {1.0: score(0.2), -1.0: score(0.2 + cfg.side_margin + 0.1)}
    level = {1.0: score(0.2), -1.0: score(0.2 + cfg.side_margin)}  # not beyond the margin
    assert choose_side(0.0, better, None, 0.0, cfg) == (-1.0, None)  # the first: outright
    side, since = choose_side(1.0, better, None, 0.0, cfg)  # a flicker ...
    assert (side, since) == (1.0, 0.0)
    side, since = choose_side(side, level, since, cfg.score_period, cfg)  # ... gone
    assert (side, since) == (1.0, None)
    t = 1.0
    side, since = choose_side(1.0, better, None, t, cfg)
    while t < 1.0 + cfg.side_hold - 1e-9:
        assert side == 1.0
        t += cfg.score_period
        side, since = choose_side(side, better, since, t, cfg)
    assert side == -1.0 and since is None


ATOL_CONTACT_RAD = math.radians(1.0)  # rad: the contact search's step (CONTACT_SEARCH)


def test_the_gap_points_of_several_poses_are_each_poses_own() -> None:
    """``gap_points_along`` measures several poses in one batch: each pose's points,
    clearances and weights are those of the pose alone (its weights floored against its own
    largest, not the batch's), whatever the others are: here a ring touching the wire and two
    farther from it (the last 3 mm), whose weights the first's would otherwise floor to zero."""
    window = leaning_wire(0.0)
    poses = [ring_pose(P_RING + k * E_CONTACT, N_RING) for k in (-1.0e-3, 1.0e-3, 2.0e-3)]  # m
    batch = gap_points_along(poses, window, RING, WIRE_R, 12, 1.5e-3)
    assert len(batch) == len(poses)
    for T, got in zip(poses, batch, strict=True):
        alone = gap_points(T, window, RING, WIRE_R, 12, 1.5e-3)
        for a, b in zip(
            (got.points, got.directions, got.clearances, got.weights),
            (alone.points, alone.directions, alone.clearances, alone.weights),
            strict=True,
        ):
            np.testing.assert_allclose(a, b, rtol=0.0, atol=ATOL_M)
    # the nearest rim points far enough apart that a batch-wide floor would zero the last's
    nearest = np.array([b.clearances.min() for b in batch])
    assert np.ptp(np.maximum(nearest, 0.0)) > -1.5e-3 * math.log(WEIGHT_FLOOR)  # weights clamp c
    assert all(np.count_nonzero(b.weights) > 0 for b in batch)


def test_the_contact_neighbourhood_surrounds_the_rim_point_nearest_the_wire() -> None:
    """``contact_points`` spreads its points evenly over ``±arc`` of rim about the rim point
    nearest the wire (found to the search's 1°), each weighted 1: with the wire 2 mm towards
    ``E_CONTACT`` the middle point is the rim's on ``E_CONTACT``, the ends ``arc / R`` rad
    either side, and every point's clearance is at least the middle's."""
    T = ring_pose(P_RING, N_RING)
    window = leaning_wire(0.0)
    arc, count = 0.7e-3, 7  # m, points
    got = contact_points(T, window, RING, WIRE_R, arc, count)
    assert got.points.shape == (count, 3) and np.all(got.weights == 1.0)
    c = got.clearances
    assert np.argmin(c) == count // 2 and np.all(c >= c[count // 2])
    np.testing.assert_allclose(c[count // 2], RING.major - 2.0e-3 - RING.minor - WIRE_R,
                               atol=RING.major * (1.0 - math.cos(ATOL_CONTACT_RAD)))  # fmt: skip
    rim = got.points - P_RING  # gap points: on the wire's side of each rim point
    across = rim - (rim @ N_RING)[:, None] * N_RING
    bearing = np.arctan2(across @ np.cross(N_RING, E_CONTACT), across @ E_CONTACT)
    assert abs(bearing[count // 2]) <= ATOL_CONTACT_RAD
    assert np.all(np.diff(bearing) * np.sign(bearing[-1] - bearing[0]) > 0.0)  # in order
    one = contact_points(T, window, RING, WIRE_R, arc, 1)
    np.testing.assert_allclose(one.points[0], got.points[count // 2], atol=ATOL_M)


def test_the_scorer_judges_the_contact_neighbourhood(monkeypatch: pytest.MonkeyPatch) -> None:
    """With ``contact_arc`` the tilt is scored on the contact's neighbourhood, equally
    weighted (``contact_points`` of them), besides the whole rim's ``rim_points`` (the side's):
    the points handed to the second sight-line call all lie within the arc of the rim's point
    nearest the wire; without it there is one call, on the whole rim."""
    import endocam.control.policies.visible as visible

    wire = centred_wire()
    up_perp = np.array([0.0, 0.0, 1.0]) - N_RING[2] * N_RING
    rcm = P_RING + 0.25 * up_perp / np.linalg.norm(up_perp)
    start = look_at_pose(P_RING + 0.045 * N_RING, P_RING)
    touching = ring_pose(P_RING + 2.8e-3 * E_CONTACT, N_RING)  # the rim 0.2 mm from the wire
    handed: list[tuple[np.ndarray, np.ndarray]] = []

    def shares(eyes: np.ndarray, axes: np.ndarray, seen: object, *_: object) -> np.ndarray:
        handed.append((np.asarray(seen.weights), np.asarray(seen.points)))  # type: ignore[attr-defined]
        return np.zeros(len(eyes))

    monkeypatch.setattr(visible, "view_shares", shares)
    for arc in (0.0, 0.7e-3):
        cfg = VisibleConfig(contact_arc=arc)
        context = PolicyContext(CAMERA, start, touching, rcm, DT, wire=wire, ring=RingConfig())
        policy = VisiblePolicy(ControllerConfig(), cfg)
        policy.reset(context)
        handed.clear()
        policy._score([touching], 0.0)
        assert len(handed[0][0]) == cfg.rim_points
        if arc == 0.0:
            assert len(handed) == 1
            continue
        assert len(handed) == 2
        weights, points = handed[1]
        assert len(weights) == cfg.contact_points and np.all(weights == 1.0)
        line = P_RING + np.linspace(-0.08, 0.08, 5)[:, None] * N_RING  # the wire's centre line
        contact = contact_points(touching, line, RING, WIRE_R, 0.0, 1).points[0]
        # the wire's straight: the gap points fan from one wire point, within the arc
        assert np.max(np.linalg.norm(points - contact, axis=1)) <= arc + ATOL_M


def test_the_side_is_judged_on_the_whole_rim_the_tilt_on_the_contact(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """With ``contact_arc``, two judgements: the whole rim's shares (first sight-line call)
    decide the side, the contact neighbourhood's (second) the tilt. A scene where the rim
    sees both sides alike but the contact would favour the other side's view starts no side
    change, and still tilts on this side to the view that shows the contact; judged on the
    contact alone (the rim's shares replaced by the contact's) it would start one."""
    import endocam.control.policies.visible as visible

    wire = centred_wire()
    up_perp = np.array([0.0, 0.0, 1.0]) - N_RING[2] * N_RING
    rcm = P_RING + 0.25 * up_perp / np.linalg.norm(up_perp)
    start = look_at_pose(P_RING + 0.045 * N_RING, P_RING)
    touching = ring_pose(P_RING + 2.8e-3 * E_CONTACT, N_RING)  # the rim 0.2 mm from the wire

    def contact_shares(m: int) -> np.ndarray:
        one = np.full(m, 0.5)  # this side's tilted views: half the contact
        one[0] = one[-1] = 0.0  # its normal (and the target on it): none
        one[-2] = 1.0  # the other side's own view: all of it
        return np.concatenate([one, one])

    for rim_like_contact in (False, True):
        calls: list[int] = []

        def shares(
            eyes: np.ndarray,
            *_: object,
            calls: list[int] = calls,
            flat: bool = not rim_like_contact,
        ) -> np.ndarray:
            calls.append(1)
            m = len(eyes) // 2
            if len(calls) == 1 and flat:
                return np.full(2 * m, 0.6)  # the whole rim: every view alike
            return contact_shares(m)

        monkeypatch.setattr(visible, "view_shares", shares)
        context = PolicyContext(CAMERA, start, touching, rcm, DT, wire=wire, ring=RingConfig())
        policy = VisiblePolicy(ControllerConfig(), VisibleConfig(contact_arc=0.7e-3))
        policy.reset(context)
        policy._score([touching], 0.0)
        side = policy._want
        assert len(calls) == 2
        assert (policy._since is not None) is rim_like_contact  # a side change started
        assert policy._targets[side] != (0.0, 0.0, 0.0)  # tilted to show the contact


def test_visible_config_validates() -> None:
    with pytest.raises(ValueError, match="contact_points"):
        VisibleConfig(contact_points=0)
    with pytest.raises(ValueError, match="contact_arc"):
        VisibleConfig(contact_arc=-1e-3)
    with pytest.raises(ValueError, match="max_tilt"):
        VisibleConfig(max_tilt=math.radians(30.0))
    with pytest.raises(ValueError, match="azimuths"):
        VisibleConfig(azimuths=0)
    with pytest.raises(ValueError, match="side_hold"):
        VisibleConfig(side_hold=-1.0)


def test_the_policy_orbits_to_the_side_with_the_clear_hole() -> None:
    """On the leaning-wire scene the camera starts on ``+n`` (the tracker's first side), keeps
    it for ``side_hold`` s, then orbits to ``−n`` and stays; every command keeps the wire
    clearance."""
    knots = leaning_wire(0.6)[::20]
    wire = Wire(WireConfig(knots=tuple(tuple(k) for k in knots.tolist())))
    T_ring = ring_pose(P_RING, N_RING)
    up_perp = np.array([0.0, 0.0, 1.0]) - N_RING[2] * N_RING
    rcm = P_RING + 0.25 * up_perp / np.linalg.norm(up_perp)  # the same port angle either side
    start = look_at_pose(P_RING + 0.05 * N_RING + [0.0, 0.0, 0.01], P_RING)
    context = PolicyContext(CAMERA, start, T_ring, rcm, DT, wire=wire, ring=RingConfig())
    cfg = VisibleConfig(either_eye=False)  # the scene is built so that both eyes lose the gap
    policy = VisiblePolicy(ControllerConfig(), cfg)
    policy.reset(context)
    T_cam = start
    sides, states = [], set()
    for k in range(400):
        cmd = policy.step(Observation(k * DT, T_ring, T_cam))
        d, _ = wire.nearest_surface(cmd.T_world_cam[:3, 3].tolist())
        assert d >= policy.config.wire_clearance - ATOL_M
        states.add(cmd.state)
        sides.append(policy._side)
        T_cam = cmd.T_world_cam
    hold = round(cfg.side_hold / DT)
    assert set(sides[1:hold]) == {1.0}  # held for side_hold
    assert sides[-1] == -1.0 and set(sides[-100:]) == {-1.0}  # then taken, and kept
    assert policy.side_changes == 1 and TrackingState.PLANNING in states  # by an orbit
    assert policy.last_scores[-1.0].utility > policy.last_scores[1.0].utility


ATOL_PRED_M = 1e-9  # m: a constant-velocity motion extrapolated exactly (round-off only)
ATOL_PRED = 1e-9  # unitless: rotation matrix entries, the same


def test_the_axis_offset_moves_smoothly_even_when_its_target_reverses() -> None:
    """The offset (the turned normal's tilt) moves at most ``tilt_rate`` and changes its rate
    by at most ``tilt_acceleration · dt`` a step, also when a new target reverses its motion
    (round 18: a jump of its rate made the tracker's observation gate refuse the ring); it
    reaches each target and rests there."""
    cfg = VisibleConfig()
    up_perp = np.array([0.0, 0.0, 1.0]) - N_RING[2] * N_RING
    rcm = P_RING + 0.25 * up_perp / np.linalg.norm(up_perp)
    start = look_at_pose(P_RING + 0.045 * N_RING, P_RING)
    context = PolicyContext(CAMERA, start, ring_pose(P_RING, N_RING), rcm, DT,
                            wire=centred_wire(), ring=RingConfig())  # fmt: skip
    policy = VisiblePolicy(ControllerConfig(), cfg)
    policy.reset(context)
    policy._want = 1.0
    out, back = (0.2, 0.1, -0.05), (-0.2, 0.0, 0.1)  # tan θ: a tilt, then one the other way
    path = [np.array(policy._offset)]
    for target, steps in ((out, 8), (back, 60), (out, 60)):  # the first is cut off halfway
        policy._targets[1.0] = target
        for _ in range(steps):
            policy._advance()
            path.append(np.array(policy._offset))
        if steps == 60:
            assert policy._offset == target  # reached, exactly
    rate = np.diff(np.array(path), axis=0) / DT  # (steps, 3), 1/s
    assert np.max(np.linalg.norm(rate, axis=1)) <= cfg.tilt_rate * (1.0 + RATE_RTOL)
    jump = np.linalg.norm(np.diff(rate, axis=0), axis=1) / DT  # 1/s²
    assert np.max(jump) <= cfg.tilt_acceleration * (1.0 + RATE_RTOL)
    assert np.max(jump) > 0.5 * cfg.tilt_acceleration  # it did accelerate and reverse


def test_the_prediction_extrapolates_a_constant_velocity_and_caps_the_turn() -> None:
    """A ring moving at constant velocity is predicted where it will be; one turning at
    1 rad/s nearly so (first order); a turn beyond ``max_turn`` is cut; the frame stays
    orthonormal; no time between the samples: the newest pose."""
    rng = np.random.default_rng(7)
    tau, h = 0.1, 0.35  # s
    first_order_rad = (1.0 * h) ** 2 / 2.0  # rad: an axis on its cone, extrapolated along
    # the tangent, falls short by at most (ω h)² / 2 (ω = 1 rad/s)
    for _ in range(20):
        v = rng.normal(0.0, 0.05, 3)  # m/s
        w = rng.normal(0.0, 1.0, 3)
        w /= np.linalg.norm(w)  # 1 rad/s, world
        T_old = np.eye(4)
        T_old[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
        T_old[:3, 3] = rng.normal(0.0, 0.05, 3)

        def at(t: float, T_old: np.ndarray = T_old, v: np.ndarray = v, w: np.ndarray = w):
            T = np.eye(4)
            T[:3, :3] = Rotation.from_rotvec(w * t).as_matrix() @ T_old[:3, :3]
            T[:3, 3] = T_old[:3, 3] + v * t
            return T

        T_pred = predicted_pose(T_old, at(tau), tau, h, math.pi)
        T_true = at(tau + h)
        np.testing.assert_allclose(T_pred[:3, 3], T_true[:3, 3], atol=ATOL_PRED_M)
        R = T_pred[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=ATOL_PRED)
        assert np.linalg.det(R) > 0.0
        lag = Rotation.from_matrix(T_true[:3, :3] @ at(tau)[:3, :3].T).magnitude()
        error = Rotation.from_matrix(T_true[:3, :3] @ R.T).magnitude()
        assert error <= first_order_rad and error < 0.5 * lag  # far better than the lag
    T_old = np.eye(4)
    T_now = np.eye(4)
    T_now[:3, :3] = Rotation.from_rotvec([0.2, 0.0, 0.0]).as_matrix()  # the normal: 0.2 rad
    capped = predicted_pose(T_old, T_now, tau, 10 * tau, 0.5)  # would turn 2 rad more
    turned = math.acos(float(capped[:3, 2] @ T_now[:3, 2]))
    assert 0.0 < turned <= 0.5
    np.testing.assert_array_equal(predicted_pose(T_old, T_now, 0.0, h, 0.5), T_now)


def centred_wire() -> Wire:
    """A straight wire along ``N_RING`` through the ring's centre: the rim 3 mm clear."""
    line = P_RING + np.linspace(-0.08, 0.08, 5)[:, None] * N_RING
    return Wire(WireConfig(knots=tuple(tuple(k) for k in line.tolist())))


def test_without_a_touch_near_the_camera_holds_the_normal() -> None:
    """A ring threaded centrally (rim ``R − r − r_w`` = 3 mm from the wire, beyond
    ``engage_clearance``) is not scored: the axis stays on the normal, the side held; with
    the gate always open (``engage_clearance = inf``) the same scene is scored and tilted."""
    T_ring = ring_pose(P_RING, N_RING)
    up_perp = np.array([0.0, 0.0, 1.0]) - N_RING[2] * N_RING
    rcm = P_RING + 0.25 * up_perp / np.linalg.norm(up_perp)
    start = look_at_pose(P_RING + 0.045 * N_RING, P_RING)
    wire = centred_wire()
    for engage, tilted in ((VisibleConfig().engage_clearance, False), (math.inf, True)):
        context = PolicyContext(CAMERA, start, T_ring, rcm, DT, wire=wire, ring=RingConfig())
        cfg = VisibleConfig(engage_clearance=engage, either_eye=False)  # a tilt pays for both
        policy = VisiblePolicy(ControllerConfig(), cfg)
        policy.reset(context)
        T_cam = start
        for k in range(30):
            T_cam = policy.step(Observation(k * DT, T_ring, T_cam)).T_world_cam
        assert (policy.tilted_steps > 0) is tilted
        assert (policy.idle_scorings > 0) is not tilted
        assert policy.engaged is tilted
        axes = policy.view_axes(T_ring)  # the bench's record: target and applied axis
        assert axes is not None
        off = [math.acos(min(1.0, float(a @ N_RING))) for a in axes]
        assert (min(off) > ATOL_ANGLE) is tilted and (max(off) > ATOL_ANGLE) is tilted


def test_the_scorer_judges_the_ring_where_it_will_be() -> None:
    """The scorer is handed the ring poses predicted over the horizon, from the step itself
    to ``lookahead`` s past it (the observation is 50 ms late), from the accepted poses: a
    ring sliding along the wire at constant speed is scored where it will be over the
    horizon, not where it was seen."""
    latency_s, speed = 0.05, 0.02  # s, m/s
    wire = centred_wire()
    up_perp = np.array([0.0, 0.0, 1.0]) - N_RING[2] * N_RING
    rcm = P_RING + 0.25 * up_perp / np.linalg.norm(up_perp)
    start = look_at_pose(P_RING + 0.045 * N_RING, P_RING)

    def ring_at(t: float) -> np.ndarray:
        return ring_pose(P_RING + speed * t * N_RING, N_RING)

    context = PolicyContext(CAMERA, start, ring_at(0.0), rcm, DT, wire=wire, ring=RingConfig())
    cfg = VisibleConfig(score_period=0.1, horizon_poses=3)
    policy = VisiblePolicy(ControllerConfig(), cfg)
    policy.reset(context)
    scored: list[tuple[float, list[np.ndarray]]] = []
    policy._score = lambda Ts, t: scored.append((t, Ts))  # type: ignore[method-assign]
    T_cam = start
    for k in range(1, 31):
        t = k * DT
        obs = Observation(t, ring_at(t - latency_s), T_cam, t_ring=t - latency_s)
        T_cam = policy.step(obs).T_world_cam
    assert len(scored) >= 2
    t, poses = scored[-1]
    assert len(poses) == cfg.horizon_poses > 1
    ahead = cfg.lookahead * np.arange(cfg.horizon_poses) / (cfg.horizon_poses - 1)  # s
    for T, h in zip(poses, ahead, strict=True):
        np.testing.assert_allclose(T[:3, 3], ring_at(t + h)[:3, 3], atol=ATOL_PRED_M)


def test_the_scorer_judges_the_pose_where_the_gap_closes() -> None:
    """Of the poses over the horizon the scorer judges the one where the rim comes within
    the closing gap of the wire, not the farthest: a ring predicted to touch midway and to
    be threaded clear again at the horizon's end (constant velocity is no bounce, but the
    touch is where the gap closes) is scored; judged at the end alone it would not be."""
    wire = centred_wire()
    up_perp = np.array([0.0, 0.0, 1.0]) - N_RING[2] * N_RING
    rcm = P_RING + 0.25 * up_perp / np.linalg.norm(up_perp)
    start = look_at_pose(P_RING + 0.045 * N_RING, P_RING)
    clear = ring_pose(P_RING, N_RING)  # the rim R − r − r_w = 3 mm from the wire
    touching = ring_pose(P_RING + 2.8e-3 * E_CONTACT, N_RING)  # the rim 0.2 mm from it
    context = PolicyContext(CAMERA, start, clear, rcm, DT, wire=wire, ring=RingConfig())
    policy = VisiblePolicy(ControllerConfig(), VisibleConfig())
    policy.reset(context)
    policy._score([clear, clear, clear], 0.0)
    assert (policy.idle_scorings, policy.last_scores) == (1, {})
    policy._score([clear, touching, clear], 0.25)
    assert policy.idle_scorings == 1 and policy.last_scores


def test_a_view_counts_what_its_better_eye_sees(monkeypatch: pytest.MonkeyPatch) -> None:
    """The study counts a gap seen from either eye, so a candidate is worth its better eye's
    share, not the two eyes' mean: a tilted view that shows every gap point to one eye and
    none to the other beats the normal that shows 60 % to both (by the mean it would not)."""
    import endocam.control.policies.visible as visible

    wire = centred_wire()
    up_perp = np.array([0.0, 0.0, 1.0]) - N_RING[2] * N_RING
    rcm = P_RING + 0.25 * up_perp / np.linalg.norm(up_perp)
    start = look_at_pose(P_RING + 0.045 * N_RING, P_RING)
    touching = ring_pose(P_RING + 2.8e-3 * E_CONTACT, N_RING)  # the rim 0.2 mm from the wire

    def shares(eyes: np.ndarray, *args: object) -> np.ndarray:
        m = len(eyes) // 2  # candidates: this side's, the other side's view, the target
        scored = np.asarray(args[-1])  # (2m,): all left eyes, then all right eyes
        per_side = m - 2
        assert scored.shape == (2 * m,) and np.array_equal(scored[:m], scored[m:])
        assert scored[0] and scored[per_side]  # the tracker's own views are always scored
        left, right = np.ones(m), np.zeros(m)
        left[0] = right[0] = left[-1] = right[-1] = 0.6  # the normal (and the target on it)
        left[-2] = 0.0  # the other side's view: nothing
        return np.concatenate([left, right])

    monkeypatch.setattr(visible, "view_shares", shares)
    for either, tilted in ((True, True), (False, False)):
        context = PolicyContext(CAMERA, start, touching, rcm, DT, wire=wire, ring=RingConfig())
        policy = VisiblePolicy(ControllerConfig(), VisibleConfig(either_eye=either))
        policy.reset(context)
        policy._score([touching], 0.0)
        side = policy._want
        assert (policy._targets[side] != (0.0, 0.0, 0.0)) is tilted


def test_the_closing_fraction_is_where_the_clearance_crosses_the_gap() -> None:
    """The secant through the first pose within the gap and the one before it: a clearance
    falling linearly crosses the gap exactly there; closed at once, never closed, one pose."""
    gap = 0.5e-3  # m
    c = np.array([3.0e-3, 2.0e-3, 1.0e-3, 0.0, -1.0e-3])  # m: 1 mm closer per pose
    k, f = closing_fraction(c, gap)
    assert k == 3 and math.isclose(f, 0.5, abs_tol=ATOL_PRED)  # 1 mm → 0 mm: 0.5 mm midway
    assert closing_fraction(np.array([2.0e-3, 0.6e-3, 0.5e-3]), gap) == (2, 1.0)  # on it
    assert closing_fraction(np.array([0.4e-3, 2.0e-3]), gap) == (0, 1.0)  # closed already
    assert closing_fraction(np.array([3.0e-3, 2.0e-3, 2.5e-3]), gap) == (2, 1.0)  # never
    assert closing_fraction(np.array([3.0e-3]), gap) == (0, 1.0)


def test_the_pose_between_is_the_prediction_at_that_time() -> None:
    """Between two poses of one predicted path, the pose a fraction ``f`` along is the
    prediction ``f`` of the way: the centre exactly, the frame orthonormal, its ends the two."""
    tau = 0.1  # s
    T_a = ring_pose(P_RING, N_RING)
    T_b = ring_pose(P_RING + np.array([1e-3, -2e-3, 0.5e-3]), N_RING + 0.2 * E_CONTACT)
    f = 0.3
    T = pose_between(T_a, T_b, f)
    np.testing.assert_allclose(T[:3, 3], T_a[:3, 3] + f * (T_b[:3, 3] - T_a[:3, 3]),
                               atol=ATOL_PRED_M)  # fmt: skip
    np.testing.assert_allclose(T, predicted_pose(T_a, T_b, tau, (f - 1.0) * tau, 0.0),
                               atol=ATOL_PRED)  # fmt: skip
    np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=ATOL_PRED)
    np.testing.assert_allclose(pose_between(T_a, T_b, 0.0), T_a, atol=ATOL_PRED)
    np.testing.assert_allclose(pose_between(T_a, T_b, 1.0), T_b, atol=ATOL_PRED)


def test_the_prediction_stops_where_the_gap_closes(monkeypatch: pytest.MonkeyPatch) -> None:
    """A ring predicted to run into the wire is scored where its rim comes within the closing
    gap (the wire stops it), not at the first pose past it, inside the wire (at 4 mm)."""
    import endocam.control.policies.visible as visible

    wire = centred_wire()
    up_perp = np.array([0.0, 0.0, 1.0]) - N_RING[2] * N_RING
    rcm = P_RING + 0.25 * up_perp / np.linalg.norm(up_perp)
    start = look_at_pose(P_RING + 0.045 * N_RING, P_RING)
    clear = ring_pose(P_RING, N_RING)  # the rim 3 mm from the wire
    inside = ring_pose(P_RING + 4.0e-3 * E_CONTACT, N_RING)  # the rim 1 mm into it
    # the rim's clearance falls 1:1 with the offset, 3 mm → −1 mm: GAP_M at 2.5 mm
    real = visible.occluders
    scored: list[np.ndarray] = []

    def occluders(window: object, radius: float, T: np.ndarray, *rest: object) -> object:
        scored.append(T.copy())  # the ring pose the candidates are scored on
        return real(window, radius, T, *rest)

    monkeypatch.setattr(visible, "occluders", occluders)
    context = PolicyContext(CAMERA, start, clear, rcm, DT, wire=wire, ring=RingConfig())
    policy = VisiblePolicy(ControllerConfig(), VisibleConfig())
    policy.reset(context)
    policy._score([clear, inside], 0.0)
    assert len(scored) == 1
    np.testing.assert_allclose(scored[0][:3, 3], P_RING + 2.5e-3 * E_CONTACT, atol=ATOL_PRED_M)


def test_the_default_horizon_reaches_a_touch_three_quarters_of_a_second_ahead() -> None:
    """The default look-ahead (0.75 s over 4 poses, round 12) engages on a ring closing on
    the wire at 3 mm/s whose gap closes ~0.7 s ahead; the 0.5 s pose alone (round 11's
    default) is still 1.2 mm clear, beyond ``engage_clearance``, and is not scored."""
    speed = 3.0e-3  # m/s towards the wire: the rim's clearance falls 1:1 from 3 mm
    t_now = 0.1  # s, the step; the ring was accepted at 0 and at t_now
    wire = centred_wire()
    up_perp = np.array([0.0, 0.0, 1.0]) - N_RING[2] * N_RING
    rcm = P_RING + 0.25 * up_perp / np.linalg.norm(up_perp)
    start = look_at_pose(P_RING + 0.045 * N_RING, P_RING)

    def ring_at(t: float) -> np.ndarray:
        return ring_pose(P_RING + speed * t * E_CONTACT, N_RING)

    for cfg, engaged in (
        (VisibleConfig(), True),
        (VisibleConfig(lookahead=0.5, horizon_poses=1), False),
    ):
        context = PolicyContext(CAMERA, start, ring_at(0.0), rcm, DT, wire=wire, ring=RingConfig())
        policy = VisiblePolicy(ControllerConfig(), cfg)
        policy.reset(context)
        policy._track.extend([(0.0, ring_at(0.0)), (t_now, ring_at(t_now))])
        policy._score(policy._ahead_poses(ring_at(t_now), t_now, t_now), t_now)
        assert (policy.idle_scorings == 0) is engaged
        assert bool(policy.last_scores) is engaged


ATOL_POLYLINE_M = 1e-8  # m: round-off of squared distances of ~1e-6 m², far below 1 µm


def test_the_contact_searchs_distances_are_the_segments_closest_points() -> None:
    """``polyline_distances_sq`` (the contact search's (M, S) form) against Ericson's closest
    points of segments (``segment_distances``, a point as a zero-length segment)."""
    from endocam.control.occlusion import polyline_distances_sq, segment_distances

    rng = np.random.default_rng(27)
    for _ in range(20):
        poly = np.cumsum(rng.normal(0.0, 2e-3, (int(rng.integers(2, 12)), 3)), axis=0)
        q = rng.normal(0.0, 4e-3, (50, 3))
        got = np.sqrt(np.maximum(polyline_distances_sq(q, poly), 0.0))
        want = segment_distances(poly[:-1], poly[1:], q, q).min(axis=0)
        np.testing.assert_allclose(got, want, atol=ATOL_POLYLINE_M)

"""The validation clips carry the study's conditions: angle noise, pushes, views, moving camera."""

import math

import numpy as np
import pytest

from endocam.study import observer_clips
from endocam.study.observer_clips import (
    ANGLE_NOISE_DEG,
    CLIPS_PER_CELL,
    CROSS_TILT_DEG,
    LEAD_IN_S,
    PUSH_PAST,
    PUSH_PERIOD_S,
    SWAY_DEG,
    TEST_ARC_FRACTIONS,
    TEST_SEED,
    TUNING_ARC_FRACTIONS,
    TUNING_SEED,
    VIEW_KINDS,
    _rest_frame,
    camera_poses,
    draw_spec,
    from_above,
    gap_visible,
    iter_validation_specs,
    push_depths,
    ring_poses,
    true_touches,
    validation_specs,
)
from endocam.task.config import TaskConfig
from endocam.task.touches import clearances
from endocam.task.wire import Wire

TASK = TaskConfig()
ANGLE_TOL_DEG = 1e-6  # deg, floating-point slack on drawn angles
ORTHO_TOL = 1e-9  # unitless, |cos| of two directions that must be perpendicular
DEPTH_TOL = 2e-6  # m, the push depth bisection's tolerance (PUSH_SEARCH_TOL) with slack


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = abs(float(a @ b)) / (np.linalg.norm(a) * np.linalg.norm(b))
    return math.degrees(math.acos(min(1.0, c)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_angle_noise_between_ring_normal_and_wire_tangent(seed: int) -> None:
    # the study's noisy trajectories turn the ring 10-30 deg off the wire's tangent; the clips
    # draw that angle (about the push direction) plus a small cross tilt, seeded
    rng = np.random.default_rng(seed)
    wire = Wire(TASK.wire)
    for arc in TUNING_ARC_FRACTIONS + TEST_ARC_FRACTIONS:
        spec = draw_spec(rng, arc, "head-on")
        R, _, u = _rest_frame(TASK, spec)
        tangent = wire.tangent(np.array([arc * wire.length]))[0]
        lo, hi = ANGLE_NOISE_DEG
        angle = _angle_deg(R[:, 2], tangent)
        assert lo - ANGLE_TOL_DEG <= abs(spec.tilt_deg) <= hi + ANGLE_TOL_DEG
        assert lo - ANGLE_TOL_DEG <= angle <= math.hypot(hi, CROSS_TILT_DEG) + ANGLE_TOL_DEG
        assert abs(u @ tangent) < ORTHO_TOL  # pushed across the wire


def test_the_noise_is_seeded_and_the_sets_differ() -> None:
    # the tuning and held-out clips sit at other bends and draw their noise from other seeds
    # (validation_specs draws from these generators, in this order, redrawing hidden gaps)
    def draws(seed: int, arcs: tuple[float, ...]) -> list:
        rng = np.random.default_rng(seed)
        return [draw_spec(rng, a, v) for a in arcs for v in VIEW_KINDS]

    tuning = draws(TUNING_SEED, TUNING_ARC_FRACTIONS)
    held = draws(TEST_SEED, TEST_ARC_FRACTIONS)
    assert tuning == draws(TUNING_SEED, TUNING_ARC_FRACTIONS)
    assert not set(TUNING_ARC_FRACTIONS) & set(TEST_ARC_FRACTIONS)
    assert not {s.tilt_deg for s in tuning} & {s.tilt_deg for s in held}
    assert all(s.moving for s in tuning + held)


def test_the_gap_opens_across_the_line_of_sight_of_a_moving_camera() -> None:
    # the camera turns only about the push direction u: u stays in the image plane in every frame
    spec = draw_spec(np.random.default_rng(TUNING_SEED), TUNING_ARC_FRACTIONS[0], "oblique")
    _, _, u = _rest_frame(TASK, spec)
    t = np.linspace(0.0, LEAD_IN_S + 2 * PUSH_PERIOD_S, 50)
    cams = camera_poses(TASK, spec, t)
    assert np.all(np.abs(cams[:, :3, 2] @ u) < ORTHO_TOL)
    view = np.degrees(np.arccos(np.clip(cams[:, :3, 2] @ cams[0, :3, 2], -1.0, 1.0)))
    assert 0.0 < view.max() <= 2.0 * SWAY_DEG + ANGLE_TOL_DEG  # it moves, slowly


def test_each_push_goes_past_contact_both_ways() -> None:
    spec = draw_spec(np.random.default_rng(TEST_SEED), TEST_ARC_FRACTIONS[0], "head-on")
    d_plus, d_minus = push_depths(TASK, spec)
    _, centre, u = _rest_frame(TASK, spec)
    wire = Wire(TASK.wire)
    for d in (d_plus, -d_minus):
        T = ring_poses(TASK, spec, np.array([0.0]))[0]
        T[:3, 3] = centre + d * u
        c, _ = clearances(T[None], wire, TASK.ring)
        assert c[0] == pytest.approx(-PUSH_PAST, abs=DEPTH_TOL)
    events = true_touches(TASK, spec, LEAD_IN_S + 2 * PUSH_PERIOD_S)
    assert len(events) == 2 and events[0][0] > LEAD_IN_S


def test_a_view_with_the_gap_behind_the_wire_is_redrawn() -> None:
    # the first head-on draw at the first tuning bend looks through the ring with the wire's
    # near part over the place where the gap closes (a ray cast to the gap hits the wire); the
    # next draw shows it, and validation_specs keeps that one
    rng = np.random.default_rng(TUNING_SEED)
    hidden = from_above(TASK, draw_spec(rng, TUNING_ARC_FRACTIONS[0], "head-on"))
    shown = from_above(TASK, draw_spec(rng, TUNING_ARC_FRACTIONS[0], "head-on"))
    assert not gap_visible(TASK, hidden)
    assert gap_visible(TASK, shown)


def test_validation_specs_redraw_hidden_gaps_bend_by_bend_and_view_by_view(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # with every other draw's gap "hidden" (a stand-in for the ray casts), each kept spec is the
    # second of two draws from the set's generator, in bend, view, clip order; the iterator
    # draws the same specs one at a time
    draws = iter(range(10**6))
    monkeypatch.setattr(observer_clips, "gap_visible", lambda task, spec: next(draws) % 2 == 1)
    specs = validation_specs(False, TASK)
    rng = np.random.default_rng(TUNING_SEED)
    want = []
    for arc in TUNING_ARC_FRACTIONS:
        for view in VIEW_KINDS:
            for _ in range(CLIPS_PER_CELL):
                draw_spec(rng, arc, view)  # hidden, redrawn
                want.append(from_above(TASK, draw_spec(rng, arc, view)))
    assert specs == want
    assert list(iter_validation_specs(False, TASK)) == want
    assert validation_specs(True, TASK) != want  # the held-out set: other bends, other seed

"""An arm's start view (the fixed camera) frames the whole task, and the arm can take it.

Independent facts, from the pixels of every task point (wire polyline, post bases, PSM2's tip)
in both eyes of the pose the arm reaches: all inside the image with ``VIEW_MARGIN`` of each
half-size spare, and the image used up to that margin (the view is as near as it frames, not a
distant overview); the joints within their limits and FK giving the pose; the camera inside the
workspace, its optical axis through the port, at least the gap beyond it; a level horizon on
the PSM. For the default config and for randomised wires, on the PSM and the ECM. A port that
cannot frame its task is a one-line config error (exit code 2).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from endocam.camera import StereoCamera
from endocam.cli import main
from endocam.config import ExperimentConfig
from endocam.robot.actuator import ArmKind
from endocam.robot.camera_arm import CameraArm, natural_pose
from endocam.robot.carriers import make_actuator
from endocam.robot.start_view import ARM_START_GAP, START_ROLL_TOL_RAD
from endocam.task.config import DEFAULT_KNOTS
from endocam.task.layout import VIEW_MARGIN, FramingError, port_view

ARMS = (ArmKind.PSM, ArmKind.ECM)
LIMIT_SLACK = 1e-9  # rad (m): round-off at a joint limit
AXIS_TOL_M = 1e-9  # m: the optical axis passes this close to the port
LEVEL_TOL = 1e-9  # unitless: the PSM's image x axis has at most this world-z component
# rad: the ECM (4 DoF) levels its start view only as far as its ±88° roll allows (from the
# default port: fully); its image's up may lean this far from world up
ECM_ROLL_TOL_RAD = math.radians(10.0)
LEVEL_TOL_RAD = LEVEL_TOL  # rad: the same bound as an angle (small-angle: sin θ ≈ θ)
ZERO_ROLL_TOL_RAD = math.radians(3.0)  # rad: "upright at zero roll" allows this lean
LOOK_M = 0.1  # m: a distance the camera looks at, for the zero-roll image
UP_PROBE_M = 0.01  # m: a point this far above the looked-at point shows where the image's up is
# unitless: the ECM's reached roll may differ from the framed one by START_ROLL_TOL_RAD, which
# moves an image corner (half-diagonal 400 px at 640 × 480) by at most this share of 240 px
ROLL_FRACTION_TOL = START_ROLL_TOL_RAD * math.hypot(320.0, 240.0) / 240.0
FILL_TOL = 0.01  # unitless: the task uses the image up to the margin less this share
SHRINK = (0.6, 0.95)  # unitless: randomised wires are the default scaled about its centre so
JITTER_M = 0.005  # m: and every knot moved up to this far (the default port's reach: see docs)


def _config(knots: object = None) -> ExperimentConfig:
    data = ExperimentConfig().model_dump(mode="json")
    if knots is not None:
        data["task"]["wire"]["knots"] = np.asarray(knots).tolist()
    return ExperimentConfig.model_validate(data)


def _task_points(cfg: ExperimentConfig) -> np.ndarray:
    """Wire polyline, post bases (the ends at z = 0) and PSM2's tip, world, m."""
    from endocam.task.wire import Wire

    wire = Wire(cfg.task.wire)
    ends = wire.polyline()[[0, -1]] * np.array([1.0, 1.0, 0.0])
    return np.vstack([wire.polyline(), ends, cfg.task.instruments.psm2_tip])


def _arm(cfg: ExperimentConfig, kind: ArmKind) -> CameraArm:
    """The carrier an episode builds (each arm with its own camera mount), in its workspace."""
    p_rcm = np.array(cfg.task.scene.rcm_position)
    workspace = cfg.controller.workspace(p_rcm, cfg.task.wire.knots[0])
    T_world_rcm = cfg.task.scene.T_world_rcm
    arm = make_actuator(
        kind, cfg.episode.limits, cfg.episode.T_tip_cam, T_world_rcm, 0.01, workspace
    )
    assert isinstance(arm, CameraArm)
    return arm


def _image_up_lean(T_world_cam: np.ndarray, look: float, camera: StereoCamera) -> float:
    """Angle (rad, in [0, π]) between world up, as the camera draws it, and the image's up.

    Projects the point ``look`` ahead of the camera (on its optical axis) and a point
    ``UP_PROBE_M`` above it, in the mean of both eyes' pixels (the view from the midpoint
    between them, whose principal ray that is): in an upright image with a level horizon the
    second is straight above the first (smaller v, same u).
    """
    centre = T_world_cam[:3, 3] + look * T_world_cam[:3, 2]
    points = np.array([centre, centre + np.array([0.0, 0.0, UP_PROBE_M])])
    uv = 0.5 * (
        camera.project(T_world_cam, points, "left") + camera.project(T_world_cam, points, "right")
    )
    du, dv = uv[1] - uv[0]
    return abs(math.atan2(du, -dv))


def _check_start(cfg: ExperimentConfig, kind: ArmKind) -> None:
    p_rcm = np.array(cfg.task.scene.rcm_position)
    arm = _arm(cfg, kind)
    workspace = arm.workspace
    assert workspace is not None
    camera = cfg.camera.stereo()
    T_goal, look = arm.start_view(cfg.task, camera)
    T = arm.reset(T_goal, look)
    # reachable: joints in limits, FK gives the pose, inside the workspace
    assert (arm.q >= arm.model.lower - LIMIT_SLACK).all()
    assert (arm.q <= arm.model.upper + LIMIT_SLACK).all()
    np.testing.assert_allclose(arm.camera_pose(arm.q), T, atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], T_goal[:3, 3], atol=1e-9)
    assert workspace.margin(T[:3, 3].tolist()) > 0.0
    # a scope through its port: the optical axis passes through the RCM, the camera beyond it
    to_cam = T[:3, 3] - p_rcm
    assert np.linalg.norm(np.cross(to_cam, T[:3, 2])) <= AXIS_TOL_M
    assert to_cam @ T[:3, 2] >= ARM_START_GAP
    if kind is ArmKind.PSM:
        assert abs(T[2, 0]) <= LEVEL_TOL and T[2, 1] < 0.0  # level horizon, image y down
    # up in the world is up in the image (the ECM as level as its roll joint allows)
    assert _image_up_lean(T, look, camera) <= (
        ECM_ROLL_TOL_RAD if kind is ArmKind.ECM else LEVEL_TOL_RAD
    )
    # every task point in both eyes with the margin; the image used up to it
    k = camera.intrinsics
    tol = ROLL_FRACTION_TOL if kind is ArmKind.ECM else 0.0
    spare_u = (VIEW_MARGIN - tol) * 0.5 * k.width  # px
    spare_v = (VIEW_MARGIN - tol) * 0.5 * k.height  # px
    used = 0.0
    for eye in ("left", "right"):
        uv = camera.project(T, _task_points(cfg), eye)
        assert not np.isnan(uv).any()
        assert (uv[:, 0] >= spare_u).all() and (uv[:, 0] <= k.width - spare_u).all()
        assert (uv[:, 1] >= spare_v).all() and (uv[:, 1] <= k.height - spare_v).all()
        off = np.abs(uv - [k.cx, k.cy]) / [0.5 * k.width, 0.5 * k.height]
        used = max(used, float(off.max()))
    assert used >= 1.0 - VIEW_MARGIN - FILL_TOL


@pytest.mark.parametrize("kind", ARMS)
def test_image_is_upright_at_zero_roll(kind: ArmKind) -> None:
    # mid-range joints (yaw, pitch, roll 0) aim the shaft along the default RCM frame's -z,
    # towards the task: there the image is upright with a level horizon (config description)
    cfg = _config()
    arm = _arm(cfg, kind)
    q = natural_pose(arm.model)
    assert not q[~np.array(arm.model.prismatic)].any()
    T = arm.camera_pose(q)
    assert T[:3, 2] @ [0.0, 0.0, 1.0] < 0.0  # looking down into the task, not up
    assert _image_up_lean(T, LOOK_M, cfg.camera.stereo()) <= ZERO_ROLL_TOL_RAD


@pytest.mark.parametrize("kind", ARMS)
def test_default_start_view_frames_the_task(kind: ArmKind) -> None:
    _check_start(_config(), kind)


@pytest.mark.parametrize("kind", ARMS)
@settings(max_examples=3, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1))
def test_randomised_wire_start_view_frames_the_task(kind: ArmKind, seed: int) -> None:
    rng = np.random.default_rng(seed)
    knots = np.array(DEFAULT_KNOTS)
    centre = knots.mean(axis=0)
    knots = centre + rng.uniform(*SHRINK) * (knots - centre)
    _check_start(_config(knots + rng.uniform(-JITTER_M, JITTER_M, knots.shape)), kind)


@pytest.mark.parametrize(
    ("port", "problem"),
    [((0.0, 0.0, 0.045), "task centre is"), ((0.0, 0.0, 0.06), "behind the camera")],
)
def test_a_port_among_the_task_cannot_frame_it(port: tuple[float, ...], problem: str) -> None:
    cfg = _config()
    with pytest.raises(FramingError, match=problem):
        port_view(cfg.task, cfg.camera.stereo(), port, ARM_START_GAP)


def test_a_task_too_wide_for_the_port_says_how_much_it_needs() -> None:
    cfg = _config(np.array(DEFAULT_KNOTS) * [2.0, 2.0, 1.0])
    with pytest.raises(FramingError, match=r"needs \d+% of the image half-size, 90% allowed"):
        port_view(cfg.task, cfg.camera.stereo(), cfg.task.scene.rcm_position, ARM_START_GAP)


@pytest.mark.parametrize("gap", [0.0, -0.01, math.nan])
def test_bad_gap_is_refused(gap: float) -> None:
    cfg = _config()
    with pytest.raises(ValueError, match="gap"):
        port_view(cfg.task, cfg.camera.stereo(), cfg.task.scene.rcm_position, gap)


def test_cli_port_that_cannot_frame_is_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "near.toml"
    config.write_text("[task.scene]\nrcm_position = [0.04, 0.0, 0.06]\n")
    out = tmp_path / "run"
    args = ["run", "--policy", "fixed", "--trajectory", "ideal", "--no-video"]
    assert main([*args, "--out", str(out), "--config", str(config)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("endocam: error: config: port:")
    assert "Traceback" not in "".join(err)
    assert not out.exists()

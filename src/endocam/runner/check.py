"""The safety checker: every logged step of a finished run against the safety invariants.

:func:`check_run` reads a run's ``scene.json`` and ``episode.csv`` (as ``endocam run`` writes
them), first refuses a log that is not one endocam writes (:class:`MalformedLogError`, from
:mod:`endocam.runner.log_schema`: the carrier's columns, the row count of the duration at
the control period, time stamps every control period, unit quaternions, known states and
faults: a log that fails these cannot be checked, so it is never passed), then checks, step
by step:

``floor``
    the camera never below the tissue plane plus its minimum height
    (``ControllerConfig.min_camera_height``, world z);
``cone``
    the camera and its command inside the cone workspace (``workspace.cone.ConeWorkspace`` of
    ``scene.json``'s cone) in every autonomous state (:data:`AUTONOMOUS_STATES`), once the
    camera has entered it (an arm's start view may lie outside: the first approach);
``joint_position``, ``joint_velocity``, ``joint_acceleration``
    a camera arm's joints within the PSM's or ECM's limits (``robot.psm`` / ``robot.ecm`` joint
    ranges, ``robot.arm`` velocity and acceleration limits), by finite differences of the
    logged positions;
``linear_speed`` … ``angular_acceleration``, ``linear_jerk``
    the free camera within its ``MotionLimits`` (speed, acceleration and jerk norms; the
    rotation's rate and its change), by finite differences: no teleporting;
``finite``
    no NaN or infinite value in a commanded or measured pose or joint (``episode.csv`` writes a
    non-finite value as an empty cell);
``fk``
    the logged camera pose equal to FK of the logged joints where an arm carries it;
``wire_clearance``
    the camera and its command at least ``ControllerConfig.wire_clearance`` from the wire's
    surface in every autonomous state (the scope tip must not touch the structure it looks
    at; ``control.clearance``). Measured to ``scene.json``'s polyline of the wire (which can
    only overestimate the distance); the tolerance is the controller's own overestimate, half
    the spacing of the wire's search polyline (``Wire.search_spacing``, ≤ 0.125 mm), plus
    the log's round-off. No speed × dt term: the carriers keep the camera itself out of the
    zone at every control step, not only its command;
``lost_hold``
    a lost or invalid observation (an invalid ring pose injected by a fault, :mod:`endocam.faults`;
    an outlier only when the gate promises to refuse it, ``control.gate.outlier_detected``,
    with its weaker promise for a burst that begins after a gap, :func:`outlier_after_gap`)
    answered in the same control step by holding: state ``lost_tracking`` and the command of
    the step before. A frozen tracker (fault ``tracker_frozen``: the same pose, its capture
    stamp kept) counts as lost from the step at which the repeated pose is surely older than
    ``ControllerConfig.ring_max_age``: at least the time since the run of frozen steps began
    plus the sensing latency (the capture can only be earlier).

Finite differences of positions sampled every control step ``dt`` bound the mean of the
derivative over the differenced steps, so a limit that held at every instant holds for them
too. The tolerances are the CSV's round-off (:data:`POSITION_TOL_M`, :data:`ANGLE_TOL_RAD`)
propagated through the difference quotients: ``2 tol / dt`` for a speed, ``4 tol / dt²`` for
an acceleration, ``8 tol / dt³`` for a jerk.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from endocam.config import ExperimentConfig
from endocam.control.gate import outlier_detected
from endocam.control.types import TrackingState
from endocam.faults import OBSERVATION_INVALID_FAULTS, fault_names
from endocam.geometry import FloatArray, R_from_quat_wxyz, so3_log
from endocam.robot.actuator import ArmKind
from endocam.robot.arm import (
    ECM_MAX_ACCELERATION,
    ECM_MAX_VELOCITY,
    PSM_MAX_ACCELERATION,
    PSM_MAX_VELOCITY,
)
from endocam.robot.camera_arm import CameraArm, arm_model
from endocam.robot.carriers import arm_mount
from endocam.runner.episode import BLOCKED, UNREACHABLE
from endocam.runner.log_schema import (
    TIME_TOL_S,
    LogHeader,
    MalformedLogError,
    joint_column,
    quat_names,
    read_columns,
    xyz_names,
)
from endocam.task.wire import Wire
from endocam.workspace.region import Workspace

SCENE_JSON = "scene.json"
EPISODE_CSV = "episode.csv"
CHECK_JSON = "check.json"

POSITION_TOL_M = 1e-9  # m: round-off of a logged position (repr floats, products of poses)
ANGLE_TOL_RAD = 1e-9  # rad: round-off of a logged orientation (quaternion → matrix)
JOINT_TOL = 1e-9  # rad or m: round-off of a logged joint position
ARRIVED_TOL_M = 1e-9  # m: a held command repeats the last one to this round-off
AUTONOMOUS_STATES = (
    TrackingState.TRACKING.value,
    TrackingState.PLANNING.value,
    UNREACHABLE,
    BLOCKED,
)
"""States in which the controller drives the camera (the cone applies)."""
HOLD_STATES = (TrackingState.LOST_TRACKING.value, TrackingState.HOLDING.value)
"""States that answer a lost observation: the camera holds its last command."""
INVARIANTS = (
    "floor",
    "cone",
    "finite",
    "joint_position",
    "joint_velocity",
    "joint_acceleration",
    "linear_speed",
    "linear_acceleration",
    "linear_jerk",
    "angular_speed",
    "angular_acceleration",
    "fk",
    "wire_clearance",
    "lost_hold",
)
MAX_LISTED = 1000  # count: violations kept in check.json per run (all are counted)
GAP_FAULTS = frozenset({"ring_dropout", "ring_nan", "ring_inf", "tracker_frozen", "latency_spike"})
"""Faults that can leave the gate without a fresh ring pose (missing, invalid, stale, older)."""


@dataclass(frozen=True)
class Violation:
    """One step that breaks one invariant.

    Attributes
    ----------
    step : int
        Control step (row of ``episode.csv``, from 0).
    t : float
        Time, s.
    invariant : str
        One of :data:`INVARIANTS`.
    value : float
        The measured quantity, in the unit ``unit`` (SI).
    limit : float
        Its limit, same unit.
    unit : str
        ``m``, ``m/s``, ``rad/s²``... (SI).
    detail : str
        What was measured (e.g. the joint's name).
    """

    step: int
    t: float
    invariant: str
    value: float
    limit: float
    unit: str
    detail: str = ""

    def line(self) -> str:
        """One human line: step, time, invariant, value, limit."""
        what = f" ({self.detail})" if self.detail else ""
        return (
            f"step {self.step} t={self.t:.3f} s: {self.invariant}{what} "
            f"{self.value:.6g} {self.unit}, limit {self.limit:.6g} {self.unit}"
        )


@dataclass(frozen=True)
class CheckResult:
    """The outcome of checking one run.

    Attributes
    ----------
    run : str
        The run folder.
    steps : int
        Control steps checked.
    arm : str
        Carrier (``free``, ``psm``, ``ecm``).
    counts : dict
        Violations per invariant (every invariant listed, 0 when it held).
    violations : tuple of Violation
        The first :data:`MAX_LISTED` violations, by step.
    """

    run: str
    steps: int
    arm: str
    counts: dict[str, int]
    violations: tuple[Violation, ...]

    @property
    def total(self) -> int:
        """Number of violations of every invariant."""
        return sum(self.counts.values())

    @property
    def ok(self) -> bool:
        """Whether every invariant held at every step."""
        return self.total == 0

    def summary(self) -> str:
        """One line: the run, its steps, and the violations per broken invariant."""
        if self.ok:
            return f"{self.run}: OK, {self.steps} steps, {len(self.counts)} invariants hold"
        broken = ", ".join(f"{k} {v}" for k, v in self.counts.items() if v)
        return f"{self.run}: {self.total} violations in {self.steps} steps ({broken})"

    def to_dict(self) -> dict[str, Any]:
        """The ``check.json`` content (SI values)."""
        return {
            "run": self.run,
            "ok": self.ok,
            "steps": self.steps,
            "arm": self.arm,
            "violations_total": self.total,
            "counts": dict(self.counts),
            "violations": [_finite_dict(asdict(v)) for v in self.violations],
        }


def _finite_dict(d: dict[str, Any]) -> dict[str, Any]:
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


@dataclass(frozen=True)
class RunLog:
    """What the checker reads from a run folder: the config and the logged columns (SI).

    Attributes
    ----------
    config : ExperimentConfig
        From ``scene.json``.
    header : LogHeader
        ``scene.json``'s ``log`` section: carrier, duration, control period.
    workspace : Workspace
        The cone of ``scene.json`` and the config's floor.
    columns : dict of str to ndarray
        Every ``episode.csv`` column: floats (NaN for an empty cell) or strings.
    wire_points : (M, 3)
        ``scene.json``'s polyline of the wire's centre line, world, m.
    wire_radius : float
        The wire's tube radius, m.
    """

    config: ExperimentConfig
    header: LogHeader
    workspace: Workspace
    columns: dict[str, np.ndarray]
    wire_points: FloatArray
    wire_radius: float

    @property
    def n(self) -> int:
        """Number of logged steps."""
        return len(self.columns["t"])

    def xyz(self, prefix: str) -> FloatArray:
        """(N, 3) positions of ``<prefix>_x/y/z``, m."""
        return np.stack([self.columns[c] for c in xyz_names(prefix)], axis=1)

    def quat(self, prefix: str) -> FloatArray:
        """(N, 4) quaternions of ``<prefix>_qw/qx/qy/qz`` (w, x, y, z)."""
        return np.stack([self.columns[c] for c in quat_names(prefix)], axis=1)


def read_run(run_dir: Path) -> RunLog:
    """Read ``scene.json`` and ``episode.csv`` of a run folder, refusing a malformed log.

    The log must be what ``endocam run`` writes for ``scene.json``'s carrier, duration and
    control period (:mod:`endocam.runner.log_schema`: columns, rows, time stamps, unit
    quaternions, known states and faults).

    Raises
    ------
    MalformedLogError
        One line when the log is not one endocam writes.
    ValueError
        One line when a file is missing or unreadable.
    """
    run_dir = Path(run_dir)
    scene_path, csv_path = run_dir / SCENE_JSON, run_dir / EPISODE_CSV
    try:
        scene = json.loads(scene_path.read_text(encoding="utf-8"))
        if not isinstance(scene, dict):
            raise MalformedLogError(f"{scene_path} is not an endocam scene: not a JSON object")
        header = LogHeader.from_scene(scene, str(scene_path))
        config = ExperimentConfig.model_validate(scene["config"])
        workspace = config.controller.workspace(
            scene["cone"]["apex"], scene["cone"]["axis_towards"]
        )
        wire_points = np.asarray(scene["wire"]["points"], dtype=float).reshape(-1, 3)
        wire_radius = float(scene["wire"]["wire_radius"])
    except OSError as exc:
        raise ValueError(f"{run_dir}: cannot read {exc.filename}: {exc.strerror}") from None
    except json.JSONDecodeError as exc:
        raise MalformedLogError(f"{scene_path} is not JSON: {exc.msg}") from None
    except UnicodeDecodeError as exc:
        raise MalformedLogError(f"{scene_path} is not UTF-8 text: {exc.reason}") from None
    except MalformedLogError:
        raise
    except (KeyError, TypeError, ValueError) as exc:
        raise MalformedLogError(f"{scene_path} is not an endocam scene: {exc}") from None
    if not math.isclose(header.control_period * config.episode.control_rate, 1.0):
        raise MalformedLogError(
            f"{scene_path}: log control_period {header.control_period:g} s is not "
            f"1 / episode.control_rate ({config.episode.control_rate:g} Hz)"
        )
    try:
        columns = read_columns(csv_path, header)
    except OSError as exc:
        raise ValueError(f"{run_dir}: cannot read {exc.filename}: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise MalformedLogError(f"{csv_path} is not UTF-8 text: {exc.reason}") from None
    return RunLog(config, header, workspace, columns, wire_points, wire_radius)


def check_run(run_dir: Path) -> CheckResult:
    """Check every logged step of a run folder against the invariants (module docstring).

    Raises
    ------
    MalformedLogError
        One line when the log is not one endocam writes (:func:`read_run`).
    ValueError
        One line when the run cannot be read.
    """
    log = read_run(run_dir)
    found: list[Violation] = []
    for rule in (_floor, _cone, _wire_clearance, _finite, _limits, _fk, _lost_hold):
        found.extend(rule(log))
    found.sort(key=lambda v: (v.step, v.invariant))
    counts = dict.fromkeys(INVARIANTS, 0)
    for v in found:
        counts[v.invariant] += 1
    return CheckResult(
        str(run_dir), log.n, log.header.carrier.value, counts, tuple(found[:MAX_LISTED])
    )


def write_check(result: CheckResult, path: Path) -> None:
    """Write ``check.json``."""
    Path(path).write_text(json.dumps(result.to_dict(), indent=2) + "\n", encoding="utf-8")


# ------------------------------------------------------------------------------ invariants
def _violations(
    log: RunLog,
    bad: np.ndarray,
    invariant: str,
    value: np.ndarray,
    limit: float | np.ndarray,
    unit: str,
    detail: str = "",
    offset: int = 0,
) -> list[Violation]:
    """A :class:`Violation` per true entry of ``bad`` (row ``i`` is step ``i + offset``)."""
    t = log.columns["t"]
    lim = np.broadcast_to(np.asarray(limit, dtype=float), bad.shape)
    return [
        Violation(
            int(i + offset),
            float(t[i + offset]),
            invariant,
            float(value[i]),
            float(lim[i]),
            unit,
            detail,
        )
        for i in np.flatnonzero(bad)
    ]


def _floor(log: RunLog) -> list[Violation]:
    floor = log.workspace.floor
    z = log.columns["cam_z"]
    bad = z < floor - POSITION_TOL_M
    return _violations(log, bad, "floor", z, floor, "m", "camera height")


def _cone(log: RunLog) -> list[Violation]:
    state = log.columns["state"]
    auto = np.isin(state, AUTONOMOUS_STATES)
    out: list[Violation] = []
    for prefix, what in (("cam", "camera"), ("cmd", "command")):
        p = log.xyz(prefix)
        margin = np.array([log.workspace.cone.margin(row) for row in p.tolist()])
        inside = margin >= -POSITION_TOL_M
        entered = np.maximum.accumulate(inside) if prefix == "cam" else np.ones_like(inside)
        bad = auto & entered & ~inside & np.isfinite(margin)
        out += _violations(log, bad, "cone", -margin, 0.0, "m", f"{what} outside by")
    return out


def _wire_clearance(log: RunLog) -> list[Violation]:
    clearance = log.config.controller.wire_clearance
    spacing = Wire(log.config.task.wire).search_spacing
    limit = clearance - 0.5 * spacing - POSITION_TOL_M  # the controller's overestimate
    auto = np.isin(log.columns["state"], AUTONOMOUS_STATES)
    tree = cKDTree(log.wire_points)
    out: list[Violation] = []
    for prefix, what in (("cam", "camera"), ("cmd", "command")):
        p = log.xyz(prefix)
        finite = np.all(np.isfinite(p), axis=1)
        d = np.full(len(p), math.inf)
        d[finite] = tree.query(p[finite])[0] - log.wire_radius
        bad = auto & (d < limit)
        out += _violations(log, bad, "wire_clearance", d, clearance, "m", f"{what} to the wire")
    return out


def _finite(log: RunLog) -> list[Violation]:
    names = [c for c in log.columns if c.startswith(("cam_", "cmd_", "q_"))]
    out: list[Violation] = []
    for name in names:
        v = log.columns[name]
        out += _violations(log, ~np.isfinite(v), "finite", v, 0.0, "", name)
    return out


def _limits(log: RunLog) -> list[Violation]:
    dt = log.header.control_period
    kind = log.header.carrier
    if kind is ArmKind.FREE:
        return _cartesian_limits(log, dt)
    model = arm_model(kind)
    names = model.joint_names
    q = np.stack([log.columns[joint_column(n)] for n in names], axis=1)
    vmax = np.array(PSM_MAX_VELOCITY if kind is ArmKind.PSM else ECM_MAX_VELOCITY)
    amax = np.array(PSM_MAX_ACCELERATION if kind is ArmKind.PSM else ECM_MAX_ACCELERATION)
    qd = np.diff(q, axis=0) / dt
    qdd = np.diff(q, n=2, axis=0) / dt**2
    out: list[Violation] = []
    for j, name in enumerate(names):
        lo, hi = float(model.lower[j]), float(model.upper[j])
        below = q[:, j] < lo - JOINT_TOL
        above = q[:, j] > hi + JOINT_TOL
        out += _violations(log, below, "joint_position", q[:, j], lo, "", f"{name} below")
        out += _violations(log, above, "joint_position", q[:, j], hi, "", f"{name} above")
        speed = np.abs(qd[:, j])
        out += _violations(
            log,
            speed > vmax[j] + 2 * JOINT_TOL / dt,
            "joint_velocity",
            speed,
            vmax[j],
            "/s",
            name,
            offset=1,
        )
        acc = np.abs(qdd[:, j])
        out += _violations(
            log,
            acc > amax[j] + 4 * JOINT_TOL / dt**2,
            "joint_acceleration",
            acc,
            amax[j],
            "/s²",
            name,
            offset=1,
        )
    return out


def _angular_velocity(quat: FloatArray, dt: float) -> FloatArray:
    """(N−1, 3) mean angular velocity between logged orientations, body frame, rad/s."""
    R = R_from_quat_wxyz(quat)
    R_rel = np.einsum("nji,njk->nik", R[:-1], R[1:])  # R_k^T R_k+1
    return so3_log(R_rel) / dt


def _cartesian_limits(log: RunLog, dt: float) -> list[Violation]:
    lim = log.config.episode.limits
    p = log.xyz("cam")
    out: list[Violation] = []
    for order, name, bound, unit in (
        (1, "linear_speed", lim.max_linear_speed, "m/s"),
        (2, "linear_acceleration", lim.max_linear_acceleration, "m/s²"),
        (3, "linear_jerk", lim.max_linear_jerk, "m/s³"),
    ):
        d = np.linalg.norm(np.diff(p, n=order, axis=0), axis=1) / dt**order
        tol = 2**order * POSITION_TOL_M / dt**order
        out += _violations(log, d > bound + tol, name, d, bound, unit, offset=1)
    quat = log.quat("cam")
    if np.isfinite(quat).all() and len(quat) > 1:
        w = _angular_velocity(quat, dt)
        rate = np.linalg.norm(w, axis=1)
        tol = 2 * ANGLE_TOL_RAD / dt
        out += _violations(
            log,
            rate > lim.max_angular_speed + tol,
            "angular_speed",
            rate,
            lim.max_angular_speed,
            "rad/s",
            offset=1,
        )
        alpha = np.linalg.norm(np.diff(w, axis=0), axis=1) / dt
        tol = 4 * ANGLE_TOL_RAD / dt**2
        out += _violations(
            log,
            alpha > lim.max_angular_acceleration + tol,
            "angular_acceleration",
            alpha,
            lim.max_angular_acceleration,
            "rad/s²",
            offset=1,
        )
    return out


def _fk(log: RunLog) -> list[Violation]:
    kind = log.header.carrier
    if kind is ArmKind.FREE:
        return []
    cfg = log.config
    T_rcm, T_tip_cam = arm_mount(kind, cfg.episode.T_tip_cam, cfg.task.scene.T_world_rcm)
    arm = CameraArm(kind, T_rcm, T_tip_cam, log.header.control_period)
    names = arm.joint_names
    q = np.stack([log.columns[joint_column(n)] for n in names], axis=1)
    ok = np.isfinite(q).all(axis=1)
    p = log.xyz("cam")
    quat = log.quat("cam")
    ok &= np.isfinite(p).all(axis=1) & np.isfinite(quat).all(axis=1)
    idx = np.flatnonzero(ok)
    T_fk = arm.camera_poses(q[idx])
    gap = np.linalg.norm(T_fk[:, :3, 3] - p[idx], axis=1)
    R_log = R_from_quat_wxyz(quat[idx])
    ang = np.linalg.norm(so3_log(np.einsum("nji,njk->nik", T_fk[:, :3, :3], R_log)), axis=1)
    out: list[Violation] = []
    for values, tol, unit, what in (
        (gap, POSITION_TOL_M, "m", "position"),
        (ang, ANGLE_TOL_RAD, "rad", "orientation"),
    ):
        bad = values > tol
        out += [
            Violation(
                int(idx[i]),
                float(log.columns["t"][idx[i]]),
                "fk",
                float(values[i]),
                tol,
                unit,
                what,
            )
            for i in np.flatnonzero(bad)
        ]
    return out


def _lost_hold(log: RunLog) -> list[Violation]:
    names = [fault_names(f) for f in log.columns["fault"]]
    refused = OBSERVATION_INVALID_FAULTS  # an outlier the gate does not promise to see is not
    # the gate the run had: on stereo, its noise floors (ExperimentConfig.controller_on_source)
    spec, limits = log.config.faults.ring_outlier, log.config.controller_on_source.ring_limits
    refused = refused - {"ring_outlier"}
    invalid = np.array([bool(f & refused) for f in names])
    outlier = np.array(["ring_outlier" in f for f in names], dtype=bool)
    settle = math.ceil(limits.reacquire / log.header.control_period - TIME_TOL_S) + 1
    after_gap = outlier_after_gap(names, settle)
    for gap in (False, True):
        if outlier_detected(spec.distance, spec.angle, limits, after_gap=gap):
            invalid |= outlier & (after_gap == gap)
    frozen = np.array(["tracker_frozen" in f for f in names], dtype=bool)
    invalid |= _frozen_age(log.columns["t"], frozen, log.config.episode.sensing_latency) > (
        log.config.controller.ring_max_age + TIME_TOL_S
    )
    state = log.columns["state"]
    cmd = log.xyz("cmd")
    moved = np.zeros(log.n)
    moved[1:] = np.linalg.norm(np.diff(cmd, axis=0), axis=1)
    bad = invalid & (~np.isin(state, HOLD_STATES) | ~(moved <= ARRIVED_TOL_M))
    return _violations(log, bad, "lost_hold", moved, ARRIVED_TOL_M, "m", "command moved")


def outlier_after_gap(names: list[frozenset[str]], settle: int) -> np.ndarray:
    """(N,) bool: outlier steps the gate may meet without a sound reference (after a gap).

    ``names``: each step's faults (:func:`~endocam.faults.fault_names`); ``settle``: clean
    steps the gate needs to take the true ring back after it took a wrong one (the steps of
    ``ring_reacquire``, plus one). A burst (a run of steps with ``ring_outlier``) is after a
    gap when the step before it or any of its own steps carries a :data:`GAP_FAULTS` fault
    (its first pose the gate sees may follow a stretch without a fresh one:
    ``control.gate.outlier_detected``'s ``after_gap``), or when the burst before it was, and
    no run of ``settle`` clean steps lies between them (the gate may have taken that burst,
    which the weaker promise allows, and still judge against it). Any other burst jumps off
    the observed ring.
    """
    out = np.zeros(len(names), dtype=bool)
    ring = GAP_FAULTS | {"ring_outlier"}
    weak, clean, k = False, 0, 0
    while k < len(names):
        if "ring_outlier" not in names[k]:
            clean = 0 if names[k] & ring else clean + 1
            if clean >= settle:
                weak = False  # the gate has the true ring again
            k += 1
            continue
        stop = k
        while stop < len(names) and "ring_outlier" in names[stop]:
            stop += 1
        weak = weak or any(f & GAP_FAULTS for f in names[max(k - 1, 0) : stop])
        out[k:stop] = weak
        clean, k = 0, stop
    return out


def _frozen_age(t: FloatArray, frozen: np.ndarray, latency: float) -> FloatArray:
    """(N,) a lower bound of the sensed ring pose's age, s, at frozen steps (0 elsewhere).

    Through a run of frozen steps from step ``s`` the tracker repeats the pose it sent at
    ``s``, captured at the latest ``max(t_s - latency, 0)`` (earlier under a latency spike).
    """
    age = np.zeros(len(t))
    start = None
    for k in range(len(t)):
        if not frozen[k]:
            start = None
            continue
        if start is None:
            start = k
        age[k] = t[k] - max(t[start] - latency, 0.0)
    return age

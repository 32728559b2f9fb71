"""The episode log's format: ``episode.csv``'s columns per carrier and what makes a log one.

One definition serves both sides: the writer (``runner.outputs.episode_columns``) orders its
columns by :func:`episode_column_names` and refuses any other set, and the checker
(``runner.check``) refuses a log whose columns differ from it. ``scene.json``'s ``log``
section (:func:`log_section`, read back by :meth:`LogHeader.from_scene`) says what the log
must be: its carrier, the trajectory's duration and the control period.

:func:`validate_log` refuses, with :class:`MalformedLogError` (one line naming what is wrong), a
log that a broken controller or logger could have written: missing, extra or repeated
columns; a row count other than the one the duration and the control period give
(:func:`control_step_count`, the runner's own grid); time stamps off ``k · dt``; a quaternion
that is not of unit norm (:data:`QUAT_NORM_TOL`); a state or fault name that no endocam run
logs. What it passes is read as the checker's invariants expect it; violations of those
invariants are a separate outcome (``endocam check``: exit 1, a malformed log: exit 2).
"""

from __future__ import annotations

import csv
import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from endocam.faults import FAULT_NAMES, fault_names
from endocam.robot.actuator import ArmKind
from endocam.robot.camera_arm import arm_model
from endocam.runner.episode import LOG_STATES
from endocam.runner.step import control_step_count

LOG_FORMAT = 1
"""Version of ``scene.json``'s ``log`` section and ``episode.csv``'s columns."""
TEXT_COLUMNS = ("state", "fault", "reason")
"""Columns of strings; every other column holds numbers (an empty cell: not finite)."""
QUATERNION_PREFIXES = ("ring", "cam", "cmd")
"""Orientations logged as ``<prefix>_qw/qx/qy/qz`` (scalar first)."""
CSV_FLOAT_EPS = float(np.finfo(np.float64).eps)
"""Relative precision of a logged float: ``episode.csv`` prints ``repr``, which round-trips
a float64 exactly, so a cell holds the computed value to its last bit (2.2e-16)."""
QUAT_NORM_TOL = 16 * CSV_FLOAT_EPS
"""``|‖q‖ − 1|`` allowed for a logged quaternion (3.6e-15). The writer's quaternion is
normalised in float64 (scipy ``as_quat``: within a few eps of unit norm), the cells keep it
exactly, and the reader's ``‖q‖`` adds a few eps of its own (four squares summed, a square
root): 16 eps bounds the three; the smallest scaling a corrupt logger could apply, one part
in 10⁹ (a 9-digit print), lies far above it."""
TIME_TOL_S = 1e-9  # s: a time stamp's distance from k · dt (the runner logs k · dt exactly)


class MalformedLogError(ValueError):
    """A run's files are not a log that endocam writes (one line: the file and the problem)."""


def xyz_names(prefix: str) -> tuple[str, ...]:
    """A position's columns ``<prefix>_x/y/z`` (world, m)."""
    return tuple(f"{prefix}_{a}" for a in "xyz")


def quat_names(prefix: str) -> tuple[str, ...]:
    """An orientation's columns ``<prefix>_qw/qx/qy/qz`` (scalar first)."""
    return tuple(f"{prefix}_q{a}" for a in "wxyz")


def joint_names(carrier: ArmKind) -> tuple[str, ...]:
    """The joints a carrier logs: none for the free camera."""
    return () if carrier is ArmKind.FREE else arm_model(carrier).joint_names


def joint_column(joint: str) -> str:
    """A joint's column: ``q_<joint>`` (rad or m)."""
    return f"q_{joint}"


ESTIMATE_COLUMNS = (
    *xyz_names("est"),
    "est_nx",
    "est_ny",
    "est_nz",
    "est_ok",
    "est_age_s",
)
"""A stereo run's estimate columns: the estimated ring centre (world, m) and unit face normal
(world) delivered at the step, ``est_ok`` 1 where one was, ``est_age_s`` its age (the step's
time less its capture time, s); empty where none."""


def episode_column_names(carrier: ArmKind, estimates: bool = False) -> tuple[str, ...]:
    """``episode.csv``'s columns, in order, for a camera carried by ``carrier``.

    Poses are world, m, quaternions scalar first; ``q_<joint>`` rad or m (an arm's joints),
    ``goal_conceded_mm`` / ``_deg`` (an arm's distance from the commanded goal), the tracking
    errors in the units their names give; with ``estimates`` (``perception.source =
    "stereo"``), :data:`ESTIMATE_COLUMNS` before ``reason``.
    """
    arm: tuple[str, ...] = ()
    if carrier is not ArmKind.FREE:
        arm = (
            *(joint_column(name) for name in joint_names(carrier)),
            "goal_conceded_mm",
            "goal_conceded_deg",
        )
    return (
        "t",
        *xyz_names("ring"),
        *quat_names("ring"),
        *xyz_names("cam"),
        *quat_names("cam"),
        "contact",
        "clearance",
        "state",
        "fault",
        "d_f",
        *xyz_names("cmd"),
        *quat_names("cmd"),
        *xyz_names("psm1_tip"),
        *xyz_names("psm2_tip"),
        *arm,
        "image_error_px",
        "center_error_mm",
        "orientation_error_deg",
        *(ESTIMATE_COLUMNS if estimates else ()),
        "reason",
    )


def log_section(
    carrier: ArmKind, duration: float, control_period: float, estimates: bool = False
) -> dict[str, Any]:
    """``scene.json``'s ``log`` section: what the run's ``episode.csv`` must be (SI).

    ``"estimates": true`` only for a run with :data:`ESTIMATE_COLUMNS` (a truth run's section
    is as before them).
    """
    section: dict[str, Any] = {
        "format": LOG_FORMAT,
        "carrier": carrier.value,
        "duration": float(duration),
        "control_period": float(control_period),
    }
    if estimates:
        section["estimates"] = True
    return section


@dataclass(frozen=True)
class LogHeader:
    """``scene.json``'s ``log`` section, read back.

    Attributes
    ----------
    carrier : ArmKind
        What carried the camera (fixes the ``q_`` columns).
    duration : float
        The trajectory's duration, s.
    control_period : float
        Time between logged steps, s.
    estimates : bool
        The log has :data:`ESTIMATE_COLUMNS` (a stereo run).
    """

    carrier: ArmKind
    duration: float
    control_period: float
    estimates: bool = False

    @property
    def steps(self) -> int:
        """Rows ``episode.csv`` must have: the runner's control steps over the duration."""
        return control_step_count(self.duration, self.control_period)

    @classmethod
    def from_scene(cls, scene: Mapping[str, Any], where: str) -> LogHeader:
        """Read the ``log`` section of a parsed ``scene.json`` (``where``: its path).

        Raises
        ------
        MalformedLogError
            When the section is missing (a log written before :data:`LOG_FORMAT`), of another
            format, or holds an unknown carrier or a non-positive duration or period.
        """
        section = scene.get("log")
        if not isinstance(section, Mapping):
            version = scene.get("endocam_version", "unknown")
            raise MalformedLogError(
                f"{where} has no 'log' section (written by endocam {version}, before log "
                f"format {LOG_FORMAT}): run the episode again to check it"
            )
        if section.get("format") != LOG_FORMAT:
            raise MalformedLogError(
                f"{where}: log format {section.get('format')!r}, this endocam reads format "
                f"{LOG_FORMAT}"
            )
        carriers = [k.value for k in ArmKind]
        if section.get("carrier") not in carriers:
            raise MalformedLogError(
                f"{where}: log carrier {section.get('carrier')!r} is not one of "
                f"{', '.join(carriers)}"
            )
        values = {}
        for key in ("duration", "control_period"):
            value = section.get(key)
            if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
                raise MalformedLogError(
                    f"{where}: log {key} {value!r} is not a positive number (s)"
                )
            values[key] = float(value)
        estimates = section.get("estimates", False)
        if not isinstance(estimates, bool):
            raise MalformedLogError(f"{where}: log estimates {estimates!r} is not true or false")
        return cls(
            ArmKind(section["carrier"]), values["duration"], values["control_period"], estimates
        )


def validate_header(header: LogHeader, names: Sequence[str], where: str) -> None:
    """Refuse a CSV header other than the carrier's columns (missing, extra or repeated).

    Raises
    ------
    MalformedLogError
    """
    repeated = [n for n, count in Counter(names).items() if count > 1]
    if repeated:
        raise MalformedLogError(f"{where}: column {repeated[0]} appears more than once")
    expected = episode_column_names(header.carrier, header.estimates)
    missing = [n for n in expected if n not in names]
    extra = [n for n in names if n not in expected]
    carrier = header.carrier.value
    if missing:
        raise MalformedLogError(
            f"{where}: missing columns (carrier {carrier}): {', '.join(missing)}"
        )
    if extra:
        raise MalformedLogError(
            f"{where}: unexpected columns (carrier {carrier}): {', '.join(extra)}"
        )


def read_columns(path: Path, header: LogHeader) -> dict[str, np.ndarray]:
    """Read ``episode.csv`` as ``header`` says it must be, refusing anything else.

    Returns every column (:func:`episode_column_names` of ``header.carrier``), (N,): floats
    (NaN for an empty cell) or, for :data:`TEXT_COLUMNS`, strings (object arrays).

    Raises
    ------
    MalformedLogError
        One line: not CSV, a cell over ``csv.field_size_limit()`` (128 kB), other columns
        (:func:`validate_header`), rows of another length, text in a numeric column, or
        rows :func:`validate_log` refuses.
    OSError
        When the file cannot be read.
    """
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        try:
            rows = list(reader)
        except csv.Error as exc:
            raise MalformedLogError(f"{path} line {reader.line_num}: {exc}") from None
    if not rows:
        raise MalformedLogError(f"{path} is empty")
    names, body = rows[0], rows[1:]
    validate_header(header, names, str(path))
    for i, row in enumerate(body):
        if len(row) != len(names):
            raise MalformedLogError(
                f"{path} line {i + 2}: {len(row)} cells, the header {len(names)}"
            )
    columns: dict[str, np.ndarray] = {}
    for j, name in enumerate(names):
        cells = [r[j] for r in body]
        if name in TEXT_COLUMNS:
            columns[name] = np.array(cells, dtype=object)
            continue
        try:
            columns[name] = np.array([float(c) if c != "" else math.nan for c in cells])
        except ValueError:
            raise MalformedLogError(f"{path}: column {name} is not numeric") from None
    validate_log(header, columns, str(path))
    return columns


def validate_log(header: LogHeader, columns: Mapping[str, np.ndarray], where: str) -> None:
    """Refuse a log whose rows a broken controller or logger could have written.

    ``columns`` : every column of :func:`episode_column_names` (``header.carrier``), (N,)
    floats (NaN for an empty cell) or, for :data:`TEXT_COLUMNS`, strings. Checks, in order:
    the row count against :attr:`LogHeader.steps`, ``t[k] = k · control_period`` within
    :data:`TIME_TOL_S`, known states and fault names, and the unit norm of every finite
    quaternion within :data:`QUAT_NORM_TOL` (a non-finite one is the checker's ``finite``
    violation, not a malformed log).

    Raises
    ------
    MalformedLogError
        One line: the file, the first offending row (step ``k`` is row ``k + 2`` counting the
        header as row 1) and what is wrong.
    """
    n = len(columns["t"])
    if n != header.steps:
        raise MalformedLogError(
            f"{where}: {n} rows, but {header.duration:g} s at a {header.control_period:g} s "
            f"control period log {header.steps}"
        )
    t = columns["t"]
    off = np.abs(t - np.arange(n) * header.control_period)
    bad = np.flatnonzero(~(off <= TIME_TOL_S))
    if bad.size:
        k = int(bad[0])
        raise MalformedLogError(
            f"{where}: t = {float(t[k])!r} s at step {k}, expected {k * header.control_period!r} s "
            f"(steps every {header.control_period:g} s from 0; {bad.size} rows off)"
        )
    unknown = sorted(set(columns["state"].tolist()) - set(LOG_STATES))
    if unknown:
        raise MalformedLogError(
            f"{where}: unknown state {unknown[0]!r} (states: {', '.join(LOG_STATES)})"
        )
    faults = set().union(*(fault_names(f) for f in set(columns["fault"].tolist())))
    if faults - set(FAULT_NAMES):
        raise MalformedLogError(f"{where}: unknown fault {sorted(faults - set(FAULT_NAMES))[0]!r}")
    for prefix in QUATERNION_PREFIXES:
        q = np.stack([columns[name] for name in quat_names(prefix)], axis=1)
        norm = np.linalg.norm(q, axis=1)
        bad = np.flatnonzero(np.isfinite(norm) & ~(np.abs(norm - 1.0) <= QUAT_NORM_TOL))
        if bad.size:
            k = int(bad[0])
            raise MalformedLogError(
                f"{where}: {prefix}_q* at step {k} has norm {norm[k]:.15g}, not a unit "
                f"quaternion (tolerance {QUAT_NORM_TOL:.2g}; {bad.size} rows)"
            )

"""The one experiment config: task, camera, controller and episode, loadable from TOML or YAML.

Every value is SI (m, s, rad; image sizes in px) and documented field by field; see
``endocam config`` for the full default config with descriptions. Files may set any subset:
unset fields keep their defaults. Unknown keys are errors (a typo must not be silently ignored).
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from endocam.camera import DEFAULT_BASELINE, DEFAULT_FOVY, Intrinsics, StereoCamera
from endocam.control.config import ControllerConfig
from endocam.faults import FaultsConfig
from endocam.geometry import FloatArray, R_from_euler_xyz, make_pose
from endocam.perception.loop import PerceptionConfig
from endocam.robot.actuator import ArmKind
from endocam.robot.cartesian import MotionLimits
from endocam.task.config import TaskConfig

_FROZEN = ConfigDict(frozen=True, extra="forbid")
MAX_CONTROL_STEPS = 400_000  # count: duration × control rate (≈ 0.4 GB of logged poses)
MAX_CONFIG_BYTES = 1_000_000  # bytes: a config or sweep file (the full default config is ~10 kB)

# The pickup camera's optical centre on the PSM tool-tip z axis (the approach direction), m:
# the dVRK's PROGRASP tip frame sits at the jaw pivot (wrist-yaw axis); ≈ 10 mm of jaw plus
# ≈ 5 mm from the jaw tips to the optical centre (an assumed geometry, not a datasheet value).
DEFAULT_TIP_CAM_OFFSET = 0.015


class CameraConfig(BaseModel):
    """The stereo endoscope: image size, field of view and baseline."""

    model_config = _FROZEN

    width: int = Field(640, ge=16, le=4096, description="Image width per eye, px.")
    height: int = Field(480, ge=16, le=4096, description="Image height per eye, px.")
    fovy: float = Field(
        DEFAULT_FOVY, gt=0.0, lt=math.pi, description="Vertical field of view, rad (60°)."
    )
    baseline: float = Field(DEFAULT_BASELINE, ge=0.0, le=0.05, description="Stereo baseline, m.")

    def stereo(self) -> StereoCamera:
        """The :class:`StereoCamera` this config describes."""
        return StereoCamera(Intrinsics.from_fovy(self.width, self.height, self.fovy), self.baseline)


class EpisodeConfig(BaseModel):
    """Simulated time, sensing and actuation."""

    model_config = _FROZEN

    control_rate: float = Field(100.0, gt=0.0, le=2000.0, description="Control rate, Hz.")
    video_fps: float = Field(30.0, gt=0.0, le=120.0, description="Video frame rate, frames/s.")
    sensing_latency: float = Field(
        0.05, ge=0.0, le=2.0, description="Delay of the ring pose the controller sees, s."
    )
    limits: MotionLimits = Field(default_factory=MotionLimits, description="Camera motion limits.")
    arm: ArmKind = Field(
        ArmKind.PSM,
        description="What carries the camera: 'free' (Cartesian limits only), 'psm' or 'ecm' "
        "(through the dVRK arm's kinematics and joint limits). A policy may force an arm "
        "(orientation-ecm uses the ECM).",
    )
    tip_cam_position: tuple[float, float, float] = Field(
        (0.0, 0.0, DEFAULT_TIP_CAM_OFFSET),
        description="Camera optical centre in the PSM tool-tip frame, m (T_tip_cam): a pickup "
        "camera grasped by ProGrasp forceps, on the approach (tip z) axis 15 mm from the jaw "
        "pivot, i.e. ~5 mm beyond the jaw tips. Ignored by the ECM (its tip frame is the "
        "optical frame).",
    )
    tip_cam_euler_xyz: tuple[float, float, float] = Field(
        (0.0, 0.0, math.pi),
        description="Camera optical frame orientation in the PSM tool-tip frame, Tait-Bryan "
        "(α, β, γ), rad (T_tip_cam): optical axis (z) along the tool's approach direction "
        "(tip z), image x along the tip's −x, so the image is upright at the arm's mid-range "
        "pose under the default RCM frame.",
    )

    @property
    def T_tip_cam(self) -> FloatArray:
        """(4, 4) camera optical frame in the PSM tool-tip frame, m."""
        return make_pose(R_from_euler_xyz(self.tip_cam_euler_xyz), self.tip_cam_position)

    @model_validator(mode="after")
    def _rates(self) -> EpisodeConfig:
        if not all(math.isfinite(v) for v in (*self.tip_cam_position, *self.tip_cam_euler_xyz)):
            raise ValueError("tip_cam_position and tip_cam_euler_xyz must be finite")
        if self.video_fps > self.control_rate:
            raise ValueError("video_fps must not exceed control_rate")
        return self


class ExperimentConfig(BaseModel):
    """Everything an episode needs, with the paper-like defaults."""

    model_config = _FROZEN

    task: TaskConfig = Field(default_factory=TaskConfig, description="The wire-chaser world.")
    camera: CameraConfig = Field(default_factory=CameraConfig, description="The stereo camera.")
    controller: ControllerConfig = Field(
        default_factory=ControllerConfig, description="The moving policies' parameters."
    )
    episode: EpisodeConfig = Field(default_factory=EpisodeConfig, description="Time and motion.")
    faults: FaultsConfig = Field(
        default_factory=FaultsConfig,
        description="Injected sensor and actuator faults (all off by default).",
    )
    perception: PerceptionConfig = Field(
        default_factory=PerceptionConfig,
        description="Where the controller's ring pose comes from: 'truth' or the stereo "
        "estimator on the rendered images (docs/perception.md).",
    )

    @property
    def controller_on_source(self) -> ControllerConfig:
        """The controller's parameters as the ring pose's source needs them.

        ``truth``: ``controller`` as it is. ``stereo``: its ``ring_gate_floor_*`` replaced by
        ``perception.gate_floor_*`` (the floor is the sensor's, not the controller's); with
        ``perception.resample`` the tracker's own prediction off (the stereo source's track
        filter predicts across the delay and the carrier's lead, ``perception.loop.resampled``).
        """
        per, controller = self.perception, self.controller
        if not per.stereo:
            return controller
        update: dict[str, object] = {
            "ring_gate_floor_position": per.gate_floor_position,
            "ring_gate_floor_angle": per.gate_floor_angle,
        }
        if per.resample:
            update["tracker"] = controller.tracker.model_copy(update={"predict": False})
        return controller.model_copy(update=update)

    @model_validator(mode="after")
    def _bounded(self) -> ExperimentConfig:
        steps = self.task.trajectory.duration * self.episode.control_rate
        if steps > MAX_CONTROL_STEPS:
            raise ValueError(
                f"task.trajectory.duration × episode.control_rate = {steps:.3g} control steps, "
                f"more than {MAX_CONTROL_STEPS}"
            )
        if not self.episode.sensing_latency < self.controller.ring_max_age:
            raise ValueError(
                f"episode.sensing_latency ({self.episode.sensing_latency} s) must be less than "
                f"controller.ring_max_age ({self.controller.ring_max_age} s): every ring pose "
                "would be too old to act on"
            )
        per, ep = self.perception, self.episode
        if per.stereo:
            if per.frame_rate > ep.control_rate:
                raise ValueError(
                    f"perception.frame_rate ({per.frame_rate:g}/s) must not exceed "
                    f"episode.control_rate ({ep.control_rate:g}/s)"
                )
            if not ep.sensing_latency + per.processing_delay < self.controller.ring_max_age:
                raise ValueError(
                    f"episode.sensing_latency + perception.processing_delay "
                    f"({ep.sensing_latency + per.processing_delay:g} s) must be less than "
                    f"controller.ring_max_age ({self.controller.ring_max_age} s)"
                )
        return self


def _one_line(exc: ValidationError) -> str:
    """The first validation error as ``path.to.field: message``."""
    err = exc.errors()[0]
    where = ".".join(str(p) for p in err["loc"]) or "config"
    more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
    msg = str(err["msg"]).removeprefix("Value error, ")
    return f"{where}: {msg}{more}"


def config_from_mapping(data: Any, source: str = "config") -> ExperimentConfig:
    """Validate a mapping (as parsed from TOML/YAML) into an :class:`ExperimentConfig`.

    Raises
    ------
    ValueError
        One line naming the file, the field and the problem.
    """
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ValueError(f"{source}: the top level must be a table of sections")
    refuse_nan(data, source)
    try:
        return ExperimentConfig.model_validate(data)
    except ValidationError as exc:
        raise ValueError(f"{source}: {_one_line(exc)}") from None


def load_config(path: str | Path) -> ExperimentConfig:
    """Load an :class:`ExperimentConfig` from a ``.toml``, ``.yaml`` or ``.yml`` file.

    Raises
    ------
    ValueError
        One line if the file is missing, unreadable, malformed or invalid.
    """
    return config_from_mapping(read_mapping(path), str(path))


def load_faults(path: str | Path) -> FaultsConfig:
    """Load a :class:`FaultsConfig` from a TOML or YAML file (``--faults``).

    The file holds the ``faults`` section itself, or a config with only a ``faults`` section.

    Raises
    ------
    ValueError
        One line if the file is missing, unreadable, malformed or invalid.
    """
    data = read_mapping(path)
    if data is None:
        data = {}
    if isinstance(data, dict) and "faults" in data:
        others = sorted(set(data) - {"faults"})
        if others:
            raise ValueError(f"{path}: holds only the faults section, found also {others[0]}")
        data = data["faults"]
    if not isinstance(data, dict):
        raise ValueError(f"{path}: the top level must be the faults section")
    refuse_nan(data, f"{path}: faults")
    try:
        return FaultsConfig.model_validate(data)
    except ValidationError as exc:
        raise ValueError(f"{path}: faults.{_one_line(exc)}") from None


def refuse_nan(data: Any, source: str, where: str = "") -> None:
    """Raise ``ValueError`` naming the first NaN in parsed ``data`` (TOML ``nan``, YAML ``.nan``).

    A bound such as ``le=3600`` would reject a NaN with a misleading message (NaN compares
    false), and a field without a bound would accept it; no config value may be NaN.
    """
    if isinstance(data, float) and math.isnan(data):
        raise ValueError(f"{source}: {where or 'value'}: not a number (nan)")
    if isinstance(data, dict):
        items: Any = data.items()
    elif isinstance(data, list | tuple):
        items = enumerate(data)
    else:
        return
    for key, value in items:
        refuse_nan(value, source, f"{where}.{key}" if where else str(key))


def read_text(path: str | Path, what: str = "config") -> str:
    """The text of a UTF-8 file of at most :data:`MAX_CONFIG_BYTES`, a byte-order mark dropped.

    Raises
    ------
    ValueError
        One line naming the file if it is missing, unreadable, too large or not UTF-8.
    """
    p = Path(path)
    try:
        with p.open("rb") as fh:
            data = fh.read(MAX_CONFIG_BYTES + 1)
    except OSError as exc:
        raise ValueError(f"cannot read {what} {p}: {exc.strerror or exc}") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise ValueError(f"{what} {p} is larger than MAX_CONFIG_BYTES = {MAX_CONFIG_BYTES} bytes")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(
            f"{what} {p} is not UTF-8 text (byte {exc.start}: 0x{data[exc.start]:02x}); "
            "save it as UTF-8"
        ) from None


def read_mapping(path: str | Path) -> Any:
    """The parsed content of a ``.toml``, ``.yaml`` or ``.yml`` file (not yet validated).

    UTF-8 with or without a byte-order mark (a file of only the mark is an empty config).

    Raises
    ------
    ValueError
        One line if the file is missing, unreadable, not UTF-8, malformed or of another format.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in (".toml", ".yaml", ".yml"):
        raise ValueError(f"config {p}: unknown format {suffix!r}; use .toml, .yaml or .yml")
    text = read_text(p)
    try:
        if suffix == ".toml":
            data: Any = tomllib.loads(text)
        else:
            data = yaml.safe_load(text)
    except (tomllib.TOMLDecodeError, yaml.YAMLError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ValueError(f"config {p} is malformed: {first}") from None
    return data

"""The study manifest: which videos exist, their ground truth and the presentation orders.

``manifest.json`` sits at the root of a study folder and is the contract between
``endocam study make`` (which writes it), ``endocam study serve`` and ``endocam study analyze``::

    {"endocam_version": "0.1.0", "created": "2024-05-01T12:00:00+00:00",
     "conditions": ["fixed", "centering", "endocam"],
     "videos": [{"id": "v01", "condition": "fixed", "trajectory": "t3-71-high",
                 "difficulty": 3, "true_touches": 7, "file": "videos/v01.mp4"}, ...],
     "orders": [["fixed", "centering", "endocam"], ...],
     "attention": {"question": "...", "answer": 4},
     "touch_definition": "A touch is ..."}

``conditions`` are two or more distinct names, each the camera policy that filmed its videos
(``endocam.registry.POLICIES``; ``"orientation"``, in studies made before round 9, is the endocam
tracker); ``orders`` are the presentation orders (``study make`` writes a Williams design,
:mod:`endocam.study.counterbalance`). ``difficulty`` runs from 1 to 3 (3 = most difficult, the
paper's 71-point trajectory). ``file`` is relative to the study folder.

Optional fields configure the online study (all have defaults, so older manifests still load):
``touch_definition`` (shown on the practice page and with every video), ``consent_file`` (plain
text, paragraphs separated by blank lines; default: the catalogue's text), ``messages_file`` (a
message catalogue replacing :file:`study/messages/en.json`, e.g. another language),
``demographics`` (ask years of surgical training and prior skill assessment), ``practice``
(``{"file": ..., "true_touches": ...}``: a practice video with feedback before the first set),
``shuffle_within_set`` (each participant sees a set's videos in a random, stored order; default
true), ``must_watch`` (a video must be watched once to its end, without skipping ahead, before its
answer is accepted) and
``recruitment`` (URL parameters naming the participant, completion code and redirect URL).
``touch_definition`` defaults to :data:`DEFAULT_TOUCH_DEFINITION`, the one ``true_touches``
counts.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from datetime import datetime
from pathlib import Path, PurePosixPath
from typing import Annotated, Any, Self

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

MANIFEST_NAME = "manifest.json"
MAX_TOUCHES = 99  # largest count a participant may report (touches)
ID_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"  # ids appear in URLs and CSV files
DEFAULT_TOUCH_DEFINITION = (
    "Count the touches between the ring and the wire. A touch begins when the ring comes into "
    "contact with the wire after a gap between them, and ends when a gap opens again: count each "
    "touch once, however long it lasts. Every video starts and ends with the ring clear of the "
    "wire."
)  # what the simulator counts (endocam.task.touches: one event per interval of contact)


CONDITION_PATTERN = r"^[a-z][a-z0-9_-]{0,31}$"  # condition names appear in file names and keys
Condition = Annotated[str, Field(pattern=CONDITION_PATTERN)]
"""A study condition: the name of the camera policy that filmed its videos
(``endocam.registry.POLICIES``); ``orientation`` in studies made before round 9 (the endocam
tracker, :data:`LEGACY_CONDITION_POLICY`)."""

# The paper's conditions I-III as endocam films them: the fixed and centering cameras and the
# endocam tracker (the orientation camera). ``study make``'s default.
DEFAULT_CONDITIONS = ("fixed", "centering", "endocam")
# Condition names of studies made before conditions were policy names, and their policy.
LEGACY_CONDITION_POLICY = {"orientation": "endocam"}
MIN_CONDITIONS = 2  # a study compares at least two conditions


def condition_policies(design: Mapping[str, Any], conditions: Sequence[str]) -> dict[str, str]:
    """The registry policy that filmed each condition's videos, from a study's ``design.json``.

    Its ``conditions`` map (round 9 on: each condition named by its policy); a folder made
    before it has none, and its names are mapped by :data:`LEGACY_CONDITION_POLICY`.
    """
    recorded = design.get("conditions")
    if isinstance(recorded, Mapping):
        return {c: str(recorded.get(c, c)) for c in conditions}
    return {c: LEGACY_CONDITION_POLICY.get(c, c) for c in conditions}


URL_PARAM_PATTERN = r"^[A-Za-z][A-Za-z0-9_]{0,31}$"  # recruitment URL parameter names


class ManifestError(ValueError):
    """A manifest that cannot be used; the message is one line."""


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class Video(_Frozen):
    """One study video and its ground truth.

    Attributes
    ----------
    id : str
        Unique video id (URL-safe).
    condition : Condition
        Camera condition the video was recorded with.
    trajectory : str
        Name of the ring trajectory; the same trajectory appears once per condition.
    difficulty : int
        1..3, 3 = most difficult.
    true_touches : int
        Ground-truth number of ring-wire touches (from the simulator's touch events).
    contact_fraction : float or None
        Share of the video's duration the ring is in contact with the wire (0..1).
    file : str
        Video path relative to the study folder (POSIX separators, no ``..``).
    """

    id: Annotated[str, Field(pattern=ID_PATTERN)]
    condition: Condition
    trajectory: Annotated[str, Field(min_length=1, max_length=128)]
    difficulty: Annotated[int, Field(ge=1, le=3)]
    true_touches: Annotated[int, Field(ge=0)]
    contact_fraction: Annotated[float | None, Field(ge=0.0, le=1.0)] = None
    file: Annotated[str, Field(min_length=1)]

    @field_validator("file")
    @classmethod
    def _relative_inside(cls, value: str) -> str:
        return _relative_path(value)


def _relative_path(value: str) -> str:
    """``value`` if it is a relative POSIX path inside the study folder, else ValueError."""
    path = PurePosixPath(value)
    if not value or path.is_absolute() or ".." in path.parts or "\\" in value:
        raise ValueError(f"must be a relative POSIX path inside the study folder, got {value!r}")
    return value


class PracticeVideo(_Frozen):
    """The practice video shown before the first set, with its true count for the feedback.

    Attributes
    ----------
    file : str
        Video path relative to the study folder (may be one of the study's own videos).
    true_touches : int
        Ground-truth number of touches, shown after the participant's answer.
    """

    file: Annotated[str, Field(min_length=1)]
    true_touches: Annotated[int, Field(ge=0, le=MAX_TOUCHES)]

    @field_validator("file")
    @classmethod
    def _relative_inside(cls, value: str) -> str:
        return _relative_path(value)


class Recruitment(_Frozen):
    """How a recruitment platform (e.g. Prolific) hands participants over and takes them back.

    Attributes
    ----------
    id_param : str
        URL parameter carrying the participant id (``/?PROLIFIC_PID=...``).
    extra_params : tuple of str
        Further URL parameters stored with the session (e.g. the platform's study and session).
    completion_code : str or None
        Code shown on the last page, to be entered on the platform.
    completion_url : str or None
        Link on the last page back to the platform; ``{code}`` is replaced by the code.
    """

    id_param: Annotated[str, Field(pattern=URL_PARAM_PATTERN)] = "PROLIFIC_PID"
    extra_params: tuple[Annotated[str, Field(pattern=URL_PARAM_PATTERN)], ...] = (
        "STUDY_ID",
        "SESSION_ID",
    )
    completion_code: Annotated[str | None, Field(pattern=ID_PATTERN)] = None
    completion_url: Annotated[str | None, Field(pattern=r"^https?://\S+$")] = None


class AttentionQuestion(_Frozen):
    """The attention question asked in the middle of the study; the answer is an integer."""

    question: Annotated[str, Field(min_length=1)]
    answer: Annotated[int, Field(ge=0, le=MAX_TOUCHES)]


class Manifest(_Frozen):
    """Validated study manifest (see the module docstring for the JSON form)."""

    endocam_version: str
    created: datetime
    conditions: tuple[Condition, ...]
    videos: tuple[Video, ...]
    orders: tuple[tuple[Condition, ...], ...]
    attention: AttentionQuestion
    touch_definition: Annotated[str, Field(min_length=1)] = DEFAULT_TOUCH_DEFINITION
    consent_file: str | None = None
    messages_file: str | None = None
    demographics: bool = False
    practice: PracticeVideo | None = None
    shuffle_within_set: bool = True
    must_watch: bool = False
    recruitment: Recruitment = Recruitment()

    @field_validator("consent_file", "messages_file")
    @classmethod
    def _relative_inside(cls, value: str | None) -> str | None:
        return None if value is None else _relative_path(value)

    @model_validator(mode="after")
    def _consistent(self) -> Self:
        if len(self.conditions) < MIN_CONDITIONS or len(set(self.conditions)) != len(
            self.conditions
        ):
            raise ValueError(
                f"conditions must list at least {MIN_CONDITIONS} distinct conditions, "
                f"got {list(self.conditions)}"
            )
        strangers = sorted({v.condition for v in self.videos} - set(self.conditions))
        if strangers:
            raise ValueError(f"videos of conditions not in conditions: {strangers}")
        ids = [v.id for v in self.videos]
        duplicates = sorted({i for i in ids if ids.count(i) > 1})
        if duplicates:
            raise ValueError(f"video ids must be unique, repeated: {duplicates}")
        trajectories = sorted({v.trajectory for v in self.videos})
        if not trajectories:
            raise ValueError("videos must not be empty")
        for condition in self.conditions:
            seen = sorted(v.trajectory for v in self.videos if v.condition == condition)
            if seen != trajectories:
                raise ValueError(
                    f"condition {condition!r} must have exactly one video per trajectory "
                    f"{trajectories}, has {seen}"
                )
        levels: dict[str, set[int]] = {}
        for v in self.videos:
            levels.setdefault(v.trajectory, set()).add(v.difficulty)
        for name, found in levels.items():
            if len(found) != 1:
                raise ValueError(f"trajectory {name!r} has differing difficulties {sorted(found)}")
        difficulty = [next(iter(found)) for found in levels.values()]
        if len(set(difficulty)) != len(difficulty):
            raise ValueError(f"each trajectory needs its own difficulty, got {sorted(difficulty)}")
        if not self.orders:
            raise ValueError("orders must not be empty")
        for order in self.orders:
            if sorted(order) != sorted(self.conditions):
                raise ValueError(f"order {list(order)} is not a permutation of conditions")
        if len(set(self.orders)) != len(self.orders):
            raise ValueError("orders must be distinct")
        return self

    def video(self, video_id: str) -> Video:
        """Return the video with id ``video_id``; KeyError if the manifest has none."""
        for v in self.videos:
            if v.id == video_id:
                return v
        raise KeyError(video_id)

    def videos_of(self, condition: str) -> tuple[Video, ...]:
        """Videos of one condition, in manifest order (the order they are shown within a set)."""
        return tuple(v for v in self.videos if v.condition == condition)

    def most_difficult(self, condition: str) -> Video:
        """The video of ``condition`` on the most difficult trajectory (the paper's analysis)."""
        return max(self.videos_of(condition), key=lambda v: v.difficulty)


def _one_line(exc: ValidationError, source: str) -> str:
    first = exc.errors()[0]
    where = ".".join(str(p) for p in first["loc"]) or "manifest"
    more = f" (+{exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
    return f"{source}: {where}: {first['msg']}{more}"


def parse_manifest(text: str, source: str = MANIFEST_NAME) -> Manifest:
    """Parse and validate manifest JSON text.

    Parameters
    ----------
    text : str
        The JSON document.
    source : str
        Name used in error messages.

    Returns
    -------
    Manifest
        The validated manifest.

    Raises
    ------
    ManifestError
        One-line message naming the offending field.
    """
    try:
        return Manifest.model_validate_json(text)
    except ValidationError as exc:
        raise ManifestError(_one_line(exc, source)) from None


def load_manifest(path: str | Path, *, check_files: bool | None = None) -> Manifest:
    """Load a manifest from a study folder or a ``manifest.json`` file.

    Parameters
    ----------
    path : str or Path
        A study folder (containing ``manifest.json``) or the manifest file itself.
    check_files : bool, optional
        Require every video file to exist. Defaults to True when ``path`` is a folder, False when
        it is a file (the analysis needs only the ground truth, not the videos).

    Returns
    -------
    Manifest
        The validated manifest.

    Raises
    ------
    ManifestError
        Missing or unreadable manifest, invalid content or missing video files (one line).
    """
    path = Path(path)
    is_dir = path.is_dir()
    file = path / MANIFEST_NAME if is_dir else path
    try:
        text = file.read_text(encoding="utf-8")
    except OSError as exc:
        raise ManifestError(f"cannot read manifest {file}: {exc.strerror or exc}") from None
    manifest = parse_manifest(text, source=str(file))
    if check_files if check_files is not None else is_dir:
        root = file.parent
        needed = [v.file for v in manifest.videos]
        needed += [manifest.practice.file] if manifest.practice else []
        needed += [f for f in (manifest.consent_file, manifest.messages_file) if f]
        missing = [f for f in needed if not (root / f).is_file()]
        if missing:
            raise ManifestError(f"{file}: video files missing in {root}: {missing}")
    return manifest


def manifest_json(manifest: Manifest) -> str:
    """Serialise a manifest to the JSON text that :func:`parse_manifest` reads back."""
    return json.dumps(manifest.model_dump(mode="json"), indent=2) + "\n"

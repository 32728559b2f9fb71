"""The study web app's JSON shapes: request bodies (validated at the boundary) and responses."""

from typing import Annotated, Any, Literal

from fastapi.exceptions import RequestValidationError
from pydantic import BaseModel, ConfigDict, Field, StrictInt, TypeAdapter

from endocam.study.flow import Step
from endocam.study.manifest import ID_PATTERN, MAX_TOUCHES

MAX_TRAINING_YEARS = 60  # years, largest years-of-training answer
MAX_MEDIA_TIME_S = 24 * 3600.0  # s, largest media time / watched seconds an event may report
MAX_PLAYBACK_RATE = 16.0  # fastest playback rate an event may report (browsers allow ≤ 16)

Touches = Annotated[StrictInt, Field(ge=0, le=MAX_TOUCHES)]
ParticipantId = Annotated[str, Field(pattern=ID_PATTERN)]
form_id: TypeAdapter[str] = TypeAdapter(ParticipantId)
Seconds = Annotated[float, Field(ge=0.0, le=MAX_MEDIA_TIME_S, allow_inf_nan=False)]


class SessionIn(BaseModel):
    """Body of ``POST /api/session``; without an id the server generates one."""

    model_config = ConfigDict(extra="forbid")
    consent: Literal[True]
    participant_id: ParticipantId | None = None
    recruitment: dict[str, ParticipantId] | None = None


class AnswerIn(BaseModel):
    """Body of ``POST /api/answer``; ``participant_id``, if sent, must be the caller's own."""

    model_config = ConfigDict(extra="forbid")
    video_id: Annotated[str, Field(min_length=1, max_length=128)]
    reported_touches: Touches
    participant_id: str | None = None


class CountIn(BaseModel):
    """Body of ``POST /api/practice``."""

    model_config = ConfigDict(extra="forbid")
    reported_touches: Touches


class AttentionIn(BaseModel):
    """Body of ``POST /api/attention``."""

    model_config = ConfigDict(extra="forbid")
    answer: Touches


class DemographicsIn(BaseModel):
    """Body of ``POST /api/demographics``; both answers optional."""

    model_config = ConfigDict(extra="forbid")
    training_years: Annotated[StrictInt, Field(ge=0, le=MAX_TRAINING_YEARS)] | None = None
    prior_assessment: Literal["yes", "no", "unsure"] | None = None


class EventIn(BaseModel):
    """Body of ``POST /api/event``: one player event (times in s of media time)."""

    model_config = ConfigDict(extra="forbid")
    video_id: Annotated[str, Field(min_length=1, max_length=128)]
    kind: Literal["play", "pause", "seeked", "ratechange", "ended", "progress"]
    media_time_s: Seconds | None = None
    playback_rate: Annotated[float, Field(gt=0.0, le=MAX_PLAYBACK_RATE)] | None = None
    watched_s: Seconds | None = None


class RefusedError(Exception):
    """A request the study refuses; ``message`` for the API, ``key`` for the page's text."""

    def __init__(self, status: int, message: str, key: str = "error_step") -> None:
        super().__init__(message)
        self.status = status
        self.message = message
        self.key = key


def step_json(step: Step) -> dict[str, Any]:
    """The JSON form of a participant's next step (``GET /api/next`` and every answer)."""
    return {
        "kind": step.kind.value,
        "video_id": step.video_id,
        "video_url": f"/videos/{step.video_id}" if step.video_id else None,
        "set_number": step.set_number,
        "position_in_set": step.position_in_set,
        "videos_in_set": step.videos_in_set,
        "n_sets": step.n_sets,
        "n_answered": step.n_answered,
        "n_videos": step.n_videos,
    }


def validation_error_body(exc: RequestValidationError) -> dict[str, Any]:
    """422 body naming each failed field and rule, never the submitted input."""
    return {
        "detail": [
            {"loc": list(e.get("loc", ())), "msg": e.get("msg", ""), "type": e.get("type", "")}
            for e in exc.errors()
        ]
    }

"""The study's stored records: a session, its status, the summary of its player events, the errors.

:class:`Participant` is one stored session, :class:`Status` where it stands,
:class:`VideoInteraction` what it did with one video; :class:`ConflictError` and
:class:`WithdrawnError` are the refusals of the store.

Split from :mod:`endocam.study.db` (the SQLite store), which builds these from its rows.
"""

from __future__ import annotations

import json
import sqlite3
from dataclasses import dataclass
from datetime import datetime, timedelta
from enum import StrEnum

from endocam.study.flow import VideoSequence

ABANDON_AFTER_S = (
    2 * 3600.0
)  # s without any activity after which an unfinished session is abandoned


class ConflictError(Exception):
    """The request conflicts with what is already stored (answer given twice, step done)."""


class WithdrawnError(ConflictError):
    """The participant id was withdrawn: it can never start a session again."""


class Status(StrEnum):
    """Where a session stands (see the module docstring)."""

    ACTIVE = "active"
    COMPLETED = "completed"
    ABANDONED = "abandoned"
    WITHDRAWN = "withdrawn"


@dataclass(frozen=True)
class Participant:
    """A stored session (never carries the session token).

    Attributes
    ----------
    pk : int
        Internal row id (the session number).
    participant_id : str
        The anonymous id the participant typed, brought in the URL, or was given.
    attempt : int
        1 for the first session with this id, 2 for the next, ...
    order_index : int
        Index into the manifest's ``orders``.
    shuffle_seed : int
        Seed of the within-set video order.
    video_order : tuple of tuples of str
        The video ids per set in the order shown (drawn from ``shuffle_seed`` at the start).
    recruitment : dict str → str
        URL parameters brought from the recruitment platform.
    created, last_active : str
        ISO 8601 UTC times of the start and of the last activity.
    demographics_done, practice_done : bool
        Whether those steps are answered.
    training_years : int or None
        Years of surgical training, None if not given.
    prior_assessment : str or None
        ``yes``, ``no`` or ``unsure`` (prefer not to say), None if not given.
    practice_answer : int or None
        The count given for the practice video.
    attention_answer : int or None
        The answer to the attention question, None until given.
    attention_passed : bool or None
        Whether that answer was right, None until given.
    completed, withdrawn : str or None
        ISO 8601 UTC times, None if not (yet).
    """

    pk: int
    participant_id: str
    attempt: int
    order_index: int
    shuffle_seed: int
    video_order: VideoSequence
    recruitment: dict[str, str]
    created: str
    last_active: str
    demographics_done: bool
    practice_done: bool
    training_years: int | None
    prior_assessment: str | None
    practice_answer: int | None
    attention_answer: int | None
    attention_passed: bool | None
    completed: str | None
    withdrawn: str | None

    def status(self, now: datetime, abandon_after_s: float = ABANDON_AFTER_S) -> Status:
        """The session's :class:`Status` at time ``now`` (UTC)."""
        if self.withdrawn:
            return Status.WITHDRAWN
        if self.completed:
            return Status.COMPLETED
        idle = now - datetime.fromisoformat(self.last_active)
        return Status.ACTIVE if idle <= timedelta(seconds=abandon_after_s) else Status.ABANDONED


@dataclass(frozen=True)
class VideoInteraction:
    """What a participant did with one video, summarised from the event log.

    Attributes
    ----------
    first_shown : str or None
        ISO 8601 UTC time the video page was first served.
    n_play, n_pause, n_seek, n_ratechange : int
        Number of those player events.
    max_playback_rate : float or None
        Fastest playback rate used (1 = normal speed).
    watched_s : float
        Seconds of the video played at least once, as last reported by the page (s of media
        time; skipped-over parts and replays not counted).
    ended : bool
        Whether the video was played to its end at least once after ``db.MIN_WATCHED_SHARE``
        of it had been played (the must-watch rule).
    """

    first_shown: str | None
    n_play: int
    n_pause: int
    n_seek: int
    n_ratechange: int
    max_playback_rate: float | None
    watched_s: float
    ended: bool


def participant_from_row(row: sqlite3.Row) -> Participant:
    """The :class:`Participant` of one ``participants`` row (``SELECT *``)."""
    passed = row["attention_passed"]
    return Participant(
        pk=row["pk"],
        participant_id=row["participant_id"],
        attempt=row["attempt"],
        order_index=row["order_index"],
        shuffle_seed=row["shuffle_seed"],
        video_order=tuple(tuple(s) for s in json.loads(row["video_order"])),
        recruitment=json.loads(row["recruitment"]),
        created=row["created"],
        last_active=row["last_active"],
        demographics_done=row["demographics_time"] is not None,
        practice_done=row["practice_time"] is not None,
        training_years=row["training_years"],
        prior_assessment=row["prior_assessment"],
        practice_answer=row["practice_answer"],
        attention_answer=row["attention_answer"],
        attention_passed=None if passed is None else bool(passed),
        completed=row["completed"],
        withdrawn=row["withdrawn"],
    )

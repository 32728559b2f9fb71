"""Exports of the study database: three tables, as CSV, JSON or Parquet, and their codebook.

- ``responses``: one row per answer, with the video's ground truth, where it stood in the
  participant's sequence (the counterbalanced order and the shuffled position) and how the player
  was used; the columns ``participant_id, video_id, reported_touches, attention_passed`` are what
  ``endocam study analyze --responses`` reads, and ``in_analysis`` marks the rows it uses;
- ``participants``: one row per session (status, order, demographics, practice, attention,
  recruitment parameters);
- ``events``: the raw player interaction log.

Each table is a pydantic model whose field descriptions *are* the codebook
(:func:`codebook_markdown`), so a column cannot be exported without being described.
"""

from __future__ import annotations

import csv
import io
import json
import types
from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Any, Literal, Union, get_args, get_origin

from pydantic import BaseModel, ConfigDict, Field

from endocam.study.db import ABANDON_AFTER_S, MIN_WATCHED_SHARE, StudyDB
from endocam.study.flow import attention_after_set
from endocam.study.manifest import Manifest

TableName = Literal["responses", "participants", "events"]
TABLES: tuple[TableName, ...] = ("responses", "participants", "events")
ORDER_SEPARATOR = ">"  # between conditions in ``condition_order``


class _Row(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class ResponseExport(_Row):
    """One row per answer."""

    participant_id: str = Field(
        description="Anonymous participant id (typed, from the URL or generated)."
    )
    attempt: int = Field(description="1 for the first session with this id, 2 for the next, ...")
    in_analysis: bool = Field(
        description="True for the first attempt of an id never withdrawn (used by `study analyze`)."
    )
    order_index: int = Field(
        description="Index of the counterbalanced presentation order (0-based)."
    )
    condition_order: str = Field(
        description="The participant's condition sets in the order shown, joined by '>'."
    )
    set_number: int = Field(description="1-based set in which the video was shown.")
    position_in_set: int = Field(
        description="1-based position of the video within its set (shuffled)."
    )
    position: int = Field(
        description="1-based position of the video in the participant's whole sequence."
    )
    after_attention: bool = Field(
        description="Whether the video came after the attention question."
    )
    video_id: str = Field(description="Video id from manifest.json.")
    condition: str = Field(
        description="Camera condition of the video: one of the manifest's `conditions` "
        "(k of them, e.g. fixed, centering, endocam)."
    )
    trajectory: str = Field(description="Name of the ring trajectory shown.")
    difficulty: int = Field(description="Trajectory difficulty, 1..3 (3 = most difficult).")
    true_touches: int = Field(description="Ground-truth number of touches (simulator), touches.")
    reported_touches: int = Field(
        description="Number of touches the participant reported, touches."
    )
    abs_error: int = Field(description="|reported_touches - true_touches|, touches.")
    shown_at: str | None = Field(description="ISO 8601 UTC time the video page was first served.")
    answered_at: str = Field(description="ISO 8601 UTC time the answer was stored.")
    answer_time_s: float | None = Field(description="answered_at - shown_at, s.")
    n_play: int = Field(description="Number of 'play' events of the player.")
    n_pause: int = Field(description="Number of 'pause' events.")
    n_seek: int = Field(description="Number of completed seeks ('seeked' events).")
    n_ratechange: int = Field(description="Number of playback-rate changes.")
    max_playback_rate: float | None = Field(
        description="Fastest playback rate reported (1 = normal speed); empty if no event."
    )
    watched_s: float = Field(
        description="Seconds of the video played at least once (skipped parts and replays not"
        " counted), as last reported by the page, s."
    )
    watched_to_end: bool = Field(
        description="Whether the video was played to its end at least once, with at least"
        f" {MIN_WATCHED_SHARE:.0%} of it played (the must-watch rule)."
    )
    attention_passed: bool | None = Field(
        description="Attention question right (true), wrong (false), or not answered (empty)."
    )
    status: str = Field(description="Session status: active, completed or abandoned.")


class ParticipantExport(_Row):
    """One row per session (a participant id's attempt)."""

    participant_id: str = Field(description="Anonymous participant id.")
    attempt: int = Field(description="1 for the first session with this id, 2 for the next, ...")
    in_analysis: bool = Field(description="True for the first attempt of an id never withdrawn.")
    status: str = Field(description="active, completed, abandoned (idle too long) or withdrawn.")
    order_index: int = Field(
        description="Index of the counterbalanced presentation order (0-based)."
    )
    condition_order: str = Field(description="Condition sets in the order shown, joined by '>'.")
    video_order: str = Field(
        description="Video ids in the order shown; sets separated by ' | ', videos by spaces."
    )
    shuffle_seed: int = Field(description="Seed of the within-set shuffle (numpy default_rng).")
    created: str = Field(description="ISO 8601 UTC time consent was given and the session began.")
    last_active: str = Field(description="ISO 8601 UTC time of the last answer or player event.")
    completed: str | None = Field(description="ISO 8601 UTC time the last step was answered.")
    withdrawn: str | None = Field(description="ISO 8601 UTC time of the withdrawal, if any.")
    n_answered: int = Field(description="Videos answered (practice excluded).")
    n_videos: int = Field(description="Videos in the participant's sequence.")
    training_years: int | None = Field(
        description="Years of surgical training (empty = not given)."
    )
    prior_assessment: str | None = Field(
        description="Assessed surgical skill before: yes, no, unsure (prefer not to say) or empty."
    )
    practice_answer: int | None = Field(description="Touches counted on the practice video.")
    practice_true_touches: int | None = Field(description="True touches of the practice video.")
    attention_answer: int | None = Field(description="Answer to the attention question.")
    attention_passed: bool | None = Field(description="Whether that answer was right.")
    recruitment: str = Field(
        description="Recruitment-platform URL parameters (e.g. STUDY_ID, SESSION_ID) as JSON."
    )


class EventExport(_Row):
    """One row per player event (the raw interaction log)."""

    participant_id: str = Field(description="Anonymous participant id.")
    attempt: int = Field(description="Session attempt of the id (see responses).")
    video_id: str = Field(description="Video id, or _practice for the practice video.")
    kind: str = Field(
        description="shown (page served), play, pause, seeked, ratechange, ended, progress."
    )
    media_time_s: float | None = Field(description="Player position when the event fired, s.")
    playback_rate: float | None = Field(description="Playback rate at the event (1 = normal).")
    watched_s: float | None = Field(
        description="Seconds of the video played at least once so far on the page, s."
    )
    received: str = Field(description="ISO 8601 UTC time the server stored the event.")


MODELS: dict[TableName, type[_Row]] = {
    "responses": ResponseExport,
    "participants": ParticipantExport,
    "events": EventExport,
}


def order_text(manifest: Manifest, order_index: int) -> str:
    """The conditions of order ``order_index`` as text, e.g. ``fixed>centering>orientation``."""
    return ORDER_SEPARATOR.join(manifest.orders[order_index])


def _seconds_between(start: str | None, end: str) -> float | None:
    if start is None:
        return None
    return (datetime.fromisoformat(end) - datetime.fromisoformat(start)).total_seconds()


def export_tables(
    db: StudyDB, manifest: Manifest, abandon_after_s: float = ABANDON_AFTER_S
) -> dict[TableName, list[Any]]:
    """Read the three tables from the database.

    Parameters
    ----------
    db : StudyDB
        The study database.
    manifest : Manifest
        Ground truth and conditions of the videos.
    abandon_after_s : float
        Idle time (s) after which an unfinished session is reported abandoned.

    Returns
    -------
    dict table name → list of rows
        Rows of :class:`ResponseExport`, :class:`ParticipantExport`, :class:`EventExport`.
    """
    now = datetime.now(UTC)
    sessions = {p.pk: p for p in db.participants()}
    analysed = db.analysed_pks()
    interactions = db.interactions()
    answered: dict[int, int] = {}
    responses = []
    for r in db.responses():
        p = sessions[r["participant_pk"]]
        answered[p.pk] = answered.get(p.pk, 0) + 1
        video = manifest.video(r["video_id"])
        where = next(
            (s, i, sum(len(x) for x in p.video_order[:s]) + i)
            for s, ids in enumerate(p.video_order)
            for i, vid in enumerate(ids)
            if vid == video.id
        )
        seen = interactions.get((p.pk, video.id))
        responses.append(
            ResponseExport(
                participant_id=p.participant_id,
                attempt=p.attempt,
                in_analysis=p.pk in analysed,
                order_index=p.order_index,
                condition_order=ORDER_SEPARATOR.join(c for c in manifest.orders[p.order_index]),
                set_number=where[0] + 1,
                position_in_set=where[1] + 1,
                position=where[2] + 1,
                after_attention=where[0] >= attention_after_set(len(p.video_order)),
                video_id=video.id,
                condition=video.condition,
                trajectory=video.trajectory,
                difficulty=video.difficulty,
                true_touches=video.true_touches,
                reported_touches=r["reported_touches"],
                abs_error=abs(r["reported_touches"] - video.true_touches),
                shown_at=seen.first_shown if seen else None,
                answered_at=r["submitted"],
                answer_time_s=_seconds_between(seen.first_shown if seen else None, r["submitted"]),
                n_play=seen.n_play if seen else 0,
                n_pause=seen.n_pause if seen else 0,
                n_seek=seen.n_seek if seen else 0,
                n_ratechange=seen.n_ratechange if seen else 0,
                max_playback_rate=seen.max_playback_rate if seen else None,
                watched_s=seen.watched_s if seen else 0.0,
                watched_to_end=seen.ended if seen else False,
                attention_passed=p.attention_passed,
                status=p.status(now, abandon_after_s).value,
            )
        )
    participants = [
        ParticipantExport(
            participant_id=p.participant_id,
            attempt=p.attempt,
            in_analysis=p.pk in analysed,
            status=p.status(now, abandon_after_s).value,
            order_index=p.order_index,
            condition_order=order_text(manifest, p.order_index),
            video_order=" | ".join(" ".join(s) for s in p.video_order),
            shuffle_seed=p.shuffle_seed,
            created=p.created,
            last_active=p.last_active,
            completed=p.completed,
            withdrawn=p.withdrawn,
            n_answered=answered.get(p.pk, 0),
            n_videos=sum(len(s) for s in p.video_order),
            training_years=p.training_years,
            prior_assessment=p.prior_assessment,
            practice_answer=p.practice_answer,
            practice_true_touches=manifest.practice.true_touches if manifest.practice else None,
            attention_answer=p.attention_answer,
            attention_passed=p.attention_passed,
            recruitment=json.dumps(p.recruitment, sort_keys=True),
        )
        for p in sessions.values()
    ]
    events = [EventExport(**e) for e in db.events()]
    return {"responses": responses, "participants": participants, "events": events}


def columns(table: TableName) -> tuple[str, ...]:
    """Column names of an export table, in order."""
    return tuple(MODELS[table].model_fields)


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, bool):
        return str(value).lower()
    return value


def to_csv(table: TableName, rows: Sequence[_Row]) -> str:
    """CSV text (header = :func:`columns`; booleans ``true``/``false``, missing values empty)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(columns(table))
    for row in rows:
        writer.writerow([_cell(v) for v in row.model_dump().values()])
    return out.getvalue()


def to_json(tables: dict[TableName, list[Any]]) -> dict[str, list[dict[str, Any]]]:
    """JSON-ready dict: table name → list of row objects (missing values null)."""
    return {name: [r.model_dump(mode="json") for r in rows] for name, rows in tables.items()}


def _base_type(annotation: Any) -> tuple[type, bool]:
    """The column's Python type and whether it may be missing (``X | None``)."""
    if get_origin(annotation) in (Union, types.UnionType):
        return next(a for a in get_args(annotation) if a is not type(None)), True
    return annotation, False


def _arrow_type(annotation: Any) -> Any:
    import pyarrow as pa

    base, _ = _base_type(annotation)
    return {bool: pa.bool_(), int: pa.int64(), float: pa.float64(), str: pa.string()}[base]


def to_parquet(table: TableName, rows: Sequence[_Row]) -> bytes:
    """Parquet file bytes with a typed schema (nullable columns where the codebook says empty)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    fields = MODELS[table].model_fields
    schema = pa.schema([(name, _arrow_type(f.annotation)) for name, f in fields.items()])
    data = pa.Table.from_pylist([r.model_dump() for r in rows], schema=schema)
    out = io.BytesIO()
    pq.write_table(data, out)
    return out.getvalue()


def codebook_markdown() -> str:
    """``codebook.md``: every column of every table, its type and meaning."""
    lines = [
        "# Codebook of the study exports",
        "",
        "Files: `<table>.csv`, `<table>.parquet` and `export.json` (`{table: [rows]}`).",
        "In CSV, booleans are `true`/`false` and an empty cell is a missing value (null in JSON",
        "and Parquet). Times are ISO 8601 in UTC.",
    ]
    for table, model in MODELS.items():
        lines += ["", f"## {table}", "", (model.__doc__ or "").strip(), ""]
        lines += ["| column | type | description |", "|---|---|---|"]
        for name, field in model.model_fields.items():
            base, optional = _base_type(field.annotation)
            kind = base.__name__ + (", may be empty" if optional else "")
            text = (field.description or "").replace("|", "\\|")
            lines.append(f"| `{name}` | {kind} | {text} |")
    return "\n".join(lines) + "\n"

"""SQLite storage of the study: sessions, their orders, answers, interaction events, admin log.

The database is a real file in WAL mode with ``synchronous=FULL``: every answer is committed in its
own transaction when it is submitted, so neither a reload nor a server restart loses anything.
Each call opens its own short-lived connection, so the store is safe to share between the web
server's worker threads and between processes. The answer that finishes a session and its
``completed`` stamp are one transaction (the ``done`` predicate of :meth:`StudyDB.record_answer`);
a database written by an older endocam, killed between the two, is repaired by
:meth:`StudyDB.repair_completed` when the app starts.

Session tokens are random (``secrets.token_urlsafe``); only their SHA-256 is stored, so a copy of
the database does not let anyone act as a participant.

A participant id is a label, not a key: the same id may start several sessions (someone reopening
a recruitment link in another browser), so the server never reveals whether an id is known. Each
session is numbered per id (``attempt`` 1, 2, ...); only the first attempt enters the analysis
(:meth:`StudyDB.analysed_pks`), the others stay in the exports, marked. A withdrawn id is refused
when it tries to start again (:class:`~endocam.study.records.WithdrawnError`) and none of its
sessions is ever analysed, not even one started before the refusal existed.

Read-only (``study analyze --db``), the file is opened ``mode=ro``; when no ``-wal`` file lies
beside it (no server running, everything checkpointed) also ``immutable=1``, so that SQLite
creates no ``-wal``/``-shm`` files next to it. With a ``-wal`` file present (a running or killed
server) it is read through that WAL.

A session's status is *completed* (every step answered), *withdrawn* (by the admin), *active*
(something happened within the last ``abandon_after_s``) or else *abandoned*. Counterbalancing
counts completed and active sessions only (:func:`endocam.study.counterbalance.assign_order`).
"""

from __future__ import annotations

import hashlib
import json
import secrets
import sqlite3
from collections.abc import Callable, Collection, Iterator, Mapping
from contextlib import closing, contextmanager
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from endocam.study.counterbalance import assign_order
from endocam.study.flow import VideoSequence
from endocam.study.migration import V1_SCHEMA_VERSION, migrate_v1
from endocam.study.records import (
    ABANDON_AFTER_S,
    ConflictError,
    Participant,
    VideoInteraction,
    WithdrawnError,
    participant_from_row,
)
from endocam.study.responses import ResponseRow

SCHEMA_VERSION = 2
BUSY_TIMEOUT_S = 10.0  # s, how long a writer waits for the lock
MAX_EVENTS_PER_VIDEO = 2000  # interaction events stored per session and video (the rest dropped)
EVENT_KINDS = ("shown", "play", "pause", "seeked", "ratechange", "ended", "progress")
MIN_WATCHED_SHARE = 0.95
"""Share of a video's duration that must have been played at least once (seeks and replays not
counted) for its ``ended`` event to count as watched to the end: the page reports the played
share from its ``timeupdate`` events, ~0.25 s apart, so an honest viewing reaches ~1.0, and a
viewer who skipped ahead to the end does not."""

WATCHED_TO_END = "(kind = 'ended' AND watched_s >= ? * media_time_s)"
"""SQL condition on an event row: an ``ended`` event after :data:`MIN_WATCHED_SHARE` of the
video was played (``watched_s`` and ``media_time_s``, the position at the end, both reported; a
missing one makes it false)."""

_SCHEMA = """
CREATE TABLE IF NOT EXISTS participants (
    pk               INTEGER PRIMARY KEY AUTOINCREMENT,
    participant_id   TEXT    NOT NULL,
    attempt          INTEGER NOT NULL CHECK (attempt >= 1),
    token_sha256     TEXT    NOT NULL UNIQUE,
    order_index      INTEGER NOT NULL CHECK (order_index >= 0),
    shuffle_seed     INTEGER NOT NULL,
    video_order      TEXT    NOT NULL,
    recruitment      TEXT    NOT NULL,
    created          TEXT    NOT NULL,
    consented        TEXT    NOT NULL,
    last_active      TEXT    NOT NULL,
    training_years   INTEGER,
    prior_assessment TEXT,
    demographics_time TEXT,
    practice_answer  INTEGER,
    practice_time    TEXT,
    attention_answer INTEGER,
    attention_passed INTEGER CHECK (attention_passed IN (0, 1)),
    attention_time   TEXT,
    completed        TEXT,
    withdrawn        TEXT,
    UNIQUE (participant_id, attempt)
);
CREATE TABLE IF NOT EXISTS responses (
    participant_pk   INTEGER NOT NULL REFERENCES participants(pk),
    video_id         TEXT    NOT NULL,
    reported_touches INTEGER NOT NULL CHECK (reported_touches BETWEEN 0 AND 99),
    submitted        TEXT    NOT NULL,
    PRIMARY KEY (participant_pk, video_id)
);
CREATE TABLE IF NOT EXISTS events (
    pk               INTEGER PRIMARY KEY AUTOINCREMENT,
    participant_pk   INTEGER NOT NULL REFERENCES participants(pk),
    video_id         TEXT    NOT NULL,
    kind             TEXT    NOT NULL,
    media_time_s     REAL,
    playback_rate    REAL,
    watched_s        REAL,
    received         TEXT    NOT NULL
);
CREATE INDEX IF NOT EXISTS events_by_video ON events (participant_pk, video_id);
CREATE TABLE IF NOT EXISTS admin_log (
    pk               INTEGER PRIMARY KEY AUTOINCREMENT,
    time             TEXT    NOT NULL,
    action           TEXT    NOT NULL,
    participant_id   TEXT,
    detail           TEXT    NOT NULL
);
"""
_TABLES = ("participants", "responses", "events", "admin_log")
# each id's first session, for ids none of whose sessions is withdrawn
_ANALYSED_PKS = (
    "SELECT MIN(pk) FROM participants GROUP BY participant_id HAVING COUNT(withdrawn) = 0"
)
# (stored session, ids of its answered videos) → whether every step of the study is answered
DonePredicate = Callable[[Participant, Collection[str]], bool]


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _token_hash(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


class StudyDB:
    """The study database file.

    Parameters
    ----------
    path : str or Path
        SQLite file; created with the schema if missing. Its folder must exist.
    read_only : bool
        Open an existing study database without changing it (the analysis): a file that is
        missing, empty or not a study database of this schema is refused.
    v1_sequence : callable order_index → VideoSequence, optional
        The video order schema 1 showed (:func:`endocam.study.migration.v1_sequence` bound to
        the study's manifest): with it a schema-1 file is migrated in place (a backup beside it,
        see :mod:`endocam.study.migration`); without it such a file is refused.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        read_only: bool = False,
        v1_sequence: Callable[[int], VideoSequence] | None = None,
    ) -> None:
        self.path = Path(path)
        self.read_only = read_only
        if read_only:
            self._check_existing()
            return
        if not self.path.parent.is_dir():
            raise ValueError(f"path: folder {self.path.parent} does not exist")
        try:
            with self._connect() as conn:
                conn.execute("PRAGMA journal_mode=WAL")
                version = conn.execute("PRAGMA user_version").fetchone()[0]
                if version == V1_SCHEMA_VERSION and v1_sequence is not None:
                    migrate_v1(conn, self.path, _SCHEMA, v1_sequence, SCHEMA_VERSION)
                elif version == V1_SCHEMA_VERSION:
                    raise ValueError(
                        f"path: {self.path} has schema 1; `endocam study serve` with its study"
                        " folder migrates it"
                    )
                elif version not in (0, SCHEMA_VERSION):
                    raise ValueError(
                        f"path: {self.path} has schema {version}, not {SCHEMA_VERSION}"
                        " (made by another endocam: export it there, start a new file)"
                    )
                conn.executescript(_SCHEMA)
                conn.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
        except sqlite3.DatabaseError as exc:
            raise ValueError(f"path: {self.path} is not a usable study database: {exc}") from None

    def _check_existing(self) -> None:
        if not self.path.is_file():
            raise ValueError(f"{self.path}: no such file")
        try:
            with self._connect() as conn:
                version = conn.execute("PRAGMA user_version").fetchone()[0]
                tables = {
                    r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")
                }
        except (sqlite3.DatabaseError, ValueError) as exc:
            raise ValueError(f"{self.path}: not a study database ({exc})") from None
        if version == V1_SCHEMA_VERSION:
            raise ValueError(
                f"{self.path}: schema 1; `endocam study serve` with its study folder migrates it"
            )
        if version != SCHEMA_VERSION or not set(_TABLES) <= tables:
            raise ValueError(
                f"{self.path}: not a study database of schema {SCHEMA_VERSION}"
                f" (schema {version}, tables {sorted(tables) or 'none'})"
            )

    @contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        try:
            if self.read_only:
                wal = self.path.with_name(self.path.name + "-wal")
                # no WAL beside it: the file is complete; immutable keeps SQLite from creating one
                mode = "mode=ro" if wal.exists() else "mode=ro&immutable=1"
                uri = f"{self.path.resolve().as_uri()}?{mode}"
                conn = sqlite3.connect(uri, uri=True, timeout=BUSY_TIMEOUT_S, isolation_level=None)
            else:
                conn = sqlite3.connect(self.path, timeout=BUSY_TIMEOUT_S, isolation_level=None)
        except sqlite3.Error as exc:
            raise ValueError(f"path: cannot open database {self.path}: {exc}") from None
        with closing(conn):
            conn.row_factory = sqlite3.Row
            conn.execute("PRAGMA foreign_keys=ON")
            if not self.read_only:
                conn.execute("PRAGMA synchronous=FULL")
            yield conn

    @contextmanager
    def _transaction(self) -> Iterator[sqlite3.Connection]:
        """One ``BEGIN IMMEDIATE`` ... ``COMMIT`` (rolled back on any exception)."""
        with self._connect() as conn:
            conn.execute("BEGIN IMMEDIATE")
            try:
                yield conn
            except BaseException:
                conn.execute("ROLLBACK")
                raise
            conn.execute("COMMIT")

    @staticmethod
    def _stamp_if_done(conn: sqlite3.Connection, pk: int, done: DonePredicate | None) -> None:
        """Inside a write transaction: stamp session ``pk`` completed if ``done`` says so."""
        if done is None:
            return
        row = conn.execute("SELECT * FROM participants WHERE pk = ?", (pk,)).fetchone()
        answered = {
            r[0]
            for r in conn.execute("SELECT video_id FROM responses WHERE participant_pk = ?", (pk,))
        }
        if row["completed"] is None and done(participant_from_row(row), answered):
            conn.execute("UPDATE participants SET completed = ? WHERE pk = ?", (_now(), pk))

    # ---- sessions ------------------------------------------------------------------------------
    def create_participant(
        self,
        participant_id: str,
        n_orders: int,
        sequence_for: Callable[[int, int], VideoSequence] | None = None,
        *,
        recruitment: Mapping[str, str] | None = None,
        abandon_after_s: float = ABANDON_AFTER_S,
    ) -> tuple[Participant, str]:
        """Start a session: assign an order (fewest counted sessions), draw the video order.

        Counting and inserting happen in one ``BEGIN IMMEDIATE`` transaction, so concurrent starts
        get balanced orders. Giving consent precedes this call (no session without consent).

        Parameters
        ----------
        participant_id : str
            Anonymous id; an id already used starts a further attempt, a withdrawn one is refused.
        n_orders : int
            Number of presentation orders in the manifest.
        sequence_for : callable (order_index, seed) → video ids per set, optional
            Usually :func:`endocam.study.flow.video_sequence` bound to the manifest; without it
            the sequence is stored empty (database-level tests).
        recruitment : mapping str → str, optional
            URL parameters from the recruitment platform.
        abandon_after_s : float
            Idle time (s) after which an unfinished session no longer counts.

        Returns
        -------
        participant : Participant
            The new session.
        token : str
            The secret session token (only its hash is stored).

        Raises
        ------
        WithdrawnError
            A session of ``participant_id`` was withdrawn (nothing is stored).
        """
        token = secrets.token_urlsafe(32)
        seed = secrets.randbits(63)
        now = datetime.now(UTC)
        active_since = (now - timedelta(seconds=abandon_after_s)).isoformat(timespec="milliseconds")
        stamp = now.isoformat(timespec="milliseconds")
        with self._transaction() as conn:
            attempt, withdrawn = conn.execute(
                "SELECT COUNT(*), COUNT(withdrawn) FROM participants WHERE participant_id = ?",
                (participant_id,),
            ).fetchone()
            if withdrawn:
                raise WithdrawnError("this participant id was withdrawn from the study")
            counts = [0] * n_orders
            for index, n in conn.execute(
                "SELECT order_index, COUNT(*) FROM participants WHERE withdrawn IS NULL"
                " AND (completed IS NOT NULL OR last_active >= ?) GROUP BY order_index",
                (active_since,),
            ):
                if index < n_orders:
                    counts[index] = n
            order_index = assign_order(counts)
            sequence = sequence_for(order_index, seed) if sequence_for else ()
            cur = conn.execute(
                "INSERT INTO participants (participant_id, attempt, token_sha256, order_index,"
                " shuffle_seed, video_order, recruitment, created, consented, last_active)"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    participant_id,
                    attempt + 1,
                    _token_hash(token),
                    order_index,
                    seed,
                    json.dumps([list(s) for s in sequence]),
                    json.dumps(dict(recruitment or {})),
                    stamp,
                    stamp,
                    stamp,
                ),
            )
            row = conn.execute(
                "SELECT * FROM participants WHERE pk = ?", (cur.lastrowid,)
            ).fetchone()
        return participant_from_row(row), token

    def participant_by_token(self, token: str) -> Participant | None:
        """The (not withdrawn) session owning ``token``, or None."""
        with self._connect() as conn:
            row = conn.execute(
                "SELECT * FROM participants WHERE token_sha256 = ? AND withdrawn IS NULL",
                (_token_hash(token),),
            ).fetchone()
        return None if row is None else participant_from_row(row)

    def refresh(self, participant: Participant) -> Participant:
        """Re-read ``participant`` (after one of its steps was stored)."""
        with self._connect() as conn:
            row = conn.execute(
                "SELECT * FROM participants WHERE pk = ?", (participant.pk,)
            ).fetchone()
        if row is None:
            raise KeyError(participant.participant_id)
        return participant_from_row(row)

    def participants(self) -> list[Participant]:
        """Every session, in order of arrival."""
        with self._connect() as conn:
            rows = conn.execute("SELECT * FROM participants ORDER BY pk").fetchall()
        return [participant_from_row(r) for r in rows]

    def answers(self, participant: Participant) -> dict[str, int]:
        """The session's own answers: video id → reported touches."""
        with self._connect() as conn:
            rows = conn.execute(
                "SELECT video_id, reported_touches FROM responses WHERE participant_pk = ?",
                (participant.pk,),
            ).fetchall()
        return {r["video_id"]: r["reported_touches"] for r in rows}

    # ---- steps ---------------------------------------------------------------------------------
    def _update_once(
        self,
        participant: Participant,
        sets: str,
        unset: str,
        values: tuple,
        done: DonePredicate | None = None,
    ) -> None:
        with self._transaction() as conn:
            cur = conn.execute(
                f"UPDATE participants SET {sets}, last_active = ? WHERE pk = ? AND {unset} IS NULL",
                (*values, _now(), participant.pk),
            )
            if cur.rowcount != 1:
                raise ConflictError("this step is already answered")
            self._stamp_if_done(conn, participant.pk, done)

    def record_demographics(
        self, participant: Participant, training_years: int | None, prior_assessment: str | None
    ) -> None:
        """Store the demographic answers once (None = not given)."""
        self._update_once(
            participant,
            "training_years = ?, prior_assessment = ?, demographics_time = ?",
            "demographics_time",
            (training_years, prior_assessment, _now()),
        )

    def record_practice(self, participant: Participant, reported_touches: int) -> None:
        """Store the practice count once."""
        self._update_once(
            participant,
            "practice_answer = ?, practice_time = ?",
            "practice_time",
            (reported_touches, _now()),
        )

    def record_answer(
        self,
        participant: Participant,
        video_id: str,
        reported_touches: int,
        done: DonePredicate | None = None,
    ) -> None:
        """Store one answer in its own transaction.

        If ``done`` (given the session and its answered video ids, this answer included) says
        every step is answered, the session is stamped completed in the same transaction: a crash
        never leaves a fully answered session unstamped.

        Raises
        ------
        ConflictError
            The participant already answered ``video_id`` (answers are never overwritten).
        """
        try:
            with self._transaction() as conn:
                now = _now()
                conn.execute(
                    "INSERT INTO responses (participant_pk, video_id, reported_touches, submitted)"
                    " VALUES (?, ?, ?, ?)",
                    (participant.pk, video_id, reported_touches, now),
                )
                conn.execute(
                    "UPDATE participants SET last_active = ? WHERE pk = ?", (now, participant.pk)
                )
                self._stamp_if_done(conn, participant.pk, done)
        except sqlite3.IntegrityError as exc:
            if "UNIQUE" in str(exc) or "PRIMARY KEY" in str(exc):
                raise ConflictError(f"video {video_id!r} is already answered") from None
            raise

    def record_attention(
        self, participant: Participant, answer: int, passed: bool, done: DonePredicate | None = None
    ) -> None:
        """Store the attention answer once, in its own transaction (``done``: as for answers).

        Raises
        ------
        ConflictError
            The participant already answered the attention question.
        """
        try:
            self._update_once(
                participant,
                "attention_answer = ?, attention_passed = ?, attention_time = ?",
                "attention_answer",
                (answer, int(passed), _now()),
                done,
            )
        except ConflictError:
            raise ConflictError("the attention question is already answered") from None

    def repair_completed(self, done: DonePredicate) -> list[str]:
        """Stamp the sessions that ``done`` finds fully answered but that lack ``completed``.

        Such a session was left by an older endocam killed between the last answer and its
        stamp. The stamp is the time of its last answer (or of the attention answer, if later);
        each repair is written to the admin log.

        Returns
        -------
        list of str
            The participant ids repaired, in order of arrival.
        """
        repaired = []
        with self._transaction() as conn:
            rows = conn.execute(
                "SELECT * FROM participants WHERE completed IS NULL AND withdrawn IS NULL"
                " ORDER BY pk"
            ).fetchall()
            for row in rows:
                answers = conn.execute(
                    "SELECT video_id, submitted FROM responses WHERE participant_pk = ?",
                    (row["pk"],),
                ).fetchall()
                if not done(participant_from_row(row), {a[0] for a in answers}):
                    continue
                stamp = max([a[1] for a in answers] + [row["attention_time"] or ""])
                conn.execute(
                    "UPDATE participants SET completed = ? WHERE pk = ?", (stamp, row["pk"])
                )
                conn.execute(
                    "INSERT INTO admin_log (time, action, participant_id, detail)"
                    " VALUES (?, ?, ?, ?)",
                    (
                        _now(),
                        "repair",
                        row["participant_id"],
                        f"attempt {row['attempt']}: every step answered but no completed stamp;"
                        f" stamped {stamp} (its last answer)",
                    ),
                )
                repaired.append(row["participant_id"])
        return repaired

    # ---- interaction log -----------------------------------------------------------------------
    def record_event(
        self,
        participant: Participant,
        video_id: str,
        kind: str,
        media_time_s: float | None = None,
        playback_rate: float | None = None,
        watched_s: float | None = None,
    ) -> bool:
        """Append one player event; returns False if the per-video cap was reached (dropped).

        ``kind`` is one of :data:`EVENT_KINDS`; times in s of media time, rate 1 = normal speed.
        """
        if kind not in EVENT_KINDS:
            raise ValueError(f"kind must be one of {EVENT_KINDS}, got {kind!r}")
        with self._transaction() as conn:
            n = conn.execute(
                "SELECT COUNT(*) FROM events WHERE participant_pk = ? AND video_id = ?",
                (participant.pk, video_id),
            ).fetchone()[0]
            if n >= MAX_EVENTS_PER_VIDEO or (
                kind == "shown"
                and conn.execute(
                    "SELECT 1 FROM events WHERE participant_pk = ? AND video_id = ?"
                    " AND kind = 'shown'",
                    (participant.pk, video_id),
                ).fetchone()
            ):
                return False
            now = _now()
            conn.execute(
                "INSERT INTO events (participant_pk, video_id, kind, media_time_s, playback_rate,"
                " watched_s, received) VALUES (?, ?, ?, ?, ?, ?, ?)",
                (participant.pk, video_id, kind, media_time_s, playback_rate, watched_s, now),
            )
            conn.execute(
                "UPDATE participants SET last_active = ? WHERE pk = ?", (now, participant.pk)
            )
        return True

    def interactions(self) -> dict[tuple[int, str], VideoInteraction]:
        """Per (session pk, video id): the summary of its interaction events."""
        with self._connect() as conn:
            rows = conn.execute(
                "SELECT participant_pk, video_id,"
                " MIN(CASE WHEN kind = 'shown' THEN received END),"
                " SUM(kind = 'play'), SUM(kind = 'pause'), SUM(kind = 'seeked'),"
                " SUM(kind = 'ratechange'), MAX(playback_rate), COALESCE(MAX(watched_s), 0),"
                f" COALESCE(MAX({WATCHED_TO_END}), 0)"
                " FROM events GROUP BY participant_pk, video_id",
                (MIN_WATCHED_SHARE,),
            ).fetchall()
        return {
            (r[0], r[1]): VideoInteraction(
                first_shown=r[2],
                n_play=r[3],
                n_pause=r[4],
                n_seek=r[5],
                n_ratechange=r[6],
                max_playback_rate=r[7],
                watched_s=float(r[8]),
                ended=bool(r[9]),
            )
            for r in rows
        }

    def watched_to_end(self, participant: Participant, video_id: str) -> bool:
        """Whether the video was played to its end with :data:`MIN_WATCHED_SHARE` of it played.

        An end reached by skipping ahead does not count.
        """
        with self._connect() as conn:
            row = conn.execute(
                "SELECT 1 FROM events WHERE participant_pk = ? AND video_id = ?"
                f" AND {WATCHED_TO_END}",
                (participant.pk, video_id, MIN_WATCHED_SHARE),
            ).fetchone()
        return row is not None

    def events(self) -> list[dict[str, Any]]:
        """Every interaction event with its session's participant id, in order of arrival."""
        with self._connect() as conn:
            rows = conn.execute(
                "SELECT p.participant_id, p.attempt, e.video_id, e.kind, e.media_time_s,"
                " e.playback_rate, e.watched_s, e.received"
                " FROM events e JOIN participants p ON p.pk = e.participant_pk ORDER BY e.pk"
            ).fetchall()
        return [dict(r) for r in rows]

    def responses(self) -> list[sqlite3.Row]:
        """Every stored answer with its session pk and time, in order of submission."""
        with self._connect() as conn:
            return conn.execute(
                "SELECT participant_pk, video_id, reported_touches, submitted FROM responses"
                " ORDER BY participant_pk, submitted, video_id"
            ).fetchall()

    # ---- admin ---------------------------------------------------------------------------------
    def withdraw(self, participant_id: str, note: str = "") -> int:
        """Withdraw every session of ``participant_id`` and log the action.

        Their answers, events, demographics and recruitment parameters are deleted; a marked row
        stays, so the id's attempts stay numbered and the session cannot continue.

        Returns
        -------
        int
            Number of answers removed.

        Raises
        ------
        KeyError
            No session has this id, or all of them are already withdrawn.
        """
        with self._transaction() as conn:
            pks = [
                r[0]
                for r in conn.execute(
                    "SELECT pk FROM participants WHERE participant_id = ? AND withdrawn IS NULL",
                    (participant_id,),
                )
            ]
            if not pks:
                raise KeyError(participant_id)
            marks = ",".join("?" * len(pks))
            removed = conn.execute(
                f"DELETE FROM responses WHERE participant_pk IN ({marks})", pks
            ).rowcount
            conn.execute(f"DELETE FROM events WHERE participant_pk IN ({marks})", pks)
            conn.execute(
                "UPDATE participants SET withdrawn = ?, training_years = NULL,"
                f" prior_assessment = NULL, recruitment = '{{}}' WHERE pk IN ({marks})",
                (_now(), *pks),
            )
            detail = f"{len(pks)} session(s), {removed} answer(s) removed"
            conn.execute(
                "INSERT INTO admin_log (time, action, participant_id, detail) VALUES (?, ?, ?, ?)",
                (_now(), "withdraw", participant_id, detail + (f"; {note}" if note else "")),
            )
        return removed

    def admin_log(self) -> list[dict[str, Any]]:
        """Every logged admin action, oldest first."""
        with self._connect() as conn:
            rows = conn.execute(
                "SELECT time, action, participant_id, detail FROM admin_log ORDER BY pk"
            ).fetchall()
        return [dict(r) for r in rows]

    def analysed_pks(self) -> set[int]:
        """The sessions that enter the analysis: each id's first attempt, unless it was withdrawn.

        An id with any withdrawn session has none analysed (a later attempt started before
        withdrawn ids were refused does not count either).
        """
        with self._connect() as conn:
            return {r[0] for r in conn.execute(_ANALYSED_PKS)}

    def export_rows(self) -> list[ResponseRow]:
        """The answers that enter the analysis (those of :meth:`analysed_pks`), oldest first."""
        with self._connect() as conn:
            rows = conn.execute(
                "SELECT p.participant_id, r.video_id, r.reported_touches, p.attention_passed"
                " FROM responses r JOIN participants p ON p.pk = r.participant_pk"
                f" WHERE p.pk IN ({_ANALYSED_PKS})"
                " ORDER BY p.pk, r.submitted, r.video_id"
            ).fetchall()
        return [
            ResponseRow(
                participant_id=r[0],
                video_id=r[1],
                reported_touches=r[2],
                attention_passed=None if r[3] is None else bool(r[3]),
            )
            for r in rows
        ]

"""SQLite storage of the study: participants, their orders, attention answers and responses.

The database is a real file in WAL mode with ``synchronous=FULL``: every answer is committed in its
own transaction when it is submitted, so neither a reload nor a server restart loses anything.
Each call opens its own short-lived connection, so the store is safe to share between the web
server's worker threads and between processes.

Session tokens are random (``secrets.token_urlsafe``); only their SHA-256 is stored, so a copy of
the database does not let anyone act as a participant.
"""

from __future__ import annotations

import hashlib
import secrets
import sqlite3
from collections.abc import Iterator
from contextlib import closing, contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from endocam.study.counterbalance import assign_order
from endocam.study.responses import ResponseRow

SCHEMA_VERSION = 1
BUSY_TIMEOUT_S = 10.0  # s, how long a writer waits for the lock

_SCHEMA = """
CREATE TABLE IF NOT EXISTS participants (
    pk               INTEGER PRIMARY KEY AUTOINCREMENT,
    participant_id   TEXT    NOT NULL UNIQUE,
    token_sha256     TEXT    NOT NULL UNIQUE,
    order_index      INTEGER NOT NULL CHECK (order_index >= 0),
    created          TEXT    NOT NULL,
    attention_answer INTEGER,
    attention_passed INTEGER CHECK (attention_passed IN (0, 1)),
    attention_time   TEXT
);
CREATE TABLE IF NOT EXISTS responses (
    participant_pk   INTEGER NOT NULL REFERENCES participants(pk),
    video_id         TEXT    NOT NULL,
    reported_touches INTEGER NOT NULL CHECK (reported_touches BETWEEN 0 AND 99),
    submitted        TEXT    NOT NULL,
    PRIMARY KEY (participant_pk, video_id)
);
"""


class ConflictError(Exception):
    """The request conflicts with what is already stored (duplicate id, answer given twice)."""


@dataclass(frozen=True)
class Participant:
    """A stored participant (never carries the session token).

    Attributes
    ----------
    pk : int
        Internal row id.
    participant_id : str
        The anonymous id the participant typed or was given.
    order_index : int
        Index into the manifest's ``orders``.
    created : str
        ISO 8601 UTC time the session started.
    attention_answer : int or None
        The answer to the attention question, None until given.
    attention_passed : bool or None
        Whether that answer was right, None until given.
    """

    pk: int
    participant_id: str
    order_index: int
    created: str
    attention_answer: int | None
    attention_passed: bool | None


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _token_hash(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def _participant(row: sqlite3.Row) -> Participant:
    passed = row["attention_passed"]
    return Participant(
        pk=row["pk"],
        participant_id=row["participant_id"],
        order_index=row["order_index"],
        created=row["created"],
        attention_answer=row["attention_answer"],
        attention_passed=None if passed is None else bool(passed),
    )


class StudyDB:
    """The study database file.

    Parameters
    ----------
    path : str or Path
        SQLite file; created with the schema if missing. Its folder must exist.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.parent.is_dir():
            raise ValueError(f"path: folder {self.path.parent} does not exist")
        try:
            with self._connect() as conn:
                conn.execute("PRAGMA journal_mode=WAL")
                version = conn.execute("PRAGMA user_version").fetchone()[0]
                if version not in (0, SCHEMA_VERSION):
                    raise ValueError(
                        f"path: {self.path} has schema {version}, not {SCHEMA_VERSION}"
                    )
                conn.executescript(_SCHEMA)
                conn.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
        except sqlite3.DatabaseError as exc:
            raise ValueError(f"path: {self.path} is not a usable study database: {exc}") from None

    @contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        try:
            conn = sqlite3.connect(self.path, timeout=BUSY_TIMEOUT_S, isolation_level=None)
        except sqlite3.Error as exc:
            raise ValueError(f"path: cannot open database {self.path}: {exc}") from None
        with closing(conn):
            conn.row_factory = sqlite3.Row
            conn.execute("PRAGMA foreign_keys=ON")
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

    def create_participant(self, participant_id: str, n_orders: int) -> tuple[Participant, str]:
        """Register a participant, assign the next order round-robin and issue a session token.

        The count of earlier participants and the insert happen in one ``BEGIN IMMEDIATE``
        transaction, so concurrent starts get consecutive order indices.

        Parameters
        ----------
        participant_id : str
            Anonymous id, unique in the study.
        n_orders : int
            Number of presentation orders in the manifest.

        Returns
        -------
        participant : Participant
            The new participant.
        token : str
            The secret session token (only its hash is stored).

        Raises
        ------
        ConflictError
            ``participant_id`` is already taken.
        """
        token = secrets.token_urlsafe(32)
        with self._transaction() as conn:
            taken = conn.execute(
                "SELECT 1 FROM participants WHERE participant_id = ?", (participant_id,)
            ).fetchone()
            if taken:
                raise ConflictError(f"participant id {participant_id!r} is already taken")
            count = conn.execute("SELECT COUNT(*) FROM participants").fetchone()[0]
            cur = conn.execute(
                "INSERT INTO participants (participant_id, token_sha256, order_index, created)"
                " VALUES (?, ?, ?, ?)",
                (participant_id, _token_hash(token), assign_order(count, n_orders), _now()),
            )
            row = conn.execute(
                "SELECT * FROM participants WHERE pk = ?", (cur.lastrowid,)
            ).fetchone()
        return _participant(row), token

    def participant_by_token(self, token: str) -> Participant | None:
        """The participant owning session ``token``, or None."""
        with self._connect() as conn:
            row = conn.execute(
                "SELECT * FROM participants WHERE token_sha256 = ?", (_token_hash(token),)
            ).fetchone()
        return None if row is None else _participant(row)

    def refresh(self, participant: Participant) -> Participant:
        """Re-read ``participant`` (after its attention answer was stored)."""
        with self._connect() as conn:
            row = conn.execute(
                "SELECT * FROM participants WHERE pk = ?", (participant.pk,)
            ).fetchone()
        if row is None:
            raise KeyError(participant.participant_id)
        return _participant(row)

    def participants(self) -> list[Participant]:
        """Every participant, in order of arrival."""
        with self._connect() as conn:
            rows = conn.execute("SELECT * FROM participants ORDER BY pk").fetchall()
        return [_participant(r) for r in rows]

    def answers(self, participant: Participant) -> dict[str, int]:
        """The participant's own answers: video id → reported touches."""
        with self._connect() as conn:
            rows = conn.execute(
                "SELECT video_id, reported_touches FROM responses WHERE participant_pk = ?",
                (participant.pk,),
            ).fetchall()
        return {r["video_id"]: r["reported_touches"] for r in rows}

    def record_answer(self, participant: Participant, video_id: str, reported_touches: int) -> None:
        """Store one answer in its own transaction.

        Raises
        ------
        ConflictError
            The participant already answered ``video_id`` (answers are never overwritten).
        """
        try:
            with self._transaction() as conn:
                conn.execute(
                    "INSERT INTO responses (participant_pk, video_id, reported_touches, submitted)"
                    " VALUES (?, ?, ?, ?)",
                    (participant.pk, video_id, reported_touches, _now()),
                )
        except sqlite3.IntegrityError as exc:
            if "UNIQUE" in str(exc) or "PRIMARY KEY" in str(exc):
                raise ConflictError(f"video {video_id!r} is already answered") from None
            raise

    def record_attention(self, participant: Participant, answer: int, passed: bool) -> None:
        """Store the attention answer once, in its own transaction.

        Raises
        ------
        ConflictError
            The participant already answered the attention question.
        """
        with self._transaction() as conn:
            cur = conn.execute(
                "UPDATE participants SET attention_answer = ?, attention_passed = ?,"
                " attention_time = ? WHERE pk = ? AND attention_answer IS NULL",
                (answer, int(passed), _now(), participant.pk),
            )
            if cur.rowcount != 1:
                raise ConflictError("the attention question is already answered")

    def export_rows(self) -> list[ResponseRow]:
        """Every stored answer, ordered by participant arrival then submission time."""
        with self._connect() as conn:
            rows = conn.execute(
                "SELECT p.participant_id, r.video_id, r.reported_touches, p.attention_passed"
                " FROM responses r JOIN participants p ON p.pk = r.participant_pk"
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

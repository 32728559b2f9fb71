"""Migration of a study database from schema 1 (endocam's first study app) to the current one.

Schema 1 held ``participants(pk, participant_id UNIQUE, token_sha256, order_index, created,
attention_answer, attention_passed, attention_time)`` and ``responses``; it had no consent step
apart from starting, no recruitment parameters, no demographics or practice, no player events and
no admin log, and it showed each set's videos in manifest order. Schema 2
(:mod:`endocam.study.db`) adds the attempt number, the stored video order and its shuffle seed,
the recruitment parameters, the activity and completion stamps, the demographics and practice
answers, the ``events`` and ``admin_log`` tables.

A schema-1 session becomes attempt 1 with:

- ``video_order``: its order's sets in manifest order (what schema 1 showed; ``shuffle_seed`` 0),
  from the study's manifest, which the migration therefore needs;
- ``consented`` = ``created`` (schema 1 started a session only after consent);
- ``last_active``: the latest of its start, answers and attention answer;
- ``completed``: that same time if every video of its sequence and the attention question are
  answered, else empty; demographics and practice stay not given (schema 1 asked neither);
- ``recruitment``: empty.

Answers keep their session key (``pk``), so nothing in ``responses`` changes. The whole migration is
one transaction, after a copy of the untouched file is written beside it (``<name>.schema1.bak``,
through SQLite's backup API); it is entered in the admin log.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

from endocam.study.flow import VideoSequence
from endocam.study.manifest import Manifest

V1_SCHEMA_VERSION = 1
BACKUP_SUFFIX = ".schema1.bak"
# the first study app's tables, verbatim (how tests build a real schema-1 file)
V1_SCHEMA = """
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
_COLUMNS = (
    "pk, participant_id, attempt, token_sha256, order_index, shuffle_seed, video_order,"
    " recruitment, created, consented, last_active, attention_answer, attention_passed,"
    " attention_time, completed"
)


def v1_sequence(manifest: Manifest, order_index: int) -> VideoSequence:
    """The video ids per set that schema 1 showed for ``order_index``: manifest order per set.

    Raises
    ------
    ValueError
        ``order_index`` is not an order of ``manifest`` (the database is another study's).
    """
    if not 0 <= order_index < len(manifest.orders):
        raise ValueError(
            f"a schema-1 session has order {order_index}, the manifest has"
            f" {len(manifest.orders)} orders: is this the study's database?"
        )
    return tuple(tuple(v.id for v in manifest.videos_of(c)) for c in manifest.orders[order_index])


def _statements(schema: str) -> list[str]:
    return [s.strip() for s in schema.split(";") if s.strip()]


def migrate_v1(
    conn: sqlite3.Connection,
    path: Path,
    schema: str,
    sequence_for: Callable[[int], VideoSequence],
    version: int,
) -> int:
    """Migrate the open schema-1 database ``conn`` (file ``path``) to ``schema`` in place.

    Parameters
    ----------
    conn : sqlite3.Connection
        Autocommit connection (``isolation_level=None``) to ``path``, no transaction open.
    path : Path
        The database file; the backup is written beside it first.
    schema : str
        The current schema's ``CREATE ... IF NOT EXISTS`` statements (``;``-separated), whose
        ``participants`` table replaces schema 1's.
    sequence_for : callable order_index → VideoSequence
        Usually :func:`v1_sequence` bound to the study's manifest.
    version : int
        The schema version written after the migration.

    Returns
    -------
    int
        Number of sessions migrated.

    Raises
    ------
    ValueError
        A session whose order the manifest does not have (nothing is changed).
    """
    backup = path.with_name(path.name + BACKUP_SUFFIX)
    with sqlite3.connect(backup) as copy:
        conn.backup(copy)
    copy.close()
    now = datetime.now(UTC).isoformat(timespec="milliseconds")
    create = [s for s in _statements(schema) if "TABLE IF NOT EXISTS participants " not in s]
    (participants,) = [s for s in _statements(schema) if s not in create]
    conn.execute("PRAGMA foreign_keys=OFF")  # the table is rebuilt under the answers' key
    conn.execute("BEGIN IMMEDIATE")
    try:
        rows = conn.execute("SELECT * FROM participants ORDER BY pk").fetchall()
        values = []
        for row in rows:
            sequence = sequence_for(row["order_index"])
            answers = conn.execute(
                "SELECT video_id, submitted FROM responses WHERE participant_pk = ?",
                (row["pk"],),
            ).fetchall()
            stamps = [row["created"], row["attention_time"] or "", *(a[1] for a in answers)]
            last = max(stamps)
            needed = {v for s in sequence for v in s}
            done = row["attention_answer"] is not None and needed <= {a[0] for a in answers}
            values.append(
                (
                    row["pk"],
                    row["participant_id"],
                    1,
                    row["token_sha256"],
                    row["order_index"],
                    0,
                    json.dumps([list(s) for s in sequence]),
                    "{}",
                    row["created"],
                    row["created"],
                    last,
                    row["attention_answer"],
                    row["attention_passed"],
                    row["attention_time"],
                    last if done else None,
                )
            )
        conn.execute(
            participants.replace(
                "CREATE TABLE IF NOT EXISTS participants ", "CREATE TABLE participants_new "
            )
        )
        marks = ", ".join("?" * len(_COLUMNS.split(",")))
        conn.executemany(f"INSERT INTO participants_new ({_COLUMNS}) VALUES ({marks})", values)
        conn.execute("DROP TABLE participants")
        conn.execute("ALTER TABLE participants_new RENAME TO participants")
        for statement in create:
            conn.execute(statement)
        if conn.execute("PRAGMA foreign_key_check").fetchall():
            raise ValueError(f"{path}: answers of unknown sessions; not migrated")
        conn.execute(
            "INSERT INTO admin_log (time, action, participant_id, detail) VALUES (?, ?, ?, ?)",
            (
                now,
                "migrate",
                None,
                f"schema {V1_SCHEMA_VERSION} → {version}: {len(rows)} session(s);"
                f" the schema-1 file is kept as {backup.name}",
            ),
        )
        conn.execute(f"PRAGMA user_version={version}")
    except BaseException:
        conn.execute("ROLLBACK")
        conn.execute("PRAGMA foreign_keys=ON")
        raise
    conn.execute("COMMIT")
    conn.execute("PRAGMA foreign_keys=ON")
    return len(rows)

"""A real schema-1 study database (built here from schema 1's tables) migrated by the app."""

import hashlib
import sqlite3
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from endocam.study.app import SESSION_COOKIE, create_app
from endocam.study.db import SCHEMA_VERSION, StudyDB
from endocam.study.manifest import load_manifest
from endocam.study.migration import BACKUP_SUFFIX, V1_SCHEMA, v1_sequence
from study_helpers import ATTENTION_ANSWER, make_study

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

T0 = "2026-01-05T10:00:00.000+00:00"


def _at(minute: int) -> str:
    return f"2026-01-05T10:{minute:02d}:00.000+00:00"


def _sha(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def _v1_database(path: Path, study: Path) -> dict[str, list[str]]:
    """Schema-1 file: 'done' answered everything (order 0), 'half' two videos (order 1)."""
    manifest = load_manifest(study)
    done_seq = [v for s in v1_sequence(manifest, 0) for v in s]
    half_seq = [v for s in v1_sequence(manifest, 1) for v in s][:2]
    with sqlite3.connect(path) as conn:
        conn.executescript(V1_SCHEMA)
        conn.execute("PRAGMA user_version=1")
        conn.execute(
            "INSERT INTO participants (participant_id, token_sha256, order_index, created,"
            " attention_answer, attention_passed, attention_time) VALUES (?, ?, 0, ?, ?, 1, ?)",
            ("done", _sha("tok-done"), T0, ATTENTION_ANSWER, _at(5)),
        )
        conn.execute(
            "INSERT INTO participants (participant_id, token_sha256, order_index, created)"
            " VALUES (?, ?, 1, ?)",
            ("half", _sha("tok-half"), T0),
        )
        for pk, seq in ((1, done_seq), (2, half_seq)):
            conn.executemany(
                "INSERT INTO responses VALUES (?, ?, ?, ?)",
                [(pk, v, i % 5, _at(10 + i)) for i, v in enumerate(seq)],
            )
    conn.close()
    return {"done": done_seq, "half": half_seq}


def test_a_schema_1_database_is_migrated_and_its_sessions_go_on(tmp_path: Path) -> None:
    study = make_study(tmp_path, stub_videos=True)  # shuffled sets: migrated ones stay in order
    db_path = tmp_path / "v1.db"
    answered = _v1_database(db_path, study)
    with pytest.raises(ValueError, match="schema 1"):  # no manifest, no migration
        StudyDB(db_path)
    with TestClient(create_app(study, db_path, "adm")) as client:
        client.cookies.set(SESSION_COOKIE, "tok-half")
        step = client.get("/api/next").json()
        manifest = load_manifest(study)
        third = v1_sequence(manifest, 1)[0][2]  # the next video in schema 1's order
        assert (step["kind"], step["video_id"]) == ("video", third)
        r = client.post("/api/answer", json={"video_id": third, "reported_touches": 3})
        assert r.status_code == 201, r.text
    db = StudyDB(db_path)
    with sqlite3.connect(db_path) as conn:
        assert conn.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    done, half = db.participants()
    assert (done.attempt, done.order_index, done.video_order) == (1, 0, v1_sequence(manifest, 0))
    assert done.completed == _at(10 + len(answered["done"]) - 1)  # its last answer
    assert half.completed is None and half.last_active > _at(11)  # the answer given just now
    assert db.answers(done) == {v: i % 5 for i, v in enumerate(answered["done"])}
    assert db.answers(half) == {**{v: i % 5 for i, v in enumerate(answered["half"])}, third: 3}
    assert [r.participant_id for r in db.export_rows()].count("done") == len(answered["done"])
    (log,) = db.admin_log()
    assert log["action"] == "migrate" and "2 session(s)" in log["detail"]
    with sqlite3.connect(db_path.with_name(db_path.name + BACKUP_SUFFIX)) as backup:
        assert backup.execute("PRAGMA user_version").fetchone()[0] == 1
        assert backup.execute("SELECT COUNT(*) FROM responses").fetchone()[0] == 11


def _dump(path: Path) -> list[str]:
    with sqlite3.connect(path) as conn:
        lines = [*conn.iterdump(), str(conn.execute("PRAGMA user_version").fetchone())]
    conn.close()
    return lines


def test_a_schema_1_database_of_another_study_is_left_unchanged(tmp_path: Path) -> None:
    study = make_study(tmp_path, stub_videos=True)
    db_path = tmp_path / "v1.db"
    _v1_database(db_path, study)
    with sqlite3.connect(db_path) as conn:
        conn.execute("UPDATE participants SET order_index = 99 WHERE participant_id = 'half'")
    conn.close()
    before = _dump(db_path)
    with pytest.raises(ValueError, match="order 99"):
        create_app(study, db_path, None)
    assert _dump(db_path) == before  # (only the journal mode, WAL, changed in the header)

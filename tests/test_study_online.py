"""The online-study features of the web app (TestClient): consent, recruitment ids, practice,
demographics, shuffled sets, interaction log, must-watch rule, exports and codebook, admin page,
withdrawal, counterbalancing over abandoned sessions, the message catalogue, and input limits."""

import io
import json
import re
import shutil
import sqlite3
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from fastapi.testclient import TestClient

from endocam.study.app import create_app
from endocam.study.catalogue import DEFAULT_CATALOGUE, load_catalogue
from endocam.study.db import MIN_WATCHED_SHARE, StudyDB
from endocam.study.export import TABLES
from endocam.study.flow import video_sequence
from endocam.study.manifest import load_manifest
from endocam.study.responses import rows_from_csv
from endocam.study.web import MAX_BODY_BYTES, RateLimit
from study_helpers import ATTENTION_ANSWER, PRACTICE_TOUCHES, make_study

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

ADMIN = "online-admin"
AUTH = {"Authorization": f"Bearer {ADMIN}"}
CODE = "C0DE42"
SHARE_STEP = 1e-3  # s: the page reports times to the ms, so one step below the must-watch share
RETURN_URL = "https://app.prolific.com/submissions/complete?cc={code}"
PLATFORM = {"PROLIFIC_PID": "5f0aa1b2c3d4e5f6a7b8c9d0", "STUDY_ID": "st1", "SESSION_ID": "se1"}


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_study(
        tmp_path_factory.mktemp("online"),
        practice=True,
        demographics=True,
        must_watch=True,
        recruitment={"completion_code": CODE, "completion_url": RETURN_URL},
    )


@pytest.fixture
def db_path(tmp_path: Path) -> Path:
    return tmp_path / "study.db"


@pytest.fixture
def client(study: Path, db_path: Path) -> Iterator[TestClient]:
    with TestClient(create_app(study, db_path, ADMIN)) as c:
        yield c


def _watch(c: TestClient, video_id: str, rate: float = 1.0) -> None:
    for kind in ("play", "ended"):
        body = {"video_id": video_id, "kind": kind, "playback_rate": rate}
        body |= {"media_time_s": 1.0, "watched_s": 1.0}  # s: the whole of a 1 s video
        assert c.post("/api/event", json=body).status_code == 204


def _run(c: TestClient, pid: str, n_videos: int, attention: int = ATTENTION_ANSWER) -> list[str]:
    """Consent, demographics, practice, then ``n_videos`` answers (attention when due)."""
    assert c.post("/api/session", json={"consent": True, "participant_id": pid}).status_code == 201
    body = {"training_years": 4, "prior_assessment": "no"}
    assert c.post("/api/demographics", json=body).status_code == 201
    _watch(c, "_practice")
    assert c.post("/api/practice", json={"reported_touches": 2}).json()["true_touches"] == 3
    shown = []
    while len(shown) < n_videos:
        step = c.get("/api/next").json()
        if step["kind"] == "attention":
            assert c.post("/api/attention", json={"answer": attention}).status_code == 201
            continue
        _watch(c, step["video_id"])
        answer = {"video_id": step["video_id"], "reported_touches": len(shown)}
        assert c.post("/api/answer", json=answer).status_code == 201
        shown.append(step["video_id"])
    return shown


# ---- participant flow --------------------------------------------------------------------------
def test_platform_link_consent_steps_and_completion_code(client: TestClient, db_path: Path) -> None:
    page = client.get("/", params=PLATFORM | {"other": "dropped"})
    assert PLATFORM["PROLIFIC_PID"] in page.text and 'name="other"' not in page.text
    assert 'name="consent"' in page.text and "voluntary" in page.text
    form = PLATFORM | {"consent": "yes", "participant_id": "typed-id-is-ignored"}
    assert client.post("/start", data=form, follow_redirects=False).status_code == 303
    (p,) = StudyDB(db_path).participants()
    assert p.participant_id == PLATFORM["PROLIFIC_PID"]
    assert p.recruitment == PLATFORM
    # demographics: the years follow a digits-only rule; both answers optional
    page = client.get("/study")
    assert 'name="training_years"' in page.text
    r = client.post("/study/demographics", data={"training_years": "1_0"})
    assert r.status_code == 400 and 'role="alert"' in r.text
    client.post("/study/demographics", data={"training_years": "7", "prior_assessment": "yes"})
    # practice: touch definition and video, then feedback with the true count
    page = client.get("/study")
    assert client.app.state.manifest.touch_definition in page.text
    assert 'src="/videos/_practice"' in page.text
    assert client.post("/study/practice", data={"reported_touches": "5"}).status_code == 409
    _watch(client, "_practice")
    r = client.post("/study/practice", data={"reported_touches": "5"}, follow_redirects=False)
    assert r.headers["location"] == "/study/practice/feedback"
    feedback = client.get("/study/practice/feedback").text
    assert f"You counted 5; the video shows {PRACTICE_TOUCHES} touches." in feedback
    assert client.app.state.manifest.touch_definition in feedback
    # the sets, the attention question, and the end with the completion code and link
    for _ in range(10):
        step = client.get("/api/next").json()
        if step["kind"] == "attention":
            client.post("/study/attention", data={"answer": str(ATTENTION_ANSWER)})
            continue
        _watch(client, step["video_id"])
        client.post("/study/answer", data={"video_id": step["video_id"], "reported_touches": "1"})
    done = client.get("/study").text
    assert f"Your completion code is {CODE}." in done
    assert 'href="https://app.prolific.com/submissions/complete?cc=C0DE42"' in done
    p = StudyDB(db_path).refresh(p)
    assert (p.training_years, p.prior_assessment, p.practice_answer) == (7, "yes", 5)
    assert p.completed is not None and p.attention_passed is True


def test_malformed_platform_parameters_are_refused(client: TestClient, db_path: Path) -> None:
    assert client.get("/", params={"PROLIFIC_PID": "<script>"}).status_code == 400
    r = client.post("/start", data={"consent": "yes", "STUDY_ID": "a b"})
    assert r.status_code == 400 and 'role="alert"' in r.text
    assert StudyDB(db_path).participants() == []


def test_must_watch_rule_and_interaction_log(client: TestClient, db_path: Path) -> None:
    client.post("/api/session", json={"consent": True, "participant_id": "w1"})
    client.post("/api/demographics", json={})
    _watch(client, "_practice")
    client.post("/api/practice", json={"reported_touches": 3})
    vid = client.get("/api/next").json()["video_id"]
    client.get("/study")  # the page is served: 'shown'
    answer = {"video_id": vid, "reported_touches": 4}
    assert client.post("/api/answer", json=answer).status_code == 409  # not watched to the end
    skipped = [  # the end reached, but most of the video skipped, or no played time reported
        {"kind": "ended", "media_time_s": 1.0, "watched_s": 1.0 * MIN_WATCHED_SHARE - SHARE_STEP},
        {"kind": "ended", "media_time_s": 1.0},
    ]
    for e in skipped:
        assert client.post("/api/event", json={"video_id": vid} | e).status_code == 204
        refused = client.post("/api/answer", json=answer)
        assert refused.status_code == 409 and "without skipping" in refused.json()["detail"]
    events = [
        {"kind": "play", "media_time_s": 0.0, "playback_rate": 1.0, "watched_s": 0.0},
        {"kind": "ratechange", "media_time_s": 0.2, "playback_rate": 2.0, "watched_s": 0.2},
        {"kind": "seeked", "media_time_s": 0.1, "playback_rate": 2.0, "watched_s": 0.2},
        {"kind": "pause", "media_time_s": 0.5, "playback_rate": 2.0, "watched_s": 0.6},
        {"kind": "play", "media_time_s": 0.5, "playback_rate": 2.0, "watched_s": 0.6},
        {"kind": "ended", "media_time_s": 1.0, "playback_rate": 2.0, "watched_s": 1.1},
    ]
    for e in events:
        assert client.post("/api/event", json={"video_id": vid} | e).status_code == 204
    for bad in ({"kind": "hack"}, {"kind": "play", "playback_rate": 0}, {"kind": "play", "x": 1}):
        assert client.post("/api/event", json={"video_id": vid} | bad).status_code == 422
    assert client.post("/api/event", json={"video_id": "v99", "kind": "play"}).status_code == 404
    assert client.post("/api/answer", json=answer).status_code == 201
    rows = client.get("/admin/export.json", headers=AUTH).json()["responses"]
    (row,) = rows
    assert (row["n_play"], row["n_pause"], row["n_seek"], row["n_ratechange"]) == (2, 1, 1, 1)
    assert (row["max_playback_rate"], row["watched_s"], row["watched_to_end"]) == (2.0, 1.1, True)
    with sqlite3.connect(db_path) as conn:
        shown, answered = conn.execute(
            "SELECT e.received, r.submitted FROM events e JOIN responses r"
            " ON r.participant_pk = e.participant_pk AND r.video_id = e.video_id"
            " WHERE e.kind = 'shown'"
        ).fetchone()
    assert (row["shown_at"], row["answered_at"]) == (shown, answered)
    elapsed = datetime.fromisoformat(answered) - datetime.fromisoformat(shown)
    assert row["answer_time_s"] == elapsed.total_seconds() >= 0


def test_within_set_order_is_random_per_participant_and_stored(study: Path, db_path: Path) -> None:
    manifest = load_manifest(study)
    first_sets = {video_sequence(manifest, 0, seed)[0] for seed in range(20)}
    assert len(first_sets) > 1  # the seed changes the order ...
    assert all(sorted(s) == ["v01", "v02", "v03"] for s in first_sets)  # ... within the set
    with TestClient(create_app(study, db_path, ADMIN)) as c:
        shown = _run(c, "s1", 9)
    (p,) = StudyDB(db_path).participants()
    assert tuple(shown) == tuple(v for s in p.video_order for v in s)
    assert p.video_order == video_sequence(manifest, p.order_index, p.shuffle_seed)
    rows = {r["video_id"]: r for r in c.get("/admin/export.json", headers=AUTH).json()["responses"]}
    assert [rows[v]["position"] for v in shown] == list(range(1, 10))
    assert [rows[v]["set_number"] for v in shown] == [1, 1, 1, 2, 2, 2, 3, 3, 3]
    assert [rows[v]["position_in_set"] for v in shown] == [1, 2, 3] * 3


# ---- exports and codebook -----------------------------------------------------------------------
def _codebook_columns(text: str) -> dict[str, list[str]]:
    sections = re.split(r"^## ", text, flags=re.M)[1:]
    return {
        s.split("\n", 1)[0].strip(): re.findall(r"^\| `([a-z_0-9]+)` \|", s, flags=re.M)
        for s in sections
    }


def test_exports_match_the_database_and_the_codebook(client: TestClient, db_path: Path) -> None:
    app = client.app
    with TestClient(app) as a, TestClient(app) as b, TestClient(app) as c:
        _run(a, "exp-a", 9)
        _run(b, "exp-b", 4)
        _run(c, "exp-a", 2)  # a second attempt of the same id
    auth = {"Authorization": f"Bearer {ADMIN}"}
    doc = client.get("/admin/export.json", headers=auth).json()
    codebook = client.get("/admin/codebook.md", headers=auth).text
    described = _codebook_columns(codebook)
    assert set(described) == set(TABLES)
    for table in TABLES:
        csv_text = client.get(f"/admin/export/{table}.csv", headers=auth).text
        header = csv_text.splitlines()[0].split(",")
        assert header == described[table]  # every exported column described, and vice versa
        parquet = pq.read_table(
            io.BytesIO(client.get(f"/admin/export/{table}.parquet", headers=auth).content)
        )
        assert parquet.column_names == header
        assert parquet.to_pylist() == doc[table]
        assert len(csv_text.splitlines()) == len(doc[table]) + 1
    with sqlite3.connect(db_path) as conn:
        stored = set(
            conn.execute(
                "SELECT p.participant_id, p.attempt, r.video_id, r.reported_touches, r.submitted"
                " FROM responses r JOIN participants p ON p.pk = r.participant_pk"
            )
        )
        n_events = conn.execute("SELECT COUNT(*) FROM events").fetchone()[0]
    exported = {
        (r["participant_id"], r["attempt"], r["video_id"], r["reported_touches"], r["answered_at"])
        for r in doc["responses"]
    }
    assert exported == stored and len(stored) == 15
    # the responses export is what `study analyze --responses` reads: first attempts only
    analysed = rows_from_csv(client.get("/admin/export/responses.csv", headers=auth).text)
    assert sorted(analysed, key=str) == sorted(StudyDB(db_path).export_rows(), key=str)
    assert len(analysed) == 13
    assert len(doc["events"]) == n_events
    manifest = client.app.state.manifest
    for r in doc["responses"]:
        video = manifest.video(r["video_id"])
        assert (r["true_touches"], r["condition"]) == (video.true_touches, video.condition)
        assert r["abs_error"] == abs(r["reported_touches"] - video.true_touches)
        assert r["in_analysis"] == (r["attempt"] == 1)
    people = {(p["participant_id"], p["attempt"]): p for p in doc["participants"]}
    assert people[("exp-a", 1)]["status"] == "completed"
    assert people[("exp-b", 1)]["status"] == "active"
    assert people[("exp-b", 1)]["n_answered"] == 4
    assert people[("exp-a", 1)]["training_years"] == 4


# ---- admin, withdrawal, counterbalancing ------------------------------------------------------
def test_admin_page_needs_the_token_and_withdraw_is_logged(
    client: TestClient, study: Path, db_path: Path
) -> None:
    with TestClient(client.app) as a, TestClient(client.app) as b:
        _run(a, "keep", 9)
        _run(b, "leave", 3)
    assert client.get("/admin").status_code == 401
    assert client.post("/admin/login", data={"token": "wrong"}).status_code == 401
    page = client.post("/admin/login", data={"token": ADMIN})  # then the cookie, no token
    assert page.status_code == 200
    assert re.search(
        r"<td>0</td><td>fixed &gt; centering &gt; orientation</td>"
        r"<td>0</td><td>1</td>",
        page.text,
    )  # order 0: 0 active, 1 completed
    before = StudyDB(db_path).export_rows()
    with TestClient(client.app) as stranger:  # no admin cookie
        bad = stranger.post("/admin/withdraw", data={"token": ADMIN, "participant_id": "leave"})
    assert bad.status_code == 401 and StudyDB(db_path).export_rows() == before
    r = client.post("/admin/withdraw", data={"participant_id": "leave"})
    assert r.status_code == 200 and "withdrew leave: 3 answer(s) removed" in r.text
    assert {x.participant_id for x in StudyDB(db_path).export_rows()} == {"keep"}
    (entry,) = StudyDB(db_path).admin_log()
    assert (entry["action"], entry["participant_id"]) == ("withdraw", "leave")
    doc = client.get("/admin/export.json").json()
    assert all(r["participant_id"] == "keep" for r in doc["responses"] + doc["events"])
    assert b.get("/api/next").status_code == 401  # the withdrawn session cannot continue
    r = client.post("/admin/withdraw", data={"participant_id": "leave"})
    assert r.status_code == 404
    with TestClient(create_app(study, db_path, None)) as no_token:
        assert no_token.get("/admin").status_code == 403
        assert no_token.post("/admin/login", data={"token": ""}).status_code == 403


def test_counterbalancing_skips_abandoned_and_withdrawn_sessions(tmp_path: Path) -> None:
    db = StudyDB(tmp_path / "c.db")
    for k in range(6):
        db.create_participant(f"c{k}", 6)
    idle = (datetime.now(UTC) - timedelta(hours=3)).isoformat(timespec="milliseconds")
    with sqlite3.connect(tmp_path / "c.db") as conn:
        conn.execute("UPDATE participants SET last_active = ? WHERE order_index IN (1, 4)", (idle,))
        # an old but completed session still counts
        conn.execute("UPDATE participants SET completed = ? WHERE order_index = 4", (idle,))
    db.withdraw("c3")
    abandon_after_s = 2 * 3600.0
    orders = [
        db.create_participant(f"n{k}", 6, abandon_after_s=abandon_after_s)[0].order_index
        for k in range(3)
    ]
    assert orders == [1, 3, 0]
    statuses = {
        p.participant_id: p.status(datetime.now(UTC), abandon_after_s).value
        for p in db.participants()
    }
    assert (statuses["c1"], statuses["c3"], statuses["c4"]) == (
        "abandoned",
        "withdrawn",
        "completed",
    )


# ---- message catalogue --------------------------------------------------------------------------
def test_a_replacement_catalogue_changes_every_participant_text(
    study: Path, tmp_path: Path
) -> None:
    texts = json.loads(DEFAULT_CATALOGUE.read_text(encoding="utf-8"))
    swapped = {k: ("xx" if k == "lang" else f"XX {v}") for k, v in texts.items()}
    original = study
    study = Path(shutil.copytree(original, tmp_path / "study"))  # the videos, not re-encoded
    manifest = json.loads((study / "manifest.json").read_text(encoding="utf-8"))
    manifest["messages_file"] = "messages/xx.json"
    (study / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    (study / "messages").mkdir()
    (study / "messages" / "xx.json").write_text(json.dumps(swapped), encoding="utf-8")
    with TestClient(create_app(study, tmp_path / "s.db", ADMIN)) as c:
        start = c.get("/").text
        assert '<html lang="xx">' in start
        assert f">{texts['consent_label']}<" not in start and swapped["consent_label"] in start
        c.post("/start", data={"consent": "yes"})
        assert swapped["demographics_heading"] in c.get("/study").text
    catalogue = load_catalogue(study / "messages" / "xx.json")
    assert catalogue("progress", n_answered=1, n_videos=9).startswith("XX Answered 1 of 9")
    del swapped["done_code"]
    (study / "messages" / "xx.json").write_text(json.dumps(swapped), encoding="utf-8")
    with pytest.raises(ValueError, match="missing keys \\['done_code'\\]"):
        create_app(study, tmp_path / "s.db", ADMIN)
    swapped["done_code"] = "code without its placeholder"
    (study / "messages" / "xx.json").write_text(json.dumps(swapped), encoding="utf-8")
    with pytest.raises(ValueError, match="placeholders"):
        create_app(study, tmp_path / "s.db", ADMIN)


# ---- input limits (defects) ---------------------------------------------------------------------
def test_bodies_are_capped_and_422_never_echoes_input(client: TestClient, db_path: Path) -> None:
    huge = json.dumps({"consent": True, "participant_id": "x" * (4 * MAX_BODY_BYTES)})
    r = client.post("/api/session", content=huge, headers={"content-type": "application/json"})
    assert r.status_code == 413 and len(r.content) < 200

    def chunks() -> Iterator[bytes]:  # no Content-Length: the streamed size is counted
        yield b'{"consent": true, "participant_id": "'
        for _ in range(8):
            yield b"y" * MAX_BODY_BYTES
        yield b'"}'

    r = client.post("/api/session", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 413
    marker = "SECRET-MARKER-" * 50
    r = client.post("/api/session", json={"consent": True, "participant_id": marker})
    assert r.status_code == 422 and "SECRET-MARKER" not in r.text
    assert r.json()["detail"][0]["loc"] == ["body", "participant_id"]
    assert StudyDB(db_path).participants() == []


def test_session_starts_are_rate_limited(study: Path, db_path: Path) -> None:
    limit = RateLimit(per_client=3, total=100, window_s=60.0)
    with TestClient(create_app(study, db_path, ADMIN, session_rate=limit)) as c:
        codes = [
            TestClient(c.app).post("/api/session", json={"consent": True}).status_code
            for _ in range(5)
        ]
        assert codes == [201, 201, 201, 429, 429]
        r = c.post("/start", data={"consent": "yes"})
        assert r.status_code == 429 and "wait a minute" in r.text
    assert len(StudyDB(db_path).participants()) == 3
    total = RateLimit(per_client=100, total=2, window_s=60.0)
    with TestClient(
        create_app(study, tmp := db_path.with_name("t.db"), ADMIN, session_rate=total)
    ) as c:
        codes = [c.post("/api/session", json={"consent": True}).status_code for _ in range(3)]
    assert codes == [201, 201, 429] and tmp.exists()

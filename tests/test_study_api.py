import sqlite3
import threading
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from endocam.study.app import SESSION_COOKIE, create_app
from endocam.study.catalogue import load_catalogue
from endocam.study.db import StudyDB
from endocam.study.export import export_tables
from endocam.study.flow import video_sequence
from endocam.study.manifest import load_manifest
from endocam.study.records import Status
from study_helpers import ATTENTION_ANSWER, make_study

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

ADMIN = "s3cret-admin"


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    # manifest order within the sets, so each step is known here (shuffling: test_study_online)
    return make_study(tmp_path_factory.mktemp("api"), shuffle_within_set=False)


@pytest.fixture
def db_path(tmp_path: Path) -> Path:
    return tmp_path / "study.db"


@pytest.fixture
def client(study: Path, db_path: Path) -> Iterator[TestClient]:
    with TestClient(create_app(study, db_path, ADMIN)) as c:
        yield c


def snapshot(db_path: Path) -> list[tuple]:
    with sqlite3.connect(db_path) as conn:
        participants = conn.execute("SELECT * FROM participants ORDER BY pk").fetchall()
        responses = conn.execute("SELECT * FROM responses ORDER BY 1, 2").fetchall()
    return participants + responses


def start(client: TestClient, pid: str) -> dict:
    r = client.post("/api/session", json={"consent": True, "participant_id": pid})
    assert r.status_code == 201, r.text
    return r.json()


def test_session_cookie_is_httponly_and_the_id_alone_grants_nothing(client: TestClient) -> None:
    r = client.post("/api/session", json={"consent": True, "participant_id": "alice"})
    cookie = r.headers["set-cookie"]
    assert "HttpOnly" in cookie and "samesite=strict" in cookie.lower()
    assert r.cookies[SESSION_COOKIE] != "alice"
    client.cookies.clear()
    assert client.get("/api/next").status_code == 401
    client.cookies.set(SESSION_COOKIE, "alice")
    assert client.get("/api/next").status_code == 401


@pytest.mark.parametrize(
    ("body", "status"),
    [
        ({"video_id": "v01", "reported_touches": -1}, 422),
        ({"video_id": "v01", "reported_touches": 100}, 422),
        ({"video_id": "v01", "reported_touches": "seven"}, 422),
        ({"video_id": "v01", "reported_touches": "7"}, 422),
        ({"video_id": "v01", "reported_touches": 7.5}, 422),
        ({"video_id": "v01", "reported_touches": True}, 422),
        ({"video_id": "v01"}, 422),
        ({"video_id": "v01", "reported_touches": 3, "extra": 1}, 422),
        ({"video_id": "v99", "reported_touches": 3}, 404),
        ({"video_id": "v02", "reported_touches": 3}, 409),  # not the current video
        ({"video_id": "v01", "reported_touches": 3, "participant_id": "bob"}, 403),
    ],
)
def test_bad_answers_are_refused_and_change_nothing(
    client: TestClient, db_path: Path, body: dict, status: int
) -> None:
    start(client, "bob")
    start_other = TestClient(client.app)
    start(start_other, "alice")
    body = {**body, "participant_id": "alice"} if status == 403 else body
    before = snapshot(db_path)
    r = client.post("/api/answer", json=body)
    assert r.status_code == status, r.text
    assert snapshot(db_path) == before


def test_unknown_or_missing_session_is_refused(client: TestClient, db_path: Path) -> None:
    start(client, "carol")
    before = snapshot(db_path)
    body = {"video_id": "v01", "reported_touches": 3}
    client.cookies.set(SESSION_COOKIE, "forged")
    assert client.post("/api/answer", json=body).status_code == 401
    client.cookies.clear()
    assert client.post("/api/answer", json=body).status_code == 401
    assert client.post("/api/attention", json={"answer": 4}).status_code == 401
    assert snapshot(db_path) == before


def test_duplicate_answer_is_refused_and_the_first_kept(client: TestClient, db_path: Path) -> None:
    start(client, "dave")
    assert (
        client.post("/api/answer", json={"video_id": "v01", "reported_touches": 5}).status_code
        == 201
    )
    before = snapshot(db_path)
    r = client.post("/api/answer", json={"video_id": "v01", "reported_touches": 9})
    assert r.status_code == 409
    assert snapshot(db_path) == before
    assert client.get("/api/me").json()["answers"] == {"v01": 5}


def test_participants_cannot_see_or_change_each_other(client: TestClient, db_path: Path) -> None:
    start(client, "erin")
    other = TestClient(client.app)
    start(other, "frank")  # order 1: starts with v04
    assert (
        client.post("/api/answer", json={"video_id": "v01", "reported_touches": 2}).status_code
        == 201
    )
    assert other.get("/api/me").json() == {
        "participant_id": "frank",
        "answers": {},
        "attention_answered": False,
    }
    before = snapshot(db_path)
    # frank cannot answer for erin, nor answer erin's current video out of his own order
    body = {"video_id": "v02", "reported_touches": 1, "participant_id": "erin"}
    assert other.post("/api/answer", json=body).status_code == 403
    assert (
        other.post("/api/answer", json={"video_id": "v01", "reported_touches": 1}).status_code
        == 409
    )
    assert snapshot(db_path) == before


def test_ids_are_checked_but_a_taken_id_is_not_revealed(client: TestClient, db_path: Path) -> None:
    first = client.post("/api/session", json={"consent": True, "participant_id": "gina"})
    before = snapshot(db_path)
    for bad in ("../x", "", "a" * 65):
        body = {"consent": True, "participant_id": bad}
        assert client.post("/api/session", json=body).status_code == 422
    assert client.post("/api/session", json={"participant_id": "ok"}).status_code == 422  # consent
    assert snapshot(db_path) == before
    # a taken id is answered exactly like a new one: no existence oracle
    again = TestClient(client.app).post(
        "/api/session", json={"consent": True, "participant_id": "gina"}
    )
    fresh = TestClient(client.app).post(
        "/api/session", json={"consent": True, "participant_id": "gina2"}
    )
    assert first.status_code == again.status_code == fresh.status_code == 201
    assert again.json()["participant_id"] == "gina"
    assert again.json()["next"].keys() == fresh.json()["next"].keys()
    attempts = [(p.participant_id, p.attempt) for p in StudyDB(db_path).participants()]
    assert attempts == [("gina", 1), ("gina", 2), ("gina2", 1)]
    generated = client.post("/api/session", json={"consent": True}).json()["participant_id"]
    assert generated.startswith("p-")


def test_only_the_first_attempt_of_an_id_is_analysed(study: Path, db_path: Path) -> None:
    with TestClient(create_app(study, db_path, ADMIN)) as one, TestClient(one.app) as two:
        start(one, "hal")
        start(two, "hal")
        for c, n in ((one, 1), (two, 5)):
            vid = c.get("/api/next").json()["video_id"]
            assert c.post("/api/answer", json={"video_id": vid, "reported_touches": n}).status_code
        assert [r.reported_touches for r in StudyDB(db_path).export_rows()] == [1]


def test_full_run_round_robin_and_restart(study: Path, db_path: Path) -> None:
    expected_orders = {}
    with TestClient(create_app(study, db_path, ADMIN)) as c:
        for k in range(7):
            TestClient(c.app).post(
                "/api/session", json={"consent": True, "participant_id": f"rr{k}"}
            )
            expected_orders[f"rr{k}"] = k % 6
        start(c, "henry")  # 8th participant → order 1 (centering, orientation, fixed)
        seen = []
        for _ in range(5):
            step = c.get("/api/next").json()
            seen.append(step["video_id"])
            c.post("/api/answer", json={"video_id": step["video_id"], "reported_touches": 1})
        cookie = c.cookies[SESSION_COOKIE]
    assert seen == ["v04", "v05", "v06", "v07", "v08"]
    # a new server process on the same file: everything is still there
    with TestClient(create_app(study, db_path, ADMIN)) as c:
        c.cookies.set(SESSION_COOKIE, cookie)
        step = c.get("/api/next").json()
        assert (step["video_id"], step["n_answered"]) == ("v09", 5)
        assert c.post("/api/attention", json={"answer": 4}).status_code == 409  # not yet
        c.post("/api/answer", json={"video_id": "v09", "reported_touches": 1})
        assert c.get("/api/next").json()["kind"] == "attention"
        assert c.post("/api/attention", json={"answer": 3}).status_code == 201
        assert c.post("/api/attention", json={"answer": ATTENTION_ANSWER}).status_code == 409
        for _ in range(3):
            vid = c.get("/api/next").json()["video_id"]
            assert (
                c.post("/api/answer", json={"video_id": vid, "reported_touches": 2}).status_code
                == 201
            )
        assert c.get("/api/next").json()["kind"] == "done"
    orders = {p.participant_id: p.order_index for p in StudyDB(db_path).participants()}
    assert {k: orders[k] for k in expected_orders} == expected_orders
    assert orders["henry"] == 1
    rows = [r for r in StudyDB(db_path).export_rows() if r.participant_id == "henry"]
    assert len(rows) == 9 and all(r.attention_passed is False for r in rows)


def test_admin_export_needs_the_token(client: TestClient, study: Path, db_path: Path) -> None:
    start(client, "ivy")
    client.post("/api/answer", json={"video_id": "v01", "reported_touches": 6})
    assert client.get("/admin/export.csv").status_code == 401
    assert client.get("/admin/export.csv?token=wrong").status_code == 401
    assert (
        client.get("/admin/export.json", headers={"Authorization": "Bearer nope"}).status_code
        == 401
    )
    r = client.get("/admin/export.csv", headers={"Authorization": f"Bearer {ADMIN}"})
    assert r.status_code == 200
    header, row = (line.split(",") for line in r.text.splitlines())
    cells = dict(zip(header, row, strict=True))
    assert {k: cells[k] for k in ("participant_id", "video_id", "reported_touches")} == {
        "participant_id": "ivy",
        "video_id": "v01",
        "reported_touches": "6",
    }
    assert cells["attention_passed"] == ""
    auth = {"Authorization": f"Bearer {ADMIN}"}
    doc = client.get("/admin/export.json", headers=auth).json()
    assert [(r["participant_id"], r["reported_touches"]) for r in doc["responses"]] == [("ivy", 6)]
    assert doc["responses"][0]["attention_passed"] is None
    with TestClient(create_app(study, db_path, None)) as no_token:
        assert no_token.get("/admin/export.csv").status_code == 403
        assert (
            no_token.get("/admin/export.json", headers={"Authorization": "Bearer x"}).status_code
            == 403
        )


def test_videos_only_from_the_manifest(client: TestClient, study: Path) -> None:
    assert client.get("/videos/v01").status_code == 401  # no session
    start(client, "jack")
    r = client.get("/videos/v01")
    assert r.status_code == 200 and r.content == (study / "videos" / "v01.mp4").read_bytes()
    assert client.get("/videos/v99").status_code == 404
    assert client.get("/videos/..%2Fmanifest.json").status_code == 404
    assert client.get("/videos/manifest.json").status_code == 404


def test_html_forms_validate_server_side(client: TestClient, db_path: Path) -> None:
    r = client.post("/start", data={"participant_id": "kim"}, follow_redirects=False)
    assert r.status_code == 400 and 'role="alert"' in r.text  # no consent, no session
    assert snapshot(db_path) == []
    data = {"participant_id": "kim", "consent": "yes"}
    r = client.post("/start", data=data, follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/study"
    page = client.get("/study")
    assert 'name="video_id" value="v01"' in page.text
    assert 'min="0" max="99"' in page.text and "required" in page.text
    before = snapshot(db_path)
    # the form follows the JSON API's rule: digits only (no '_', sign, decimal point or
    # non-ASCII digits), 0..99
    for bad in ["-1", "abc", "100", "", "3.5", "1_0", "3.0", "+5", "٣", "1e1", " "]:
        r = client.post("/study/answer", data={"video_id": "v01", "reported_touches": bad})
        assert r.status_code == 400 and 'role="alert"' in r.text
    assert snapshot(db_path) == before
    r = client.post(
        "/study/answer", data={"video_id": "v01", "reported_touches": "7"}, follow_redirects=False
    )
    assert r.status_code == 303
    r = client.post("/study/answer", data={"video_id": "v01", "reported_touches": "8"})
    assert r.status_code == 409
    assert client.get("/api/me").json()["answers"] == {"v01": 7}


def test_concurrent_starts_get_balanced_orders(tmp_path: Path) -> None:
    db = StudyDB(tmp_path / "c.db")
    results: list[int] = []
    lock = threading.Lock()

    def worker(k: int) -> None:
        participant, _ = db.create_participant(f"c{k}", 6)
        with lock:
            results.append(participant.order_index)

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(18)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(results) == sorted(list(range(6)) * 3)
    with sqlite3.connect(tmp_path / "c.db") as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


# ---- issue 24 §4 -------------------------------------------------------------------------------
def _answer_all(c: TestClient, last: bool = True) -> dict:
    """Answer every step (attention rightly); without ``last`` stop before the last answer."""
    while (step := c.get("/api/next").json())["kind"] != "done":
        if step["kind"] == "attention":
            assert c.post("/api/attention", json={"answer": ATTENTION_ANSWER}).status_code == 201
            continue
        if not last and step["n_answered"] == step["n_videos"] - 1:
            return step
        body = {"video_id": step["video_id"], "reported_touches": 1}
        assert c.post("/api/answer", json=body).status_code == 201
    return step


def test_the_last_answer_and_the_completed_stamp_are_one_transaction(
    study: Path, db_path: Path
) -> None:
    app = create_app(study, db_path, ADMIN)
    with TestClient(app, raise_server_exceptions=False) as c:
        start(c, "kill9")
        step = _answer_all(c, last=False)
        # a crash while stamping: the answer that completes the session must not stay without it
        with sqlite3.connect(db_path) as conn:
            conn.execute(
                "CREATE TRIGGER crash BEFORE UPDATE OF completed ON participants"
                " BEGIN SELECT RAISE(ABORT, 'simulated crash'); END"
            )
        body = {"video_id": step["video_id"], "reported_touches": 1}
        assert c.post("/api/answer", json=body).status_code == 500
        (p,) = StudyDB(db_path).participants()
        assert (len(StudyDB(db_path).answers(p)), p.completed) == (8, None)  # both or neither
        with sqlite3.connect(db_path) as conn:
            conn.execute("DROP TRIGGER crash")
        assert c.post("/api/answer", json=body).status_code == 201
    (p,) = StudyDB(db_path).participants()
    assert len(StudyDB(db_path).answers(p)) == 9 and p.completed is not None


def test_a_session_answered_but_never_stamped_is_repaired_at_start(
    study: Path, db_path: Path
) -> None:
    with TestClient(create_app(study, db_path, ADMIN)) as c:
        start(c, "crashed")
        _answer_all(c)
    # what an older endocam killed between the last answer and the stamp left, 3 h ago
    idle = (datetime.now(UTC) - timedelta(hours=3)).isoformat(timespec="milliseconds")
    with sqlite3.connect(db_path) as conn:
        conn.execute(
            "UPDATE participants SET completed = NULL, last_active = ?1, attention_time = ?1",
            (idle,),
        )
        conn.execute("UPDATE responses SET submitted = ?", (idle,))
    (p,) = StudyDB(db_path).participants()
    assert p.status(datetime.now(UTC)) == Status.ABANDONED  # its order would be given again
    with TestClient(create_app(study, db_path, ADMIN)) as c:
        start(c, "next")
    crashed, following = StudyDB(db_path).participants()
    assert crashed.status(datetime.now(UTC)) == Status.COMPLETED and crashed.completed == idle
    assert (crashed.order_index, following.order_index) == (0, 1)
    (entry,) = StudyDB(db_path).admin_log()
    assert (entry["action"], entry["participant_id"]) == ("repair", "crashed")


def test_admin_signs_in_once_and_the_token_never_travels_in_a_url(
    client: TestClient, study: Path, db_path: Path
) -> None:
    start(TestClient(client.app), "leaver")
    # a token in the URL is not accepted (it would reach access logs and browser history)
    for url in (f"/admin?token={ADMIN}", f"/admin/export.json?token={ADMIN}"):
        assert client.get(url).status_code == 401
    page = client.get("/admin")
    assert page.status_code == 401 and 'action="/admin/login"' in page.text
    wrong = client.post("/admin/login", data={"token": "wrong"}, follow_redirects=False)
    assert wrong.status_code == 401 and "set-cookie" not in wrong.headers
    r = client.post("/admin/login", data={"token": ADMIN}, follow_redirects=False)
    assert (r.status_code, r.headers["location"]) == (303, "/admin")
    cookie = r.headers["set-cookie"]
    assert "HttpOnly" in cookie and "samesite=strict" in cookie.lower() and "Path=/admin" in cookie
    assert "Secure" not in cookie  # plain http unless told (see the next test)
    assert ADMIN not in cookie and ADMIN not in r.headers["location"]
    page = client.get("/admin")
    assert page.status_code == 200 and ADMIN not in page.text and "token=" not in page.text
    assert client.get("/admin/export/responses.csv").status_code == 200  # the links work
    r = client.post("/admin/withdraw", data={"participant_id": "leaver"}, follow_redirects=False)
    assert r.status_code == 303 and ADMIN not in r.headers["location"]
    assert "token" not in r.headers["location"]
    client.post("/admin/logout")
    assert client.get("/admin/export.json").status_code == 401
    # scripts keep the header
    bearer = {"Authorization": f"Bearer {ADMIN}"}
    assert client.get("/admin/export.json", headers=bearer).status_code == 200


def test_cookies_are_secure_when_served_over_https(study: Path, db_path: Path) -> None:
    with TestClient(create_app(study, db_path, ADMIN, secure_cookies=True)) as c:
        participant = c.post("/api/session", json={"consent": True, "participant_id": "tls"})
        admin = c.post("/admin/login", data={"token": ADMIN}, follow_redirects=False)
    for r in (participant, admin):
        assert "Secure" in r.headers["set-cookie"]


def test_a_withdrawn_id_cannot_start_again(client: TestClient, db_path: Path) -> None:
    start(client, "gone")
    client.post("/api/answer", json={"video_id": "v01", "reported_touches": 3})
    StudyDB(db_path).withdraw("gone")
    before = snapshot(db_path)
    with TestClient(client.app) as again:
        r = again.post("/api/session", json={"consent": True, "participant_id": "gone"})
        assert r.status_code == 403 and "withdrawn" in r.json()["detail"]
        form = {"participant_id": "gone", "consent": "yes"}
        page = again.post("/start", data=form, follow_redirects=False)
        assert page.status_code == 403 and load_catalogue()("error_withdrawn") in page.text
        assert SESSION_COOKIE not in again.cookies
    assert snapshot(db_path) == before


def test_a_later_attempt_of_a_withdrawn_id_is_not_analysed(study: Path, db_path: Path) -> None:
    db = StudyDB(db_path)
    manifest = load_manifest(study)
    for pid in ("stays", "went", "went"):  # the second "went" started after the withdrawal
        participant, _ = db.create_participant(
            pid, 6, lambda order, seed: video_sequence(manifest, order, seed)
        )
        db.record_answer(participant, "v01", 2)
    with sqlite3.connect(db_path) as conn:  # what withdraw() left, then an older endocam allowed
        conn.execute("DELETE FROM responses WHERE participant_pk = 2")
        conn.execute("UPDATE participants SET withdrawn = '2024-05-02T00:00:00' WHERE pk = 2")
    assert [r.participant_id for r in db.export_rows()] == ["stays"]
    exported = export_tables(db, manifest)
    assert [(r.participant_id, r.in_analysis) for r in exported["responses"]] == [
        ("stays", True),
        ("went", False),
    ]


def test_a_404_does_not_echo_the_video_id(client: TestClient) -> None:
    start(client, "echo")
    for method, url, body in (
        ("POST", "/api/answer", {"video_id": "ZZ-echo-42", "reported_touches": 3}),
        ("POST", "/api/event", {"video_id": "ZZ-echo-42", "kind": "play"}),
        ("GET", "/videos/ZZ-echo-42", None),
    ):
        r = client.request(method, url, json=body)
        assert r.status_code == 404 and "ZZ-echo-42" not in r.text, url

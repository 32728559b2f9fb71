"""End to end in headless Debian Chromium (Playwright sync API) against a real uvicorn server.

One server, two participants: a desktop one arriving from a recruitment-platform link (consent →
demographics → practice with feedback → three sets with the attention question → completion code)
and a phone-width one typing an id. With ``ENDOCAM_STUDY_SCREENSHOTS=DIR`` the pages are saved
as PNG files in DIR (how docs/img/study-*.png are made); with
``ENDOCAM_STUDY_SCREENSHOT_VIDEOS=STUDY_DIR`` as well, the set videos are that rendered study's
(``endocam study make``), shown 20 s in, so the pictures show what participants really see.
"""

import os
import shutil
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import uvicorn
from playwright.sync_api import Browser, Page, expect, sync_playwright

from endocam.study.app import create_app
from endocam.study.db import StudyDB
from study_helpers import (
    ATTENTION_ANSWER,
    PRACTICE_TOUCHES,
    VIDEO_FPS,
    VIDEO_FRAMES,
    VIDEO_H_PX,
    VIDEO_W_PX,
    make_study,
    write_tiny_mp4,
)

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

ADMIN = "browser-admin-token"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-quic",
    "--autoplay-policy=no-user-gesture-required",
]
SERVER_START_TIMEOUT_S = 10.0  # s
MAX_TABS = 12  # Tab presses allowed to reach a field
UI_TIMEOUT_MS = 30_000  # ms, Playwright waits: a bound on a hang, not a speed check
PHONE = {"width": 390, "height": 844}  # px, CSS viewport of a typical phone
CODE = "BROWSER1"
PID = "60a1b2c3d4e5f6a7b8c9d0e1"  # Prolific-style participant id
PLATFORM_URL = f"/?PROLIFIC_PID={PID}&STUDY_ID=study42&SESSION_ID=sess7"
VIDEO_DURATION_S = VIDEO_FRAMES / VIDEO_FPS
FRAME_S = 1.0 / VIDEO_FPS  # tolerance of watched seconds: one frame interval
SHOTS = os.environ.get("ENDOCAM_STUDY_SCREENSHOTS")
SHOT_VIDEOS = os.environ.get("ENDOCAM_STUDY_SCREENSHOT_VIDEOS")  # a rendered study folder
SHOT_VIDEO_TIME_S = 20.0  # s into a rendered study video for its screenshot


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    root = tmp_path_factory.mktemp("browser")
    study = make_study(
        root,
        practice=True,
        demographics=True,
        recruitment={
            "completion_code": CODE,
            "completion_url": "https://app.prolific.com/submissions/complete?cc={code}",
        },
    )
    if SHOTS and SHOT_VIDEOS:  # real frames for the documentation's pictures
        rendered = sorted(Path(SHOT_VIDEOS).glob("videos/*.mp4"))
        assert rendered, f"no videos in {SHOT_VIDEOS}"
        fixtures = sorted(p for p in (study / "videos").glob("*.mp4") if p.stem != "practice")
        for i, path in enumerate(fixtures):
            shutil.copyfile(rendered[i % len(rendered)], path)
    db_path = root / "study.db"
    port = _free_port()
    # the last page goes back to the platform after 5 s: the checks on it take far less
    with _running(create_app(study, db_path, ADMIN), port):
        yield f"http://127.0.0.1:{port}", db_path


@contextmanager
def _running(app: Any, port: int) -> Iterator[None]:
    """Serve ``app`` with uvicorn on 127.0.0.1:``port`` in a thread while the block runs."""
    config = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning")
    srv = uvicorn.Server(config)
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + SERVER_START_TIMEOUT_S
    while not srv.started:
        assert time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.05)
    try:
        yield
    finally:
        srv.should_exit = True
        thread.join(timeout=SERVER_START_TIMEOUT_S)


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
        yield b
        b.close()


def _shot(page: Page, name: str) -> None:
    if SHOTS:
        if page.locator("#study_video").count():  # the first frame, not the loading spinner
            page.wait_for_function("() => study_video.readyState >= 2")
            if SHOT_VIDEOS and page.evaluate("study_video.duration") > SHOT_VIDEO_TIME_S:
                page.evaluate(f"study_video.currentTime = {SHOT_VIDEO_TIME_S}")
                page.wait_for_function("() => !study_video.seeking && study_video.readyState >= 2")
        page.screenshot(path=str(Path(SHOTS) / f"study-{name}.png"), full_page=True)


def _tab_to(page: Page, element_id: str) -> None:
    """Press Tab until the element has the keyboard focus (the page's focus order)."""
    for _ in range(MAX_TABS):
        if page.evaluate("document.activeElement && document.activeElement.id") == element_id:
            return
        page.keyboard.press("Tab")
    pytest.fail(f"#{element_id} not reachable with Tab")


def _type_and_submit(page: Page, element_id: str, value: str) -> None:
    _tab_to(page, element_id)
    page.keyboard.type(value)
    with page.expect_navigation():
        page.keyboard.press("Enter")


def _consent(page: Page) -> None:
    _tab_to(page, "consent")
    page.keyboard.press("Space")
    page.keyboard.press("Tab")
    with page.expect_navigation():
        page.keyboard.press("Enter")


def _value(video_id: str) -> int:
    return (int(video_id[1:]) * 3) % 10


def test_platform_participant_completes_the_study(
    server: tuple[str, Path], browser: Browser
) -> None:
    base, db_path = server
    page = browser.new_context(viewport={"width": 1000, "height": 900}).new_page()
    page.set_default_timeout(UI_TIMEOUT_MS)
    page.goto(base + PLATFORM_URL)
    expect(page.get_by_role("heading", level=1)).to_have_text("Information about this study")
    expect(page.locator("#platform_id")).to_contain_text(PID)
    _shot(page, "consent")
    _consent(page)

    expect(page.get_by_role("heading", level=1)).to_have_text("About you")
    page.get_by_label("Yes").check()
    _shot(page, "demographics")
    _type_and_submit(page, "training_years", "5")

    expect(page.get_by_role("heading", level=1)).to_have_text("Practice video")
    page.wait_for_function("() => study_video.readyState >= 1")
    assert page.evaluate("[study_video.videoWidth, study_video.videoHeight]") == [
        VIDEO_W_PX,
        VIDEO_H_PX,
    ]
    page.evaluate("study_video.play()")
    page.wait_for_function("() => study_video.ended")
    _shot(page, "practice")
    _type_and_submit(page, "reported_touches", str(PRACTICE_TOUCHES))
    expect(page.locator("#feedback")).to_contain_text(
        f"You counted {PRACTICE_TOUCHES}; the video shows {PRACTICE_TOUCHES} touches."
    )
    _shot(page, "feedback")
    with page.expect_navigation():
        page.locator("#continue").click()

    answered = []
    while page.locator("input[name=video_id]").count() or page.locator("#attention_answer").count():
        if page.locator("#attention_answer").count():
            _shot(page, "attention")
            _type_and_submit(page, "attention_answer", str(ATTENTION_ANSWER))
            continue
        video_id = page.locator("input[name=video_id]").input_value()
        if not answered:
            expect(page.get_by_role("heading", level=1)).to_have_text("Set 1 of 3: video 1 of 3")
            _shot(page, "video")
        _type_and_submit(page, "reported_touches", str(_value(video_id)))
        answered.append(video_id)
    expect(page.get_by_role("heading", level=1)).to_have_text("Thank you")
    expect(page.locator("#completion_code")).to_contain_text(CODE)
    expect(page.locator("#return_link")).to_have_attribute(
        "href", f"https://app.prolific.com/submissions/complete?cc={CODE}"
    )
    _shot(page, "done")
    page.goto(f"{base}/admin")  # sign in once with the token; then a cookie, no token in URLs
    expect(page.get_by_role("heading", level=1)).to_have_text("Study admin: sign in")
    page.get_by_label("Admin token").fill(ADMIN)
    with page.expect_navigation():
        page.get_by_role("button", name="Sign in").click()
    assert page.url == f"{base}/admin"
    expect(page.get_by_role("heading", level=1)).to_have_text("Study admin")
    _shot(page, "admin")

    db = StudyDB(db_path)
    (p,) = [p for p in db.participants() if p.participant_id == PID]
    assert p.recruitment == {"PROLIFIC_PID": PID, "STUDY_ID": "study42", "SESSION_ID": "sess7"}
    assert (p.training_years, p.prior_assessment, p.practice_answer) == (5, "yes", 3)
    assert answered == [v for s in p.video_order for v in s] and p.completed is not None
    assert db.answers(p) == {v: _value(v) for v in answered}
    practice = [e for e in db.events() if e["video_id"] == "_practice"]
    assert practice[0]["kind"] == "shown" and {"play", "pause"} < {e["kind"] for e in practice}
    (ended,) = [e for e in practice if e["kind"] == "ended"]
    assert ended["watched_s"] == pytest.approx(VIDEO_DURATION_S, abs=FRAME_S)
    assert ended["media_time_s"] == pytest.approx(VIDEO_DURATION_S, abs=FRAME_S)


def test_phone_width_participant_with_a_typed_id(
    server: tuple[str, Path], browser: Browser
) -> None:
    base, db_path = server
    context = browser.new_context(viewport=PHONE, is_mobile=True, has_touch=True)
    page = context.new_page()
    page.set_default_timeout(UI_TIMEOUT_MS)
    page.goto(base + "/")
    _tab_to(page, "participant_id")
    page.keyboard.type("phone-1")
    page.keyboard.press("Enter")  # no consent yet: the browser keeps the form
    assert page.evaluate("document.getElementById('consent').validity.valueMissing")
    assert "phone-1" not in {p.participant_id for p in StudyDB(db_path).participants()}
    _consent(page)
    with page.expect_navigation():
        page.get_by_role("button").click()  # demographics left empty
    _type_and_submit(page, "reported_touches", "2")  # practice
    with page.expect_navigation():
        page.locator("#continue").click()
    expect(page.get_by_role("heading", level=1)).to_have_text("Set 1 of 3: video 1 of 3")
    fits = "document.documentElement.scrollWidth <= window.innerWidth"
    assert page.evaluate(fits), "the page scrolls sideways at phone width"
    box = page.locator("#study_video").bounding_box()
    assert box is not None and box["width"] <= PHONE["width"]
    _shot(page, "phone")
    first = page.locator("input[name=video_id]").input_value()
    # a value typed past the browser's own check is refused by the server
    page.evaluate("document.getElementById('reported_touches').removeAttribute('max')")
    _type_and_submit(page, "reported_touches", "150")
    expect(page.get_by_role("alert")).to_contain_text("0 to 99")
    _type_and_submit(page, "reported_touches", "4")
    page.reload()  # a reload resumes at the next step
    expect(page.get_by_role("heading", level=1)).to_have_text("Set 1 of 3: video 2 of 3")
    sessions = StudyDB(db_path).participants()
    assert sessions[-1].participant_id == "phone-1"
    assert StudyDB(db_path).answers(sessions[-1]) == {first: 4}
    assert sessions[-1].order_index == len(sessions) - 1  # round-robin over the orders


REDIRECT_AFTER_S = 0.2  # s, the must-watch study's last page before it goes back
SKIP_TO_END_S = 0.1  # s of the 1 s video left when the participant skips ahead
SETTLE_MS = 200  # ms for the page to act on the server's reply to its "ended" event


def test_must_watch_in_chromium_then_the_automatic_redirect(
    tmp_path: Path, browser: Browser
) -> None:
    port = _free_port()
    base = f"http://127.0.0.1:{port}"
    back = f"{base}/static/style.css?cc={CODE}"  # stands for the platform's completion page
    study = make_study(  # only the video played here is a real one (v01, shown first)
        tmp_path,
        stub_videos=True,
        shuffle_within_set=False,
        must_watch=True,
        recruitment={
            "completion_code": CODE,
            "completion_url": f"{base}/static/style.css?cc={{code}}",
        },
    )
    write_tiny_mp4(study / "videos" / "v01.mp4", 0)
    app = create_app(study, tmp_path / "w.db", None, redirect_after_s=REDIRECT_AFTER_S)
    with _running(app, port):
        page = browser.new_context().new_page()
        page.set_default_timeout(UI_TIMEOUT_MS)
        page.goto(base + "/")
        _consent(page)
        expect(page.locator("#answer_button")).to_be_disabled()  # study.js: not watched yet
        page.evaluate("answer_button.disabled = false")  # past the page's rule: the server's
        _type_and_submit(page, "reported_touches", "1")
        expect(page.get_by_role("alert")).to_contain_text("without skipping ahead")
        expect(page.locator("#answer_button")).to_be_disabled()
        with page.expect_response("**/api/event") as logged:  # skipped ahead to the last frames
            page.evaluate(
                "study_video.addEventListener('ended', () => { window.ended = 1 }, {once: true});"
                f"study_video.currentTime = study_video.duration - {SKIP_TO_END_S};"
                "study_video.play()"
            )
        page.wait_for_function("window.ended === 1")
        page.wait_for_timeout(SETTLE_MS)  # the "ended" event's reply would enable the button
        expect(page.locator("#answer_button")).to_be_disabled()  # ended, most of it unseen
        assert logged.value.ok
        page.evaluate("study_video.currentTime = 0; study_video.playbackRate = 8")
        page.evaluate("study_video.play()")  # 1 s video, faster, from the start
        expect(page.locator("#answer_button")).to_be_enabled()  # after the logged "ended"
        _type_and_submit(page, "reported_touches", "1")
        expect(page.get_by_role("heading", level=1)).to_have_text("Set 1 of 3: video 2 of 3")
        api = page.request  # the rest through the API with the page's session cookie
        while (step := api.get(f"{base}/api/next").json())["kind"] != "done":
            if step["kind"] == "attention":
                api.post(f"{base}/api/attention", data={"answer": ATTENTION_ANSWER})
                continue
            vid = step["video_id"]
            whole = {"kind": "ended", "media_time_s": 1.0, "watched_s": 1.0}  # s, a 1 s video
            api.post(f"{base}/api/event", data=whole | {"video_id": vid})
            assert api.post(f"{base}/api/answer", data={"video_id": vid, "reported_touches": 2}).ok
        with page.expect_navigation(url=back):  # the done page sends the browser back
            page.goto(base + "/study")

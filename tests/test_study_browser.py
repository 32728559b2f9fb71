"""End to end in headless Debian Chromium (Playwright sync API) against a real uvicorn server."""

import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import uvicorn
from playwright.sync_api import Browser, Page, expect, sync_playwright

from endocam.study.app import create_app
from endocam.study.db import StudyDB
from study_helpers import ATTENTION_ANSWER, VIDEO_H_PX, VIDEO_W_PX, make_study

ADMIN = "browser-admin-token"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-quic",
]
SERVER_START_TIMEOUT_S = 10.0  # s
MAX_TABS = 12  # Tab presses allowed to reach a field
UI_TIMEOUT_MS = 5000  # ms, Playwright waits
# expected presentation: participant 0 gets order 0, participant 1 gets order 1
ORDER_0 = ["v01", "v02", "v03", "v04", "v05", "v06", "attention", "v07", "v08", "v09"]
ORDER_1 = ["v04", "v05", "v06", "v07", "v08", "v09", "attention", "v01", "v02", "v03"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    root = tmp_path_factory.mktemp("browser")
    study, db_path = make_study(root), root / "study.db"
    port = _free_port()
    config = uvicorn.Config(
        create_app(study, db_path, ADMIN), host="127.0.0.1", port=port, log_level="warning"
    )
    srv = uvicorn.Server(config)
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + SERVER_START_TIMEOUT_S
    while not srv.started:
        assert time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}", db_path
    srv.should_exit = True
    thread.join(timeout=SERVER_START_TIMEOUT_S)


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
        yield b
        b.close()


def _tab_to(page: Page, element_id: str) -> None:
    """Press Tab until the element has the keyboard focus (the page's focus order)."""
    for _ in range(MAX_TABS):
        if page.evaluate("document.activeElement && document.activeElement.id") == element_id:
            return
        page.keyboard.press("Tab")
    pytest.fail(f"#{element_id} not reachable with Tab")


def _answer_current(page: Page, expected: str, value: int) -> None:
    """Answer the current step with the keyboard only; checks it is the expected one."""
    if expected == "attention":
        expect(page.get_by_role("heading", level=1)).to_have_text("A quick question")
        _tab_to(page, "attention_answer")
    else:
        expect(page.locator("input[name=video_id]")).to_have_value(expected)
        _tab_to(page, "reported_touches")
    page.keyboard.type(str(value))
    with page.expect_navigation():
        page.keyboard.press("Enter")


def _start(page: Page, base: str, pid: str) -> None:
    page.goto(base + "/")
    expect(page.get_by_role("heading", level=1)).to_have_text("Welcome")
    _tab_to(page, "participant_id")
    page.keyboard.type(pid)
    with page.expect_navigation():
        page.keyboard.press("Enter")


def _value(pid_number: int, video_id: str) -> int:
    return (int(video_id[1:]) * 3 + pid_number) % 10


def test_two_participants_complete_the_study(server: tuple[str, Path], browser: Browser) -> None:
    base, db_path = server
    page = browser.new_context().new_page()
    page.set_default_timeout(UI_TIMEOUT_MS)
    _start(page, base, "kb-alice")
    # the video plays: the tiny mp4 loads and reports its size
    page.wait_for_function("document.getElementById('study_video').readyState >= 1")
    size = page.evaluate("[study_video.videoWidth, study_video.videoHeight]")
    assert size == [VIDEO_W_PX, VIDEO_H_PX]
    for step in ORDER_0:
        value = ATTENTION_ANSWER if step == "attention" else _value(0, step)
        _answer_current(page, step, value)
    expect(page.get_by_role("heading", level=1)).to_have_text("Thank you")

    # the second participant reloads midway and resumes at the same step
    page2 = browser.new_context().new_page()
    page2.set_default_timeout(UI_TIMEOUT_MS)
    _start(page2, base, "kb-bob")
    for step in ORDER_1[:4]:
        _answer_current(page2, step, _value(1, step))
    page2.reload()
    expect(page2.locator("input[name=video_id]")).to_have_value(ORDER_1[4])
    expect(page2.get_by_role("heading", level=1)).to_have_text("Set 2 of 3: video 2 of 3")
    # a bad value typed past the browser's own check is refused by the server
    page2.evaluate("document.getElementById('reported_touches').removeAttribute('max')")
    _tab_to(page2, "reported_touches")
    page2.keyboard.type("150")
    with page2.expect_navigation():
        page2.keyboard.press("Enter")
    expect(page2.get_by_role("alert")).to_contain_text("0 to 99")
    for step in ORDER_1[4:]:
        value = ATTENTION_ANSWER + 1 if step == "attention" else _value(1, step)
        _answer_current(page2, step, value)
    expect(page2.get_by_role("heading", level=1)).to_have_text("Thank you")

    expected = {("kb-alice", v, _value(0, v), True) for v in ORDER_0 if v != "attention"}
    expected |= {("kb-bob", v, _value(1, v), False) for v in ORDER_1 if v != "attention"}
    stored = {
        (r.participant_id, r.video_id, r.reported_touches, r.attention_passed)
        for r in StudyDB(db_path).export_rows()
    }
    assert stored == expected
    csv = httpx.get(f"{base}/admin/export.csv", headers={"Authorization": f"Bearer {ADMIN}"})
    lines = csv.text.splitlines()
    assert lines[0] == "participant_id,video_id,reported_touches,attention_passed"
    exported = {tuple(line.split(",")) for line in lines[1:]}
    assert exported == {(p, v, str(n), str(a).lower()) for p, v, n, a in expected}

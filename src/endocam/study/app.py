"""The study web app: FastAPI + Jinja templates + the SQLite store (needs the ``study`` extra).

Participants open ``/``, type an anonymous id (or leave it empty to get one) and receive a random
session token in an ``HttpOnly``, ``SameSite=Strict`` cookie; the id alone never grants access.
``/study`` always shows the first unanswered step (see :mod:`endocam.study.flow`), so a reload
resumes where the participant stopped. Answers are never overwritten: a second answer for the same
video is refused with 409.

JSON API (the pages post plain forms; the API serves scripts and tests):

- ``POST /api/session`` ``{"participant_id": "..."?}`` → 201, sets the session cookie;
- ``GET /api/next`` → the next step;
- ``POST /api/answer`` ``{"video_id": "v01", "reported_touches": 7}`` → 201 with the next step;
- ``POST /api/attention`` ``{"answer": 4}`` → 201 with the next step;
- ``GET /api/me`` → the caller's own answers;
- ``GET /admin/export.csv`` and ``/admin/export.json`` with ``Authorization: Bearer TOKEN`` or
  ``?token=TOKEN``; disabled (403) when the app has no admin token.
"""

import secrets
from pathlib import Path
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Form, HTTPException, Request, Response
from fastapi.responses import FileResponse, JSONResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from pydantic import BaseModel, ConfigDict, Field, StrictInt, TypeAdapter, ValidationError
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from endocam import __version__
from endocam.study.db import ConflictError, Participant, StudyDB
from endocam.study.flow import Step, StepKind, next_step
from endocam.study.manifest import ID_PATTERN, MAX_TOUCHES, Manifest, load_manifest
from endocam.study.responses import rows_to_csv

SESSION_COOKIE = "endocam_session"
SESSION_MAX_AGE_S = 7 * 24 * 3600  # s, cookie lifetime
_HERE = Path(__file__).parent
TEMPLATES_DIR = _HERE / "templates"
STATIC_DIR = _HERE / "static"

Touches = Annotated[StrictInt, Field(ge=0, le=MAX_TOUCHES)]
ParticipantId = Annotated[str, Field(pattern=ID_PATTERN)]
_form_touches: TypeAdapter[int] = TypeAdapter(Annotated[int, Field(ge=0, le=MAX_TOUCHES)])
_form_id: TypeAdapter[str] = TypeAdapter(ParticipantId)


class SessionIn(BaseModel):
    """Body of ``POST /api/session``; without an id the server generates one."""

    model_config = ConfigDict(extra="forbid")
    participant_id: ParticipantId | None = None


class AnswerIn(BaseModel):
    """Body of ``POST /api/answer``; ``participant_id``, if sent, must be the caller's own."""

    model_config = ConfigDict(extra="forbid")
    video_id: Annotated[str, Field(min_length=1, max_length=128)]
    reported_touches: Touches
    participant_id: str | None = None


class AttentionIn(BaseModel):
    """Body of ``POST /api/attention``."""

    model_config = ConfigDict(extra="forbid")
    answer: Touches


class _RefusedError(Exception):
    """A request the study refuses; becomes an HTTP error or an error message on the page."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message


class _SecurityHeaders:
    """Pure-ASGI middleware: no caching of participant data, no framing, same-origin content."""

    _HEADERS = (
        (b"cache-control", b"no-store"),
        (b"x-content-type-options", b"nosniff"),
        (b"referrer-policy", b"no-referrer"),
        (b"x-frame-options", b"DENY"),
        (b"content-security-policy", b"default-src 'self'; frame-ancestors 'none'"),
    )

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message.setdefault("headers", [])
                message["headers"] = list(message["headers"]) + list(self._HEADERS)
            await send(message)

        await self.app(scope, receive, send_with_headers)


def _step_json(step: Step) -> dict[str, Any]:
    return {
        "kind": step.kind.value,
        "video_id": step.video_id,
        "video_url": f"/videos/{step.video_id}" if step.video_id else None,
        "set_number": step.set_number,
        "position_in_set": step.position_in_set,
        "videos_in_set": step.videos_in_set,
        "n_sets": step.n_sets,
        "n_answered": step.n_answered,
        "n_videos": step.n_videos,
    }


def create_app(study_dir: str | Path, db_path: str | Path, admin_token: str | None) -> FastAPI:
    """Build the study web app.

    Parameters
    ----------
    study_dir : str or Path
        Study folder with ``manifest.json`` and the video files it lists.
    db_path : str or Path
        SQLite database file (created if missing; its folder must exist).
    admin_token : str or None
        Token guarding ``/admin/export.*``; None or empty disables the export (403).

    Returns
    -------
    FastAPI
        The ASGI app.

    Raises
    ------
    ValueError
        Unusable study folder or database (one-line message).
    """
    study_root = Path(study_dir).resolve()
    manifest: Manifest = load_manifest(study_root, check_files=True)
    db = StudyDB(db_path)
    video_files = {v.id: study_root / v.file for v in manifest.videos}
    templates = Jinja2Templates(directory=str(TEMPLATES_DIR))

    app = FastAPI(
        title="endocam study", version=__version__, docs_url=None, redoc_url=None, openapi_url=None
    )
    app.add_middleware(_SecurityHeaders)
    app.mount("/static", StaticFiles(directory=str(STATIC_DIR)), name="static")
    app.state.manifest = manifest
    app.state.db = db

    # ---- shared logic ---------------------------------------------------------------------
    def session_participant(request: Request) -> Participant | None:
        token = request.cookies.get(SESSION_COOKIE)
        return db.participant_by_token(token) if token else None

    def require_participant(request: Request) -> Participant:
        participant = session_participant(request)
        if participant is None:
            raise HTTPException(401, "no valid session: start one at / or POST /api/session")
        return participant

    def current_step(participant: Participant) -> Step:
        return next_step(
            manifest,
            participant.order_index,
            db.answers(participant).keys(),
            participant.attention_answer is not None,
        )

    def start_session(response: Response, participant_id: str | None) -> Participant:
        for _ in range(5):
            pid = participant_id or f"p-{secrets.token_hex(4)}"
            try:
                participant, token = db.create_participant(pid, len(manifest.orders))
            except ConflictError:
                if participant_id:
                    msg = f"the id {pid!r} is already taken; choose another"
                    raise _RefusedError(409, msg) from None
                continue
            response.set_cookie(
                SESSION_COOKIE,
                token,
                max_age=SESSION_MAX_AGE_S,
                httponly=True,
                samesite="strict",
                path="/",
            )
            return participant
        raise _RefusedError(503, "could not generate a free participant id; try again")

    def submit_answer(participant: Participant, video_id: str, touches: int) -> None:
        if video_id not in video_files:
            raise _RefusedError(404, f"unknown video {video_id!r}")
        answers = db.answers(participant)
        if video_id in answers:
            raise _RefusedError(409, f"video {video_id!r} is already answered; answers are final")
        step = next_step(
            manifest,
            participant.order_index,
            answers.keys(),
            participant.attention_answer is not None,
        )
        if step.kind != StepKind.VIDEO or step.video_id != video_id:
            raise _RefusedError(
                409, f"video {video_id!r} is not the current step ({step.kind.value})"
            )
        try:
            db.record_answer(participant, video_id, touches)
        except ConflictError as exc:
            raise _RefusedError(409, str(exc)) from None

    def submit_attention(participant: Participant, answer: int) -> None:
        if current_step(participant).kind != StepKind.ATTENTION:
            raise _RefusedError(409, "the attention question is not the current step")
        try:
            db.record_attention(participant, answer, answer == manifest.attention.answer)
        except ConflictError as exc:
            raise _RefusedError(409, str(exc)) from None

    def check_admin(request: Request) -> None:
        if not admin_token:
            raise HTTPException(403, "the export is disabled: start the server with an admin token")
        header = request.headers.get("authorization", "")
        given = header[7:] if header.lower().startswith("bearer ") else ""
        given = given or request.query_params.get("token", "")
        if not secrets.compare_digest(given.encode(), admin_token.encode()):
            raise HTTPException(401, "admin token missing or wrong", {"WWW-Authenticate": "Bearer"})

    CurrentParticipant = Annotated[Participant, Depends(require_participant)]

    # ---- JSON API -------------------------------------------------------------------------
    @app.post("/api/session", status_code=201)
    def api_session(response: Response, body: SessionIn | None = None) -> dict[str, Any]:
        try:
            participant = start_session(response, body.participant_id if body else None)
        except _RefusedError as exc:
            raise HTTPException(exc.status, exc.message) from None
        return {
            "participant_id": participant.participant_id,
            "next": _step_json(current_step(participant)),
        }

    @app.get("/api/next")
    def api_next(participant: CurrentParticipant) -> dict[str, Any]:
        return _step_json(current_step(participant))

    @app.get("/api/me")
    def api_me(participant: CurrentParticipant) -> dict[str, Any]:
        return {
            "participant_id": participant.participant_id,
            "answers": db.answers(participant),
            "attention_answered": participant.attention_answer is not None,
        }

    @app.post("/api/answer", status_code=201)
    def api_answer(body: AnswerIn, participant: CurrentParticipant) -> dict[str, Any]:
        if body.participant_id is not None and body.participant_id != participant.participant_id:
            raise HTTPException(403, "a session may only answer for its own participant")
        try:
            submit_answer(participant, body.video_id, body.reported_touches)
        except _RefusedError as exc:
            raise HTTPException(exc.status, exc.message) from None
        return {"next": _step_json(current_step(participant))}

    @app.post("/api/attention", status_code=201)
    def api_attention(body: AttentionIn, participant: CurrentParticipant) -> dict[str, Any]:
        try:
            submit_attention(participant, body.answer)
        except _RefusedError as exc:
            raise HTTPException(exc.status, exc.message) from None
        return {"next": _step_json(current_step(db.refresh(participant)))}

    # ---- pages ----------------------------------------------------------------------------
    def page(request: Request, name: str, status: int = 200, **context: Any) -> Response:
        return templates.TemplateResponse(request, name, context, status_code=status)

    @app.get("/")
    def start_page(request: Request) -> Response:
        if session_participant(request) is not None:
            return RedirectResponse("/study", status_code=303)
        return page(request, "start.html", error=None, value="")

    @app.post("/start")
    def start_form(request: Request, participant_id: Annotated[str, Form()] = "") -> Response:
        value = participant_id.strip()
        try:
            chosen = _form_id.validate_python(value) if value else None
            redirect = RedirectResponse("/study", status_code=303)
            start_session(redirect, chosen)
        except ValidationError:
            message = "Use 1–64 letters, digits, '-', '_' or '.', starting with a letter or digit."
            return page(request, "start.html", 400, error=message, value=value)
        except _RefusedError as exc:
            return page(request, "start.html", exc.status, error=exc.message, value=value)
        return redirect

    def step_page(
        request: Request, participant: Participant, status: int = 200, error: str | None = None
    ) -> Response:
        step = current_step(participant)
        context: dict[str, Any] = {"step": step, "participant": participant, "error": error}
        if step.kind == StepKind.VIDEO:
            return page(request, "video.html", status, **context)
        if step.kind == StepKind.ATTENTION:
            return page(
                request, "attention.html", status, question=manifest.attention.question, **context
            )
        return page(request, "done.html", status, **context)

    @app.get("/study")
    def study_page(request: Request) -> Response:
        participant = session_participant(request)
        if participant is None:
            return RedirectResponse("/", status_code=303)
        return step_page(request, participant)

    @app.post("/study/answer")
    def answer_form(
        request: Request,
        video_id: Annotated[str, Form()] = "",
        reported_touches: Annotated[str, Form()] = "",
    ) -> Response:
        participant = session_participant(request)
        if participant is None:
            return RedirectResponse("/", status_code=303)
        try:
            touches = _form_touches.validate_python(reported_touches.strip())
        except ValidationError:
            return step_page(
                request, participant, 400, f"Enter a whole number from 0 to {MAX_TOUCHES}."
            )
        try:
            submit_answer(participant, video_id, touches)
        except _RefusedError as exc:
            return step_page(request, participant, exc.status, exc.message)
        return RedirectResponse("/study", status_code=303)

    @app.post("/study/attention")
    def attention_form(request: Request, answer: Annotated[str, Form()] = "") -> Response:
        participant = session_participant(request)
        if participant is None:
            return RedirectResponse("/", status_code=303)
        try:
            value = _form_touches.validate_python(answer.strip())
        except ValidationError:
            return step_page(
                request, participant, 400, f"Enter a whole number from 0 to {MAX_TOUCHES}."
            )
        try:
            submit_attention(participant, value)
        except _RefusedError as exc:
            return step_page(request, participant, exc.status, exc.message)
        return RedirectResponse("/study", status_code=303)

    @app.get("/videos/{video_id}")
    def video_file(video_id: str, participant: CurrentParticipant) -> FileResponse:
        path = video_files.get(video_id)
        if path is None:
            raise HTTPException(404, f"unknown video {video_id!r}")
        return FileResponse(path, media_type="video/mp4")

    # ---- admin ----------------------------------------------------------------------------
    @app.get("/admin/export.csv", dependencies=[Depends(check_admin)])
    def export_csv() -> Response:
        return Response(
            rows_to_csv(db.export_rows()),
            media_type="text/csv; charset=utf-8",
            headers={"Content-Disposition": 'attachment; filename="responses.csv"'},
        )

    @app.get("/admin/export.json", dependencies=[Depends(check_admin)])
    def export_json() -> JSONResponse:
        participants = [
            {
                "participant_id": p.participant_id,
                "order_index": p.order_index,
                "order": [c.value for c in manifest.orders[p.order_index]],
                "created": p.created,
                "attention_answer": p.attention_answer,
                "attention_passed": p.attention_passed,
            }
            for p in db.participants()
        ]
        responses = [r.model_dump(mode="json") for r in db.export_rows()]
        return JSONResponse({"participants": participants, "responses": responses})

    return app

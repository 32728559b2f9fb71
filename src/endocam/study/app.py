"""The study web app: FastAPI + Jinja templates + the SQLite store (needs the ``study`` extra).

Participants open ``/`` (from a recruitment platform: ``/?PROLIFIC_PID=...&STUDY_ID=...&
SESSION_ID=...``, parameter names from the manifest's ``recruitment``), read the information,
give consent and receive a random session token in an ``HttpOnly``, ``SameSite=Strict`` cookie
(``Secure`` with ``secure_cookies``); the id alone never grants access, and the server never
tells whether an id is already known (see :mod:`endocam.study.db`), except that a withdrawn id is
refused (403). ``/study`` always shows the first unanswered step (see
:mod:`endocam.study.flow`): demographics, practice video with feedback, the sets, the attention
question, and the last page with the completion code (which, with a ``completion_url``, sends
the browser back to the platform after ``redirect_after_s``). A reload resumes where the participant
stopped. Answers are never overwritten: a second answer for the same step is refused with 409.
Every participant-facing text comes from the message catalogue (:mod:`endocam.study.catalogue`).

The video pages post player events (play, pause, seek, rate change, end, watched seconds) to
``/api/event`` from :file:`static/study.js`; with the manifest's ``must_watch`` an answer is
accepted only after the video was played to its end once with ``db.MIN_WATCHED_SHARE`` of it
played on the way (skipping ahead to the end does not count).

JSON API (the pages post plain forms; the API serves scripts and tests):

- ``POST /api/session`` ``{"consent": true, "participant_id": "..."?, "recruitment": {...}?}``
  → 201, sets the session cookie;
- ``GET /api/next`` → the next step;
- ``POST /api/demographics`` ``{"training_years": 3, "prior_assessment": "no"}``,
  ``POST /api/practice`` ``{"reported_touches": 2}`` → 201 with the next step;
- ``POST /api/answer`` ``{"video_id": "v01", "reported_touches": 7}`` → 201 with the next step;
- ``POST /api/attention`` ``{"answer": 4}`` → 201 with the next step;
- ``POST /api/event`` ``{"video_id": "v01", "kind": "play", "media_time_s": 0.0, ...}`` → 204;
- ``GET /api/me`` → the caller's own answers.

Admin (``Authorization: Bearer TOKEN``, or the admin session cookie a browser gets by posting the
token once to ``POST /admin/login``, see :mod:`endocam.study.admin_auth`; never a token in a URL;
403 when the app has no token): ``GET /admin`` (progress per order, sessions, withdraw form,
action log; the sign-in form without a sign-in), ``POST /admin/withdraw``, ``POST /admin/logout``,
``GET /admin/export/{responses|participants|events}.{csv|parquet}``, ``/admin/export.json``,
``/admin/codebook.md`` and, as before, ``/admin/export.csv`` (= responses).

At start the app stamps completed any session that has every step answered but no ``completed``
stamp (left by an older endocam killed between the two writes; see
:meth:`~endocam.study.db.StudyDB.repair_completed`); now the last answer and its stamp are one
transaction.

Limits (:mod:`endocam.study.web`): request bodies above :data:`MAX_BODY_BYTES` get 413;
validation errors (422) and 404s name the field or the rule but never echo the input; session starts
are rate-limited per client address and in total (:data:`SESSION_RATE`, 429).
"""

import math
import secrets
from collections.abc import Callable, Collection
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any, cast
from urllib.parse import urlencode

from fastapi import Depends, FastAPI, Form, HTTPException, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from pydantic import ValidationError

from endocam import __version__
from endocam.study.admin_auth import ADMIN_COOKIE, AdminSessions
from endocam.study.api_models import (
    MAX_TRAINING_YEARS,
    AnswerIn,
    AttentionIn,
    CountIn,
    DemographicsIn,
    EventIn,
    RefusedError,
    SessionIn,
    form_id,
    step_json,
    validation_error_body,
)
from endocam.study.catalogue import Catalogue, load_catalogue
from endocam.study.db import ABANDON_AFTER_S, MIN_WATCHED_SHARE, StudyDB
from endocam.study.export import (
    TABLES,
    TableName,
    codebook_markdown,
    export_tables,
    to_csv,
    to_json,
)
from endocam.study.export import to_parquet as table_to_parquet
from endocam.study.flow import Step, StepKind, next_step, video_sequence
from endocam.study.manifest import MAX_TOUCHES, Manifest, load_manifest
from endocam.study.migration import v1_sequence
from endocam.study.records import ConflictError, Participant, Status, WithdrawnError
from endocam.study.responses import parse_count
from endocam.study.web import (
    SESSION_RATE,
    BodyLimit,
    RateLimit,
    RateLimiter,
    SecurityHeaders,
)

SESSION_COOKIE = "endocam_session"
SESSION_MAX_AGE_S = 7 * 24 * 3600  # s, cookie lifetime
PRACTICE_ID = "_practice"  # video id of the practice video (never a manifest id: see ID_PATTERN)
PRIOR_ASSESSMENT = ("yes", "no", "unsure")
REDIRECT_AFTER_S = 5.0  # s the last page shows the completion code before going back
ADMIN_DISABLED = "the admin pages are disabled: start with an admin token"
MUST_WATCH_REFUSAL = "watch the whole video to its end first, without skipping ahead"
_HERE = Path(__file__).parent
TEMPLATES_DIR = _HERE / "templates"
STATIC_DIR = _HERE / "static"


def create_app(
    study_dir: str | Path,
    db_path: str | Path,
    admin_token: str | None,
    *,
    session_rate: RateLimit = SESSION_RATE,
    abandon_after_s: float = ABANDON_AFTER_S,
    secure_cookies: bool = False,
    redirect_after_s: float = REDIRECT_AFTER_S,
) -> FastAPI:
    """Build the study web app.

    Parameters
    ----------
    study_dir : str or Path
        Study folder with ``manifest.json`` and the files it names.
    db_path : str or Path
        SQLite database file (created if missing; its folder must exist).
    admin_token : str or None
        Token guarding ``/admin``; None or empty disables the admin pages (403).
    session_rate : RateLimit
        Limit on session starts.
    abandon_after_s : float
        Idle time (s) after which an unfinished session is abandoned (no longer counted for
        counterbalancing; shown as such on the admin page).
    secure_cookies : bool
        Mark the session and admin cookies ``Secure`` (sent over HTTPS only): set it when the app
        is served over HTTPS (behind a reverse proxy).
    redirect_after_s : float
        With the manifest's ``completion_url``, the last page sends the browser there after
        this many seconds (an HTML refresh, no script needed), the code shown meanwhile.

    Returns
    -------
    FastAPI
        The ASGI app.

    Raises
    ------
    ValueError
        Unusable study folder, message catalogue or database (one-line message).
    """
    if not (math.isfinite(redirect_after_s) and redirect_after_s >= 0):
        raise ValueError(f"redirect_after_s must be >= 0, got {redirect_after_s}")
    if not (math.isfinite(abandon_after_s) and abandon_after_s > 0):
        raise ValueError(f"abandon_after_s must be > 0, got {abandon_after_s}")
    study_root = Path(study_dir).resolve()
    manifest: Manifest = load_manifest(study_root, check_files=True)
    t: Catalogue = load_catalogue(
        study_root / manifest.messages_file if manifest.messages_file else None
    )
    consent_text = (
        [p.strip() for p in (study_root / manifest.consent_file).read_text("utf-8").split("\n\n")]
        if manifest.consent_file
        else t.paragraphs("consent_default")
    )
    db = StudyDB(db_path, v1_sequence=lambda order: v1_sequence(manifest, order))
    admin = AdminSessions(admin_token)
    video_files = {v.id: study_root / v.file for v in manifest.videos}
    if manifest.practice:
        video_files[PRACTICE_ID] = study_root / manifest.practice.file
    templates = Jinja2Templates(directory=str(TEMPLATES_DIR))
    templates.env.globals.update(
        t=t,
        manifest=manifest,
        max_touches=MAX_TOUCHES,
        max_years=MAX_TRAINING_YEARS,
        min_watched_share=MIN_WATCHED_SHARE,
    )
    limiter = RateLimiter(session_rate)
    recruitment_params = (manifest.recruitment.id_param, *manifest.recruitment.extra_params)

    app = FastAPI(
        title="endocam study", version=__version__, docs_url=None, redoc_url=None, openapi_url=None
    )
    app.add_middleware(SecurityHeaders)
    app.add_middleware(BodyLimit)
    app.mount("/static", StaticFiles(directory=str(STATIC_DIR)), name="static")
    app.state.manifest = manifest
    app.state.db = db

    @app.exception_handler(RequestValidationError)
    async def no_echo(request: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse(validation_error_body(exc), status_code=422)

    # ---- shared logic ---------------------------------------------------------------------
    def session_participant(request: Request) -> Participant | None:
        token = request.cookies.get(SESSION_COOKIE)
        return db.participant_by_token(token) if token else None

    def require_participant(request: Request) -> Participant:
        participant = session_participant(request)
        if participant is None:
            raise HTTPException(401, "no valid session: start one at / or POST /api/session")
        return participant

    def step_for(participant: Participant, answered: Collection[str]) -> Step:
        return next_step(
            participant.video_order,
            answered,
            participant.attention_answer is not None,
            demographics_due=manifest.demographics and not participant.demographics_done,
            practice_due=manifest.practice is not None and not participant.practice_done,
        )

    def current_step(participant: Participant) -> Step:
        return step_for(participant, db.answers(participant).keys())

    def is_done(participant: Participant, answered: Collection[str]) -> bool:
        """The store's ``done`` predicate: every step of the session answered."""
        steps = participant.video_order
        return bool(steps and steps[0]) and step_for(participant, answered).kind == StepKind.DONE

    db.repair_completed(is_done)  # sessions an older endocam left answered but unstamped

    def start_session(
        request: Request,
        response: Response,
        participant_id: str | None,
        recruitment: dict[str, str],
    ) -> Participant:
        client = request.client.host if request.client else "unknown"
        if not limiter.allow(client):
            raise RefusedError(429, "too many new sessions; wait a minute", "error_rate")
        unknown = sorted(set(recruitment) - set(recruitment_params))
        if unknown:
            raise RefusedError(422, f"unknown recruitment parameters {unknown}", "error_platform")
        pid = recruitment.get(manifest.recruitment.id_param) or participant_id
        try:
            participant, token = db.create_participant(
                pid or f"p-{secrets.token_hex(4)}",
                len(manifest.orders),
                lambda order, seed: video_sequence(manifest, order, seed),
                recruitment=recruitment,
                abandon_after_s=abandon_after_s,
            )
        except WithdrawnError:
            message = "this participant id was withdrawn from the study; it cannot take part again"
            raise RefusedError(403, message, "error_withdrawn") from None
        response.set_cookie(
            SESSION_COOKIE,
            token,
            max_age=SESSION_MAX_AGE_S,
            httponly=True,
            samesite="strict",
            secure=secure_cookies,
            path="/",
        )
        return participant

    def expect_step(participant: Participant, kind: StepKind) -> None:
        step = current_step(participant)
        if step.kind != kind:
            raise RefusedError(409, f"{kind.value} is not the current step ({step.kind.value})")

    def submit_demographics(participant: Participant, years: int | None, prior: str | None) -> None:
        expect_step(participant, StepKind.DEMOGRAPHICS)
        try:
            db.record_demographics(participant, years, prior)
        except ConflictError as exc:
            raise RefusedError(409, str(exc)) from None

    def submit_practice(participant: Participant, touches: int) -> None:
        expect_step(participant, StepKind.PRACTICE)
        if manifest.must_watch and not db.watched_to_end(participant, PRACTICE_ID):
            raise RefusedError(409, MUST_WATCH_REFUSAL, "error_must_watch")
        try:
            db.record_practice(participant, touches)
        except ConflictError as exc:
            raise RefusedError(409, str(exc)) from None

    def submit_answer(participant: Participant, video_id: str, touches: int) -> None:
        if video_id not in video_files or video_id == PRACTICE_ID:
            raise RefusedError(404, "unknown video_id")
        answers = db.answers(participant)
        if video_id in answers:
            raise RefusedError(409, f"video {video_id!r} is already answered; answers are final")
        step = current_step(participant)
        if step.kind != StepKind.VIDEO or step.video_id != video_id:
            raise RefusedError(
                409, f"video {video_id!r} is not the current step ({step.kind.value})"
            )
        if manifest.must_watch and not db.watched_to_end(participant, video_id):
            raise RefusedError(409, MUST_WATCH_REFUSAL, "error_must_watch")
        try:
            db.record_answer(participant, video_id, touches, is_done)
        except ConflictError as exc:
            raise RefusedError(409, str(exc)) from None

    def submit_attention(participant: Participant, answer: int) -> None:
        expect_step(participant, StepKind.ATTENTION)
        try:
            db.record_attention(participant, answer, answer == manifest.attention.answer, is_done)
        except ConflictError as exc:
            raise RefusedError(409, str(exc)) from None

    def check_admin(request: Request) -> None:
        if not admin.enabled:
            raise HTTPException(403, ADMIN_DISABLED)
        if not admin.authorised(request):
            raise HTTPException(
                401,
                "admin sign-in needed: sign in at /admin or send Authorization: Bearer TOKEN"
                " (a token in the URL is not accepted)",
                {"WWW-Authenticate": "Bearer"},
            )

    CurrentParticipant = Annotated[Participant, Depends(require_participant)]

    def api_refusal(exc: RefusedError) -> HTTPException:
        return HTTPException(exc.status, exc.message)

    # ---- JSON API -------------------------------------------------------------------------
    @app.post("/api/session", status_code=201)
    def api_session(request: Request, response: Response, body: SessionIn) -> dict[str, Any]:
        try:
            participant = start_session(
                request, response, body.participant_id, body.recruitment or {}
            )
        except RefusedError as exc:
            raise api_refusal(exc) from None
        return {
            "participant_id": participant.participant_id,
            "next": step_json(current_step(participant)),
        }

    @app.get("/api/next")
    def api_next(participant: CurrentParticipant) -> dict[str, Any]:
        return step_json(current_step(participant))

    @app.get("/api/me")
    def api_me(participant: CurrentParticipant) -> dict[str, Any]:
        return {
            "participant_id": participant.participant_id,
            "answers": db.answers(participant),
            "attention_answered": participant.attention_answer is not None,
        }

    @app.post("/api/demographics", status_code=201)
    def api_demographics(body: DemographicsIn, participant: CurrentParticipant) -> dict[str, Any]:
        try:
            submit_demographics(participant, body.training_years, body.prior_assessment)
        except RefusedError as exc:
            raise api_refusal(exc) from None
        return {"next": step_json(current_step(db.refresh(participant)))}

    @app.post("/api/practice", status_code=201)
    def api_practice(body: CountIn, participant: CurrentParticipant) -> dict[str, Any]:
        try:
            submit_practice(participant, body.reported_touches)
        except RefusedError as exc:
            raise api_refusal(exc) from None
        assert manifest.practice is not None  # submit_practice checked the step
        return {
            "true_touches": manifest.practice.true_touches,
            "next": step_json(current_step(db.refresh(participant))),
        }

    @app.post("/api/answer", status_code=201)
    def api_answer(body: AnswerIn, participant: CurrentParticipant) -> dict[str, Any]:
        if body.participant_id is not None and body.participant_id != participant.participant_id:
            raise HTTPException(403, "a session may only answer for its own participant")
        try:
            submit_answer(participant, body.video_id, body.reported_touches)
        except RefusedError as exc:
            raise api_refusal(exc) from None
        return {"next": step_json(current_step(participant))}

    @app.post("/api/attention", status_code=201)
    def api_attention(body: AttentionIn, participant: CurrentParticipant) -> dict[str, Any]:
        try:
            submit_attention(participant, body.answer)
        except RefusedError as exc:
            raise api_refusal(exc) from None
        return {"next": step_json(current_step(db.refresh(participant)))}

    @app.post("/api/event", status_code=204)
    def api_event(body: EventIn, participant: CurrentParticipant) -> Response:
        if body.video_id not in video_files:
            raise HTTPException(404, "unknown video_id")
        db.record_event(
            participant,
            body.video_id,
            body.kind,
            body.media_time_s,
            body.playback_rate,
            body.watched_s,
        )
        return Response(status_code=204)

    # ---- pages ----------------------------------------------------------------------------
    def page(request: Request, name: str, status: int = 200, **context: Any) -> Response:
        return templates.TemplateResponse(request, name, context, status_code=status)

    def start_context(params: dict[str, str], value: str = "") -> dict[str, Any]:
        return {
            "consent_text": consent_text,
            "params": params,
            "platform_id": params.get(manifest.recruitment.id_param),
            "value": value,
            "n_videos": len(manifest.videos),
            "n_sets": len(manifest.conditions),
            "per_set": len(manifest.videos) // len(manifest.conditions),
        }

    @app.get("/")
    def start_page(request: Request) -> Response:
        if session_participant(request) is not None:
            return RedirectResponse("/study", status_code=303)
        params = {k: v for k, v in request.query_params.items() if k in recruitment_params}
        try:
            for v in params.values():
                form_id.validate_python(v)
        except ValidationError:
            context = start_context({})
            return page(request, "start.html", 400, error=t("error_platform"), **context)
        return page(request, "start.html", error=None, **start_context(params))

    @app.post("/start")
    async def start_form(request: Request) -> Response:
        form = await request.form()
        fields = {k: v for k, v in form.items() if isinstance(v, str)}
        params = {k: v for k, v in fields.items() if k in recruitment_params and v}
        value = fields.get("participant_id", "").strip()
        context = start_context(params, value)
        if fields.get("consent") != "yes":
            return page(request, "start.html", 400, error=t("error_consent"), **context)
        try:
            chosen = form_id.validate_python(value) if value else None
            for v in params.values():
                form_id.validate_python(v)
        except ValidationError:
            key = "error_platform" if params else "error_id"
            return page(request, "start.html", 400, error=t(key), **context)
        redirect = RedirectResponse("/study", status_code=303)
        try:
            start_session(request, redirect, chosen, params)
        except RefusedError as exc:
            return page(request, "start.html", exc.status, error=t(exc.key), **context)
        return redirect

    def step_page(
        request: Request, participant: Participant, status: int = 200, error: str | None = None
    ) -> Response:
        step = current_step(participant)
        context: dict[str, Any] = {"step": step, "participant": participant, "error": error}
        if step.kind == StepKind.DEMOGRAPHICS:
            return page(request, "demographics.html", status, **context)
        if step.kind == StepKind.PRACTICE:
            db.record_event(participant, PRACTICE_ID, "shown")
            return page(request, "practice.html", status, video_id=PRACTICE_ID, **context)
        if step.kind == StepKind.VIDEO:
            assert step.video_id is not None
            db.record_event(participant, step.video_id, "shown")
            return page(request, "video.html", status, video_id=step.video_id, **context)
        if step.kind == StepKind.ATTENTION:
            return page(
                request, "attention.html", status, question=manifest.attention.question, **context
            )
        code = manifest.recruitment.completion_code
        url = manifest.recruitment.completion_url
        return page(
            request,
            "done.html",
            status,
            code=code,
            return_url=url.replace("{code}", code or "") if url else None,
            redirect_after_s=redirect_after_s,
            **context,
        )

    @app.get("/study")
    def study_page(request: Request) -> Response:
        participant = session_participant(request)
        if participant is None:
            return RedirectResponse("/", status_code=303)
        return step_page(request, participant)

    def form_count(text: str) -> int | None:
        try:
            return parse_count(text)
        except ValueError:
            return None

    @app.post("/study/demographics")
    def demographics_form(
        request: Request,
        training_years: Annotated[str, Form()] = "",
        prior_assessment: Annotated[str, Form()] = "",
    ) -> Response:
        participant = session_participant(request)
        if participant is None:
            return RedirectResponse("/", status_code=303)
        try:
            text = training_years.strip()
            years = parse_count(text, MAX_TRAINING_YEARS) if text else None
        except ValueError:
            return step_page(
                request, participant, 400, t("error_years", max_years=MAX_TRAINING_YEARS)
            )
        prior = prior_assessment if prior_assessment in PRIOR_ASSESSMENT else None
        try:
            submit_demographics(participant, years, prior)
        except RefusedError as exc:
            return step_page(request, participant, exc.status, t(exc.key))
        return RedirectResponse("/study", status_code=303)

    def count_form(
        request: Request, text: str, submit: Callable[[Participant, int], None], then: str
    ) -> Response:
        """A form that posts one count: parsed by the JSON API's rule, submitted, redirected."""
        participant = session_participant(request)
        if participant is None:
            return RedirectResponse("/", status_code=303)
        value = form_count(text)
        if value is None:
            return step_page(request, participant, 400, t("error_count", max_touches=MAX_TOUCHES))
        try:
            submit(participant, value)
        except RefusedError as exc:
            return step_page(request, participant, exc.status, t(exc.key))
        return RedirectResponse(then, status_code=303)

    @app.post("/study/practice")
    def practice_form(request: Request, reported_touches: Annotated[str, Form()] = "") -> Response:
        return count_form(request, reported_touches, submit_practice, "/study/practice/feedback")

    @app.get("/study/practice/feedback")
    def practice_feedback(request: Request) -> Response:
        participant = session_participant(request)
        if participant is None:
            return RedirectResponse("/", status_code=303)
        if manifest.practice is None or participant.practice_answer is None:
            return RedirectResponse("/study", status_code=303)
        return page(
            request,
            "feedback.html",
            participant=participant,
            given=participant.practice_answer,
            true_touches=manifest.practice.true_touches,
        )

    @app.post("/study/answer")
    def answer_form(
        request: Request,
        video_id: Annotated[str, Form()] = "",
        reported_touches: Annotated[str, Form()] = "",
    ) -> Response:
        def submit(participant: Participant, touches: int) -> None:
            submit_answer(participant, video_id, touches)

        return count_form(request, reported_touches, submit, "/study")

    @app.post("/study/attention")
    def attention_form(request: Request, answer: Annotated[str, Form()] = "") -> Response:
        return count_form(request, answer, submit_attention, "/study")

    @app.get("/videos/{video_id}")
    def video_file(video_id: str, participant: CurrentParticipant) -> FileResponse:
        path = video_files.get(video_id)
        if path is None:
            raise HTTPException(404, "unknown video")
        return FileResponse(path, media_type="video/mp4")

    # ---- admin ----------------------------------------------------------------------------
    def tables() -> dict[TableName, list[Any]]:
        return export_tables(db, manifest, abandon_after_s)

    def sign_in_page(request: Request, error: str | None = None) -> Response:
        if not admin.enabled:
            raise HTTPException(403, ADMIN_DISABLED)
        hours = admin.lifetime_s / 3600.0
        response = page(request, "admin_login.html", 401, error=error, hours=hours)
        response.headers["WWW-Authenticate"] = "Bearer"
        return response

    @app.post("/admin/login")
    async def admin_login(request: Request) -> Response:
        form = await request.form()
        value = admin.sign_in(str(form.get("token", "")))
        if value is None:
            return sign_in_page(request, "admin token wrong")
        redirect = RedirectResponse("/admin", status_code=303)
        admin.set_cookie(redirect, value, secure=secure_cookies)
        return redirect

    @app.post("/admin/logout")
    def admin_logout(request: Request) -> Response:
        admin.sign_out(request.cookies.get(ADMIN_COOKIE, ""))
        redirect = RedirectResponse("/admin", status_code=303)
        admin.clear_cookie(redirect, secure=secure_cookies)
        return redirect

    @app.get("/admin")
    def admin_page(request: Request) -> Response:
        if not admin.authorised(request):
            return sign_in_page(request)
        now = datetime.now(UTC)
        sessions = db.participants()
        statuses = [p.status(now, abandon_after_s) for p in sessions]
        progress = [
            {
                "index": i,
                "order": " > ".join(order),
                **{
                    s.value: sum(
                        1
                        for p, st in zip(sessions, statuses, strict=True)
                        if p.order_index == i and st == s
                    )
                    for s in Status
                },
            }
            for i, order in enumerate(manifest.orders)
        ]
        return page(
            request,
            "admin.html",
            progress=progress,
            statuses=list(Status),
            sessions=list(zip(sessions, statuses, strict=True)),
            log=db.admin_log(),
            abandon_after_min=abandon_after_s / 60.0,
            tables=TABLES,
            message=request.query_params.get("message"),
        )

    @app.post("/admin/withdraw", dependencies=[Depends(check_admin)])
    async def admin_withdraw(request: Request) -> Response:
        form = await request.form()
        pid = str(form.get("participant_id", "")).strip()
        try:
            removed = db.withdraw(pid, note=str(form.get("note", "")).strip()[:200])
        except KeyError:
            raise HTTPException(404, "no active session has this participant id") from None
        message = f"withdrew {pid}: {removed} answer(s) removed"
        target = f"/admin?{urlencode({'message': message})}"
        return RedirectResponse(target, status_code=303)

    @app.get("/admin/codebook.md", dependencies=[Depends(check_admin)])
    def codebook() -> PlainTextResponse:
        return PlainTextResponse(codebook_markdown(), media_type="text/markdown; charset=utf-8")

    @app.get("/admin/export.json", dependencies=[Depends(check_admin)])
    def export_json() -> JSONResponse:
        return JSONResponse(to_json(tables()))

    @app.get("/admin/export.csv", dependencies=[Depends(check_admin)])
    def export_csv() -> Response:
        return export_table("responses", "csv")

    @app.get("/admin/export/{table}.{fmt}", dependencies=[Depends(check_admin)])
    def export_table(table: str, fmt: str) -> Response:
        if table not in TABLES or fmt not in ("csv", "parquet"):
            raise HTTPException(404, f"no such export: tables {TABLES}, formats csv or parquet")
        name = cast(TableName, table)
        rows = tables()[name]
        disposition = {"Content-Disposition": f'attachment; filename="{table}.{fmt}"'}
        if fmt == "csv":
            return Response(
                to_csv(name, rows), media_type="text/csv; charset=utf-8", headers=disposition
            )
        return Response(
            table_to_parquet(name, rows),
            media_type="application/vnd.apache.parquet",
            headers=disposition,
        )

    return app

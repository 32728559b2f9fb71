"""ASGI guards of the study web app: security headers, a request-body cap, a session-start limit.

Pure-ASGI middleware (no FastAPI import), so each guard sees every request before the app does.
"""

import threading
import time
from collections import deque
from dataclasses import dataclass

from starlette.types import ASGIApp, Message, Receive, Scope, Send

MAX_BODY_BYTES = 16 * 1024  # largest request body accepted (forms and JSON are far smaller)


@dataclass(frozen=True)
class RateLimit:
    """Limit on session starts within any ``window_s`` seconds.

    Attributes
    ----------
    per_client : int
        Starts allowed per client address.
    total : int
        Starts allowed in total.
    window_s : float
        Length of the sliding window, s.
    """

    per_client: int
    total: int
    window_s: float


SESSION_RATE = RateLimit(per_client=20, total=600, window_s=60.0)


class SecurityHeaders:
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
        """Add the headers to every HTTP response."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message.setdefault("headers", [])
                message["headers"] = list(message["headers"]) + list(self._HEADERS)
            await send(message)

        await self.app(scope, receive, send_with_headers)


class BodyLimit:
    """Pure-ASGI middleware: refuse request bodies above ``max_bytes`` with 413.

    Both a declared ``Content-Length`` and the bytes actually streamed are checked.
    """

    def __init__(self, app: ASGIApp, max_bytes: int = MAX_BODY_BYTES) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def _refuse(self, send: Send) -> None:
        body = f'{{"detail":"request body larger than {self.max_bytes} bytes"}}'.encode()
        await send(
            {
                "type": "http.response.start",
                "status": 413,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                    (b"connection", b"close"),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Pass the request on with its body read, or answer 413."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and (not declared.isdigit() or int(declared) > self.max_bytes):
            await self._refuse(send)
            return
        # bodies are small: read the whole body (up to the cap) before the app sees it
        chunks: list[bytes] = []
        size = 0
        while True:
            message = await receive()
            if message["type"] != "http.request":  # client went away
                return
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.max_bytes:
                await self._refuse(send)
                return
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        body = b"".join(chunks)
        sent = False

        async def replay() -> Message:
            nonlocal sent
            if not sent:
                sent = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


class RateLimiter:
    """Sliding-window counter of session starts (thread-safe, in memory)."""

    def __init__(self, limit: RateLimit) -> None:
        self.limit = limit
        self._lock = threading.Lock()
        self._all: deque[float] = deque()
        self._by_client: dict[str, deque[float]] = {}

    def allow(self, client: str) -> bool:
        """Count one start by ``client``; False if it is over a limit (then nothing is counted)."""
        now = time.monotonic()
        with self._lock:
            for stamps in (self._all, *self._by_client.values()):
                while stamps and now - stamps[0] > self.limit.window_s:
                    stamps.popleft()
            self._by_client = {k: v for k, v in self._by_client.items() if v}
            mine = self._by_client.setdefault(client, deque())
            if len(mine) >= self.limit.per_client or len(self._all) >= self.limit.total:
                return False
            mine.append(now)
            self._all.append(now)
            return True

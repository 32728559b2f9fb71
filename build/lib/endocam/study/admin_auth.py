"""Admin sign-in of the study web app: the token once, then an admin session in a cookie.

The admin token never travels in a URL. A browser posts it once to ``POST /admin/login`` (a
form); the server answers with a random admin session value in an ``HttpOnly``,
``SameSite=Strict`` cookie scoped to ``/admin`` (``Secure`` when the app is served over HTTPS) and
a redirect to ``/admin`` that carries nothing. The cookie holds no trace of the token: the server
keeps only the SHA-256 of each admin session, in memory, so a restart signs every admin out, and
``POST /admin/logout`` ends one. Scripts send ``Authorization: Bearer TOKEN`` with each request.
"""

from __future__ import annotations

import hashlib
import secrets
import threading
import time

from starlette.requests import Request
from starlette.responses import Response

ADMIN_COOKIE = "endocam_admin"
ADMIN_COOKIE_PATH = "/admin"
ADMIN_SESSION_S = 8 * 3600.0  # s, lifetime of an admin sign-in


def _digest(value: str) -> str:
    return hashlib.sha256(value.encode("utf-8")).hexdigest()


class AdminSessions:
    """The admin token and the admin sessions signed in with it (thread-safe, in memory).

    Parameters
    ----------
    token : str or None
        The admin token; None or empty disables the admin pages.
    lifetime_s : float
        How long (s) a sign-in lasts.
    """

    def __init__(self, token: str | None, lifetime_s: float = ADMIN_SESSION_S) -> None:
        self._token = token or ""
        self.lifetime_s = lifetime_s
        self._lock = threading.Lock()
        self._expiry: dict[str, float] = {}  # SHA-256 of a session value → monotonic expiry, s

    @property
    def enabled(self) -> bool:
        """Whether the app has an admin token at all."""
        return bool(self._token)

    def token_ok(self, given: str) -> bool:
        """Whether ``given`` is the admin token (constant-time comparison)."""
        return self.enabled and secrets.compare_digest(given.encode(), self._token.encode())

    def sign_in(self, given: str) -> str | None:
        """A new admin session value if ``given`` is the token, else None."""
        if not self.token_ok(given):
            return None
        value = secrets.token_urlsafe(32)
        now = time.monotonic()
        with self._lock:
            self._expiry = {k: t for k, t in self._expiry.items() if t > now}
            self._expiry[_digest(value)] = now + self.lifetime_s
        return value

    def sign_out(self, value: str) -> None:
        """End the admin session ``value`` (unknown values are ignored)."""
        with self._lock:
            self._expiry.pop(_digest(value), None)

    def session_ok(self, value: str) -> bool:
        """Whether ``value`` is a live admin session."""
        with self._lock:
            expiry = self._expiry.get(_digest(value))
        return expiry is not None and expiry > time.monotonic()

    def authorised(self, request: Request) -> bool:
        """Whether the request carries the token as a bearer header or a live admin session."""
        if not self.enabled:
            return False
        header = request.headers.get("authorization", "")
        if header.lower().startswith("bearer "):
            return self.token_ok(header[7:])
        return self.session_ok(request.cookies.get(ADMIN_COOKIE, ""))

    def set_cookie(self, response: Response, value: str, *, secure: bool) -> None:
        """Give ``response`` the admin session cookie (``Secure`` if ``secure``)."""
        response.set_cookie(
            ADMIN_COOKIE,
            value,
            max_age=int(self.lifetime_s),
            path=ADMIN_COOKIE_PATH,
            httponly=True,
            samesite="strict",
            secure=secure,
        )

    @staticmethod
    def clear_cookie(response: Response, *, secure: bool) -> None:
        """Make ``response`` delete the admin session cookie."""
        response.delete_cookie(
            ADMIN_COOKIE, path=ADMIN_COOKIE_PATH, httponly=True, samesite="strict", secure=secure
        )

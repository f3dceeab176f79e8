"""Access to the dashboard: a token (``Authorization: Bearer``) or a login session.

The login form (``/login``) exchanges the token for a random session id in an HttpOnly,
SameSite=Strict cookie that expires (:data:`SESSION_S`); the token itself never goes into a
cookie. The form's body is read up to :data:`LOGIN_BODY_BYTES`, and a client address that
sends :data:`LOGIN_FAILURES` wrong tokens within :data:`LOGIN_WINDOW_S` waits (429).
"""

from __future__ import annotations

import math
import time
from typing import Any

from cnctwin.exceptions import ConfigError

__all__ = ["LOGIN_BODY_BYTES", "LOGIN_FAILURES", "LOGIN_WINDOW_S", "SESSION_S", "TOKEN_COOKIE",
           "add_token_auth"]


TOKEN_COOKIE = "cnctwin_session"
"""Cookie the login form sets (HttpOnly, SameSite=Strict): a random session id, not the
token; it expires after :data:`SESSION_S`."""

SESSION_S = 12 * 3600.0
"""Lifetime of a login session [s] (one shift and a half)."""

LOGIN_BODY_BYTES = 4096
"""Largest ``POST /login`` body read [bytes]; a longer one is refused (413) unread."""

LOGIN_FAILURES = 5
"""Wrong tokens allowed per client address within :data:`LOGIN_WINDOW_S` before 429."""

LOGIN_WINDOW_S = 60.0


class _Sessions:
    """Login sessions of one dashboard: random ids with an expiry, and failed logins per
    client address (throttled)."""

    def __init__(self, *, lifetime_s: float = SESSION_S, max_sessions: int = 1000) -> None:
        self.lifetime_s = lifetime_s
        self.max_sessions = max_sessions
        self._ids: dict[str, float] = {}
        self._failures: dict[str, list[float]] = {}

    def new(self) -> str:
        import secrets

        now = time.monotonic()
        self._ids = {k: v for k, v in self._ids.items() if v > now}
        while len(self._ids) >= self.max_sessions:  # the oldest goes first
            self._ids.pop(next(iter(self._ids)))
        sid = secrets.token_urlsafe(32)
        self._ids[sid] = now + self.lifetime_s
        return sid

    def valid(self, sid: str | None) -> bool:
        if not sid:
            return False
        exp = self._ids.get(sid)
        if exp is None:
            return False
        if exp <= time.monotonic():
            self._ids.pop(sid, None)
            return False
        return True

    def blocked_s(self, client: str) -> float:
        """Seconds until ``client`` may try again (0: now)."""
        now = time.monotonic()
        recent = [t for t in self._failures.get(client, []) if t > now - LOGIN_WINDOW_S]
        self._failures[client] = recent
        if len(recent) < LOGIN_FAILURES:
            return 0.0
        return max(recent[0] + LOGIN_WINDOW_S - now, 1.0)

    def failed(self, client: str) -> None:
        self._failures.setdefault(client, []).append(time.monotonic())
        if len(self._failures) > 10_000:  # addresses that stopped trying
            self._failures = {k: v for k, v in self._failures.items()
                              if v and v[-1] > time.monotonic() - LOGIN_WINDOW_S}


def add_token_auth(app: Any, token: str, title: str) -> None:
    """401 for every request without the token (header) or a login session (cookie);
    ``/login`` form (body read up to :data:`LOGIN_BODY_BYTES`, failures throttled).

    Parameters
    ----------
    app : fastapi.FastAPI
        The dashboard app; gets the middleware, ``GET``/``POST /login`` and
        ``app.state.sessions``.
    token : str
        The access token (at least 16 characters).
    title : str
        The dashboard's name on the login form.

    Returns
    -------
    None

    Raises
    ------
    ConfigError
        For a token shorter than 16 characters.
    """
    import hmac
    import html

    from fastapi import Request
    from fastapi.responses import HTMLResponse, RedirectResponse, Response

    if len(token) < 16:
        raise ConfigError("the dashboard token must have at least 16 characters "
                          "(e.g. python -c 'import secrets; print(secrets.token_urlsafe(24))')")
    expected = token.encode("utf-8")
    sessions = _Sessions()
    app.state.sessions = sessions

    def ok(value: str | None) -> bool:
        return value is not None and hmac.compare_digest(value.encode("utf-8"), expected)

    def login_page(message: str = "") -> str:
        note = f"<p style='color:#b3261e'>{html.escape(message)}</p>" if message else ""
        return (f"<!doctype html><html lang='en'><head><meta charset='utf-8'>"
                f"<title>{html.escape(title)}: sign in</title></head>"
                "<body style='font-family:system-ui,sans-serif;max-width:28em;margin:4em auto'>"
                f"<h1>{html.escape(title)}</h1><p>This dashboard needs its access token "
                "(<code>--token-file</code> / <code>CNCTWIN_WEB_TOKEN</code> of "
                f"<code>cnctwin web</code>).</p>{note}"
                "<form method='post' action='/login'><label>token "
                "<input name='token' type='password' autocomplete='current-password' "
                "autofocus></label> <button type='submit'>sign in</button></form>"
                "</body></html>")

    @app.middleware("http")
    async def _auth(request: Request, call_next: Any) -> Any:
        if request.url.path == "/login":
            return await call_next(request)
        auth = request.headers.get("authorization", "")
        bearer = auth[7:].strip() if auth.lower().startswith("bearer ") else None
        if ok(bearer) or sessions.valid(request.cookies.get(TOKEN_COOKIE)):
            return await call_next(request)
        if request.url.path.startswith("/api/") or "text/html" not in request.headers.get(
                "accept", ""):
            return Response(b'{"detail":"authentication required: send Authorization: '
                            b'Bearer TOKEN"}', status_code=401, media_type="application/json",
                            headers={"WWW-Authenticate": "Bearer"})
        return HTMLResponse(login_page(), status_code=401,
                            headers={"WWW-Authenticate": "Bearer"})

    @app.get("/login", response_class=HTMLResponse, include_in_schema=False)
    def _login_form() -> Any:
        return HTMLResponse(login_page())

    async def _login(request: Request) -> Any:
        from urllib.parse import parse_qs

        client = request.client.host if request.client is not None else "?"
        wait = sessions.blocked_s(client)
        if wait:
            return HTMLResponse(login_page(f"too many wrong tokens: try again in "
                                           f"{wait:.0f} s"), status_code=429,
                                headers={"Retry-After": str(math.ceil(wait))})
        too_big = HTMLResponse(login_page(f"the form is larger than {LOGIN_BODY_BYTES} "
                                          "bytes"), status_code=413)
        try:
            if int(request.headers.get("content-length", "0")) > LOGIN_BODY_BYTES:
                return too_big
        except ValueError:
            return HTMLResponse(login_page("bad Content-Length"), status_code=400)
        body = b""
        async for part in request.stream():  # chunked bodies too: never more than the limit
            body += part
            if len(body) > LOGIN_BODY_BYTES:
                return too_big
        given = parse_qs(body.decode("utf-8", "replace")).get("token", [""])[0]
        if not ok(given):
            sessions.failed(client)
            return HTMLResponse(login_page("wrong token"), status_code=401)
        resp = RedirectResponse("/", status_code=303)
        resp.set_cookie(TOKEN_COOKIE, sessions.new(), httponly=True, samesite="strict",
                        secure=request.url.scheme == "https", max_age=int(SESSION_S))
        return resp

    # the annotations are strings here (postponed evaluation) and Request is a local name:
    # give FastAPI the class itself, or it takes ``request`` for a query parameter
    _login.__annotations__["request"] = Request
    app.post("/login", include_in_schema=False)(_login)

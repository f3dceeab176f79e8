"""Nobody let in: the dashboard's access token (issue 14, point 3: the dashboard).

Every page, asset and API endpoint answers 401 without the token and works with it (the
``Authorization: Bearer`` header or the cookie of the ``/login`` form); ``cnctwin web`` on a
non-loopback host refuses to start without a token unless ``--insecure``; a real headless
Chromium gets the login form, not the dashboard.
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from cnctwin.cli import main
from tests._services import free_port

pytest.importorskip("fastapi", reason="the web extra: pip install 'cnctwin[web]'")
from fastapi.testclient import TestClient

from cnctwin.web.app import create_app

TOKEN = "s3cret-token-for-the-tests-0123456789"
ROOT = Path(__file__).resolve().parents[2]
TRACE = ROOT / "tests" / "data" / "real" / "sinumerik-trace"


def _paths(app: object) -> list[str]:
    out = []
    for route in app.routes:  # type: ignore[attr-defined]
        path = getattr(route, "path", "")
        if not path or path == "/login" or "GET" not in getattr(route, "methods", {"GET"}):
            continue
        out.append(re.sub(r"\{[^}]+\}", "x", path))
    return out


def test_every_endpoint_needs_the_token() -> None:
    app = create_app(recordings=[TRACE], token=TOKEN)
    paths = _paths(app)
    assert {"/", "/api/recordings", "/api/machines", "/healthz", "/static/x"} <= set(paths)
    paths += ["/static/app.js", "/static/plotly.min.js", "/no/such/page"]
    with TestClient(app) as client:
        for path in paths:
            r = client.get(path)
            assert r.status_code == 401, path
            r = client.get(path, headers={"Authorization": "Bearer wrong-" + TOKEN})
            assert r.status_code == 401, path
        ok = {"Authorization": f"Bearer {TOKEN}"}
        assert client.get("/api/recordings", headers=ok).status_code == 200
        assert client.get("/", headers=ok).status_code == 200
        assert client.get("/healthz", headers=ok).status_code == 200
        page = client.get("/", headers={"Accept": "text/html"})
        assert page.status_code == 401 and "sign in" in page.text


def test_login_form_sets_the_cookie() -> None:
    app = create_app(recordings=[TRACE], token=TOKEN)
    with TestClient(app) as client:
        bad = client.post("/login", data={"token": "nope"}, follow_redirects=False)
        assert bad.status_code == 401 and "wrong token" in bad.text
        good = client.post("/login", data={"token": TOKEN}, follow_redirects=False)
        assert good.status_code == 303
        cookie = good.headers["set-cookie"]
        assert "HttpOnly" in cookie and "SameSite=strict" in cookie.replace("Strict", "strict")
        assert client.get("/api/recordings").status_code == 200  # the cookie is sent now


def test_the_cookie_is_a_session_that_expires_not_the_token(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 24, pt 8: the login cookie was the raw long-lived token."""
    import cnctwin.web.auth as auth

    app = create_app(recordings=[TRACE], token=TOKEN)
    with TestClient(app) as client:
        good = client.post("/login", data={"token": TOKEN}, follow_redirects=False)
        cookie = good.headers["set-cookie"]
        assert TOKEN not in cookie and f"Max-Age={int(auth.SESSION_S)}" in cookie
        assert client.get("/api/recordings").status_code == 200
        now = time.monotonic()
        monkeypatch.setattr(auth.time, "monotonic", lambda: now + auth.SESSION_S + 1)
        assert client.get("/api/recordings").status_code == 401  # expired


def test_wrong_tokens_are_throttled() -> None:
    """Five wrong tokens from one address within a minute: the sixth try waits (429), even
    with the right token; other clients (the bearer header) are not affected."""
    import cnctwin.web.auth as auth

    app = create_app(recordings=[TRACE], token=TOKEN)
    with TestClient(app) as client:
        for _ in range(auth.LOGIN_FAILURES):
            assert client.post("/login", data={"token": "guess"}).status_code == 401
        r = client.post("/login", data={"token": TOKEN}, follow_redirects=False)
        assert r.status_code == 429 and int(r.headers["Retry-After"]) >= 1
        assert "try again in" in r.text
        ok = {"Authorization": f"Bearer {TOKEN}"}
        assert client.get("/api/recordings", headers=ok).status_code == 200


def test_login_reads_a_few_kb_at_most() -> None:
    """Issue 24, pt 7: a 300 MB login body raised the process to 1.75 GB. A body over 4 kB is
    refused unread (declared length) or after 4 kB (streamed without a length)."""
    app = create_app(recordings=[TRACE], token=TOKEN)
    with TestClient(app) as client:
        big = client.post("/login", content=b"token=" + b"x" * 10_000_000,
                          headers={"Content-Type": "application/x-www-form-urlencoded"})
        assert big.status_code == 413

        def chunks():  # no Content-Length: chunked transfer
            for _ in range(1000):
                yield b"x" * 10_000

        streamed = client.post("/login", content=chunks(),
                               headers={"Content-Type": "application/x-www-form-urlencoded"})
        assert streamed.status_code == 413
        assert client.post("/login", data={"token": TOKEN},
                           follow_redirects=False).status_code == 303


def test_short_tokens_are_refused() -> None:
    from cnctwin.exceptions import ConfigError

    with pytest.raises(ConfigError, match="16 characters"):
        create_app(recordings=[TRACE], token="short")


def test_cli_refuses_a_network_host_without_a_token(
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CNCTWIN_WEB_TOKEN", raising=False)
    assert main(["web", "--recording", str(TRACE), "--host", "0.0.0.0"]) == 2
    err = capsys.readouterr().err
    assert "faces the network" in err and "--insecure" in err


@pytest.mark.browser
def test_a_real_browser_gets_the_login_form(tmp_path: Path) -> None:
    from tests.web.test_browser import _dump_dom

    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n", encoding="utf-8")
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "cnctwin", "web", "--recording", str(TRACE),
                             "--port", str(port), "--token-file", str(token_file)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 30
        while True:
            req = urllib.request.Request(url + "/healthz",
                                         headers={"Authorization": f"Bearer {TOKEN}"})
            try:
                with urllib.request.urlopen(req, timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("cnctwin web did not start") from None
                time.sleep(0.2)
        dom = _dump_dom(url + "/", tmp_path)
        assert "sign in" in dom and "token" in dom
        assert "plotly" not in dom.lower() and "recordings" not in dom.lower()
    finally:
        proc.terminate()
        proc.wait(timeout=10)

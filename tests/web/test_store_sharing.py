"""The dashboard reads a store beside its writers (issue 24, point 5).

DuckDB lets one process hold a catalog file for writing, or several for reading, never both.
Before the fix ``cnctwin web --store`` held the write lock for its whole life, so
``cnctwin ingest``, ``cnctwin query``, ``edge run --store`` and a second dashboard on the same
store failed with a lock error (and a hint to use ``create=True``). Here every one of them runs
as a separate process, as a user starts them, beside a running dashboard.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from typing import Any

from tests._services import free_port


def _start_web(store: Path) -> tuple[subprocess.Popen[bytes], str]:
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "cnctwin", "web", "--store", str(store),
                             "--port", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while True:
        try:
            with urllib.request.urlopen(url + "/healthz", timeout=2) as r:
                if r.status == 200:
                    return proc, url
        except OSError:
            if proc.poll() is not None:
                raise RuntimeError(f"cnctwin web did not start: "
                                   f"{proc.communicate()[1].decode()}") from None
            if time.monotonic() > deadline:
                proc.kill()
                raise RuntimeError("cnctwin web did not answer in 60 s") from None
            time.sleep(0.2)


def _get(url: str) -> str:
    with urllib.request.urlopen(url, timeout=30) as r:
        assert r.status == 200
        return str(r.read().decode("utf-8"))


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "cnctwin", *args], capture_output=True,
                          text=True, timeout=180)


def test_dashboard_beside_ingest_query_edge_run_and_a_second_dashboard(
        store_dir: Path, wear12: dict[str, Any], model_file: Path, tmp_path: Path) -> None:
    store = tmp_path / "store"
    shutil.copytree(store_dir, store)
    web, url = _start_web(store)
    try:
        page = _get(url + "/")
        assert "wear12" in page
        ing = _cli("ingest", str(wear12["path"]), "--store", str(store), "--machine", "mill-2")
        assert ing.returncode == 0, ing.stderr
        rid = ing.stdout.split("\t", 1)[0]
        assert rid in _get(url + "/")  # the dashboard sees the new recording
        q = _cli("query", "--store", str(store))
        assert q.returncode == 0, q.stderr
        assert rid in q.stdout
        run = _cli("edge", "run", "--source", str(wear12["path"]), "--model", str(model_file),
                   "--out", str(tmp_path / "edge"), "--store", str(store), "--quiet",
                   "--no-twin", "--machine", "mill-3")
        assert run.returncode == 0, run.stderr
        page = _get(url + "/")
        assert "edge-mill-3-" in page
        web2, url2 = _start_web(store)
        try:
            assert "edge-mill-3-" in _get(url2 + "/")
            assert "wear12" in _get(url + "/")  # both dashboards serve at once
        finally:
            web2.terminate()
            web2.wait(timeout=10)
    finally:
        web.terminate()
        web.wait(timeout=10)


def test_query_on_a_missing_store_says_how_to_make_one(tmp_path: Path) -> None:
    res = _cli("query", "--store", str(tmp_path / "nowhere"))
    assert res.returncode != 0 and "Traceback" not in res.stderr
    assert "cnctwin ingest" in res.stderr and "create=True" not in res.stderr


def test_ingest_waits_for_a_store_another_process_writes(store_dir: Path, wear12: dict,
                                                          tmp_path: Path) -> None:
    """A writer that holds the store for 3 s: ``ingest`` waits for it (bounded by --wait)
    instead of failing at once; with --wait 0.5 it fails with a message saying why."""
    store = tmp_path / "store"
    shutil.copytree(store_dir, store)
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time, cnctwin.store\n"
         f"st = cnctwin.store.open({str(store)!r})\n"
         "print('held', flush=True)\n"
         "time.sleep(3)\n"
         "st.close()\n"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        quick = _cli("ingest", str(wear12["path"]), "--store", str(store), "--wait", "0.5")
        assert quick.returncode != 0 and "Traceback" not in quick.stderr
        assert "is held by process" in quick.stderr and "waited 0.5 s" in quick.stderr
        t0 = time.monotonic()
        res = _cli("ingest", str(wear12["path"]), "--store", str(store))
        assert res.returncode == 0, res.stderr
        assert time.monotonic() - t0 < 60
    finally:
        holder.wait(timeout=30)

"""End to end: `cnctwin web` started as a server on a free port, pages rendered by headless
Chromium; the DOM must hold the plots drawn by plotly.js (served locally, no network)."""

from __future__ import annotations

import contextlib
import json
import os
import re
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests._services import free_port, require_tool

pytestmark = pytest.mark.browser


@contextlib.contextmanager
def _serve(args: list[str], log_path: Path) -> Iterator[str]:
    """`cnctwin web ARGS --port P` as a process; yields its URL once /healthz answers."""
    port = free_port()
    log = log_path.open("w")
    proc = subprocess.Popen([sys.executable, "-m", "cnctwin", "web", *args, "--port", str(port)],
                            stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                with urllib.request.urlopen(url + "/healthz", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    log.flush()
                    raise RuntimeError(f"cnctwin web did not start (exit {proc.poll()}); "
                                       f"see {log.name}") from None
                time.sleep(0.2)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()


@pytest.fixture(scope="module")
def server(wear12: dict[str, Any], c4a_file: Path, model_file: Path, live_dir: Path,
           tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with _serve(["--recording", str(wear12["path"]), "--recording", str(c4a_file),
                 "--model", str(model_file), "--live", str(live_dir)],
                tmp_path_factory.mktemp("srv") / "server.log") as url:
        yield url


def _dump_dom(url: str, tmp_path: Path) -> str:
    chromium = require_tool("chromium", install="apt-get install chromium "
                            "(scripts/ensure-services.sh does it as root)")
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}",
           "--virtual-time-budget=20000", "--window-size=1400,1600", "--dump-dom", url]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=90,
                         env={**os.environ, "HOME": str(tmp_path)})
    assert res.returncode == 0, res.stderr[-2000:]
    return res.stdout


def test_recording_page_draws_the_plot(server: str, tmp_path: Path) -> None:
    dom = _dump_dom(server + "/recordings/file:0", tmp_path)
    # plotly.js ran (its SVG root is there) and drew the two default signals
    assert dom.count('class="main-svg"') >= 2
    points = int(re.search(r'id="plot"[^>]*data-points="(\d+)"', dom)  # type: ignore[union-attr]
                 .group(1))
    assert 0 < points <= 2 * (2 * 4000 + 2)
    info = re.search(r'id="plot-info"[^>]*>([^<]*)<', dom).group(1)  # type: ignore[union-attr]
    assert "CURRENT|SP1" in info and "of 26169 samples" in info and "error" not in info
    # the use-case section filled from the API: 12 holes (the simulated program)
    assert re.search(r'id="holes-info"[^>]*>12 holes', dom)
    assert dom.count("<tr>") > 12
    # issue 24, pt 8: the wear plot's right axis read 0.399/0.214/0.028 % (ticks synced to
    # the left axis' grid); now round numbers, and whole hole numbers on the x axis
    y2 = [float(v) for v in re.findall(
        r'class="y2tick"><text[^>]*data-unformatted="([-\d.e]+)"', dom)]
    assert len(y2) >= 3
    assert all(abs(v * 20 - round(v * 20)) < 1e-6 * max(1.0, abs(v * 20))
               or abs(v - round(v, 1)) < 1e-9 for v in y2), y2


def test_overview_page(server: str, tmp_path: Path) -> None:
    dom = _dump_dom(server + "/", tmp_path)
    assert "sinumerik_adapter_840Dsl" in dom and "1 (7.72 s)" in dom
    # issue 24, pt 8: the recordings table was wider than a 1400 px window
    width = int(re.search(r'data-scroll-width="(\d+)"', dom).group(1))  # type: ignore[union-attr]
    assert width <= 1400, width


def test_live_page_receives_events(server: str, tmp_path: Path, live_dir: Path) -> None:
    # limit = every line of the finished run: the stream then ends with an `end` event and
    # the page closes its EventSource (an open stream would keep the headless page loading)
    # (the last line, the final status, is left out: that one ends the stream as finished)
    n = len((live_dir / "results.jsonl").read_text().splitlines()) - 1
    dom = _dump_dom(server + f"/live?limit={n}", tmp_path)
    assert "stream ended" in dom
    # the drawn x axis (plotly's tick labels) shows the last 30 s of the 52 s run
    ticks = [float(t) for t in re.findall(r'class="xtick"><text[^>]*data-unformatted="([-\d.]+)"',
                                          dom)]
    assert ticks and min(ticks) >= 22.0 and 45.0 <= max(ticks) <= 52.4
    table = re.search(r'<table id="live-holes">(.*?)</table>', dom, re.S).group(1)  # type: ignore[union-attr]
    assert table.count("<tr>") == 1 + 12  # header + the 12 holes of the run
    # the tool's life after its last hole: 12 used of the 40 planned, 28 left, and the time
    # left at its hole period (~4 s per hole in the wear program: 28 x 4 s ~ 2 min)
    tools = re.search(r'<table id="live-tools">(.*?)</table>', dom, re.S).group(1)  # type: ignore[union-attr]
    cells = re.findall(r"<td>(.*?)</td>", tools)
    assert cells[:4] == ["T1", "D20 HSS", "12", "40"], cells
    assert cells[6].startswith("28 (90 %: 28") and cells[7] == "2 min", cells
    assert cells[8] == "usage"


def test_live_page_of_a_finished_run_shows_its_final_counts(server: str, tmp_path: Path,
                                                            live_dir: Path) -> None:
    """Issue 24, pt 7/8: without ``limit`` the page of a finished run loaded forever (the
    docs' screenshot recipe hung) and did not show the final counts. Now the stream ends
    after the run's final status and the page shows it."""
    dom = _dump_dom(server + "/live", tmp_path)
    assert re.search(r'id="live-state"[^>]*data-finished="true"', dom), dom[-3000:]
    assert "run finished" in dom
    status = re.search(r'<dl id="live-status"[^>]*>(.*?)</dl>', dom, re.S).group(1)  # type: ignore[union-attr]
    assert "<dt>state</dt><dd>finished</dd>" in status
    assert "<dt>holes</dt><dd>12</dd>" in status
    assert "e+" not in status  # 127031 cycles/s, not 1.2703e+5


def test_api_docs_page_renders_without_a_cdn(server: str, tmp_path: Path) -> None:
    # every asset of the page is served by the dashboard itself (the machine has no internet,
    # so a CDN reference would leave the page empty)
    with urllib.request.urlopen(server + "/api/docs", timeout=10) as r:
        html = r.read().decode()
    assert not re.search(r"""(src|href)=["']?https?://""", html), html
    dom = _dump_dom(server + "/api/docs", tmp_path)
    # Swagger UI ran and listed the operations of openapi.json
    assert "swagger-ui" in dom and "opblock" in dom
    assert "/api/recordings" in dom


def test_live_page_starts_a_new_view_for_a_new_run(wear12: dict[str, Any], model_file: Path,
                                                    tmp_path: Path) -> None:
    # issue 14: a second `edge run` into the same --out appended to the same results, and the
    # live page drew both runs over each other (time running backwards). Each run now begins
    # with a `run` message and the page starts a new view on it.
    from cnctwin.cli import main

    live = tmp_path / "live"
    for _ in range(2):
        assert main(["edge", "run", "--source", str(wear12["path"]), "--model",
                     str(model_file), "--out", str(live), "--quiet", "--learn-s", "2"]) == 0
    lines = [json.loads(x) for x in (live / "results.jsonl").read_text().splitlines()]
    starts = [k for k, m in enumerate(lines) if m["kind"] == "run"]
    assert len(starts) == 2 and starts[0] == 0
    seqs = [m["seq"] for m in lines]
    assert seqs == sorted(set(seqs))  # seq goes on across the runs
    n_points_one_run = sum(m["n"] for m in lines[starts[1]:] if m["kind"] == "torque")
    with _serve(["--live", str(live)], tmp_path / "server.log") as url:
        dom = _dump_dom(url + f"/live?limit={len(lines)}", tmp_path)
    assert "run finished" in dom  # the last line is the second run's final status
    assert dom.count("run started") == 2
    table = re.search(r'<table id="live-holes">(.*?)</table>', dom, re.S).group(1)  # type: ignore[union-attr]
    assert table.count("<tr>") == 1 + 12  # the second run's 12 holes, not 24
    points = int(re.search(r'id="live-plot"[^>]*data-points="(\d+)"', dom)  # type: ignore[union-attr]
                 .group(1))
    assert 0 < points <= min(n_points_one_run, 30 * 500 + 1)  # one run, last 30 s window


def _screenshot(url: str, tmp_path: Path, name: str) -> Path:
    """A PNG of the page as headless Chromium draws it (kept with the test's files; copied to
    $CNCTWIN_SCREENSHOTS when that names a folder, to look at them)."""
    chromium = require_tool("chromium", install="apt-get install chromium "
                            "(scripts/ensure-services.sh does it as root)")
    png = tmp_path / f"{name}.png"
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", "--hide-scrollbars", f"--user-data-dir={tmp_path / 'profile-png'}",
           "--virtual-time-budget=20000", "--window-size=1400,1000", f"--screenshot={png}", url]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=90,
                         env={**os.environ, "HOME": str(tmp_path)})
    assert res.returncode == 0 and png.exists(), res.stderr[-2000:]
    keep = os.environ.get("CNCTWIN_SCREENSHOTS")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        (Path(keep) / png.name).write_bytes(png.read_bytes())
    return png


def _visible_text(dom: str) -> str:
    """The page's text without scripts and without the reader's notes (prose that may name
    NaN, e.g. "0 non-numeric kept as text only (value NaN)")."""
    dom = re.sub(r"<script.*?</script>|<style.*?</style>|<details>.*?</details>", " ", dom,
                 flags=re.S)
    return re.sub(r"<[^>]+>", " ", dom)


_REPRS = re.compile(r"\bNone\b|\bnan\b|\bNaN\b|\{'|<cnctwin\.|Timestamp\(|array\(|dtype")


@pytest.fixture(scope="module")
def plant_server(live_dir: Path, wear12: dict[str, Any], model_file: Path, c4a_file: Path,
                 tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """Two machines: the finished edge run and one whose runtime went silent."""
    silent = tmp_path_factory.mktemp("plant") / "M2-silent"
    silent.mkdir()
    (silent / "status.json").write_text(json.dumps({
        "machine": "DMU-2", "state": "running", "updated": "2026-01-01T00:00:00Z",
        "cycles": 5, "holes": 0, "alarms": 0}))
    with _serve(["--live", str(live_dir), "--live", str(silent), "--recording",
                 str(wear12["path"]), "--recording", str(c4a_file), "--model",
                 str(model_file)],
                tmp_path_factory.mktemp("srv-plant") / "server.log") as url:
        yield url


def test_plant_page_in_the_browser(plant_server: str, tmp_path: Path) -> None:
    """Issue 16, point 3: status per machine at a glance, checked as Chromium draws it."""
    dom = _dump_dom(plant_server + "/plant", tmp_path)
    tiles = dict((m, st) for st, m in re.findall(
        r'class="tile state-(\w+)" data-machine="([^"]+)"', dom))
    # labelled by the machine each status.json names (issue 24, pt 8: not the folder name)
    assert sorted(tiles.values()) == ["finished", "stale"] and tiles["DMU-2"] == "stale"
    text = _visible_text(dom)
    assert "no status for" in text  # the stale machine says why
    assert not _REPRS.search(text), _REPRS.search(text)
    png = _screenshot(plant_server + "/plant", tmp_path, "plant")
    import matplotlib.image as mpimg
    import numpy as np

    img = mpimg.imread(png)[..., :3]
    assert img.shape[0] >= 900 and img.shape[1] >= 1300
    # the stale tile's orange border (#b25e00) is drawn: the colours carry the state
    orange = np.all(np.abs(img - np.array([0xB2, 0x5E, 0x00]) / 255) < 0.06, axis=-1)
    assert orange.sum() > 200


def test_pages_show_no_python_reprs_and_a_time_range(plant_server: str, tmp_path: Path) -> None:
    """No None/nan/dict reprs on any page; a recording page opened with a time range draws
    that range at full resolution and shows it in the range picker."""
    # (the live page with a limit: its event stream then ends and the page finishes loading)
    for path in ("/", "/live?limit=20", "/recordings/file:0"):
        text = _visible_text(_dump_dom(plant_server + path, tmp_path))
        assert not _REPRS.search(text), (path, _REPRS.search(text))
    dom = _dump_dom(plant_server + "/recordings/file:0?start_s=10&end_s=12", tmp_path)
    info = re.search(r'id="plot-info"[^>]*>([^<]*)<', dom).group(1)  # type: ignore[union-attr]
    assert "(full resolution)" in info  # 2 s = 1000 samples fit the plot width
    assert re.search(r'id="range-start"[^>]*value="10.000"', dom)
    assert re.search(r'id="range-end"[^>]*value="12.000"', dom)
    _screenshot(plant_server + "/recordings/file:0?start_s=10&end_s=12", tmp_path, "recording")
    # a recording without drilling (the real Capture4Analysis file): no empty table or plot
    dom = _dump_dom(plant_server + "/recordings/file:1", tmp_path)
    assert re.search(r'id="holes-info"[^>]*>0 holes', dom)
    for name in ("holes-table", "trend-plot", "temperature-plot"):
        assert re.search(rf'id="{name}"[^>]*style="display: none;"', dom), name


def test_compare_page_draws_the_twin_curves(wear12: dict[str, Any], tmp_path: Path) -> None:
    """Issue 24, pt 8: the web compare page had only the table; the CLI's compare.html has
    the following-error and current curves of machine and twin per axis. Now the page draws
    them (plotly in Chromium)."""
    from cnctwin.machine import MachineFile, save_machine

    machine = save_machine(MachineFile(), tmp_path / "machine.toml")
    with _serve(["--recording", str(wear12["path"]), "--machine", str(machine)],
                tmp_path / "server.log") as url:
        dom = _dump_dom(url + "/recordings/file:0/compare", tmp_path)
    plots = re.findall(r'class="plot compare-plot[^"]*" data-axis="(\w+)"[^>]*'
                       r'data-points="(\d+)"', dom)
    assert {a for a, _ in plots} == {"X1", "Y1", "Z1"}, plots
    assert all(int(n) > 1000 for _, n in plots)
    assert dom.count('class="main-svg"') >= 3

"""The plant at a glance (issue 16, point 3): a status per machine from each edge runtime's
state directory, with the rules of :mod:`cnctwin.web.plant` checked on state directories
written here (every state), on a real finished `cnctwin edge run`, and through the API."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest

from cnctwin.web.live import LiveSource
from cnctwin.web.plant import PlantStatusOptions, machine_state

NOW = 1_764_150_000.0  # 2025-11-26T09:40:00Z


def _iso(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 1e6):06d}Z"


def _state_dir(tmp_path: Path, name: str, *, status: dict[str, Any] | None,
               messages: list[dict[str, Any]]) -> LiveSource:
    d = tmp_path / name
    d.mkdir()
    if status is not None:
        (d / "status.json").write_text(json.dumps({"machine": name, **status}))
    (d / "results.jsonl").write_text("".join(json.dumps(m) + "\n" for m in messages))
    return LiveSource(d)


def _torque(t: float, cycle: int, value: float) -> dict[str, Any]:
    return {"kind": "torque", "cycle": cycle, "time": _iso(t), "first_cycle": cycle, "n": 3,
            "torque_nm": [value, value, None], "speed_rpm": [2400.0, 2400.0, 2400.0]}


RUNNING = {"state": "running", "updated": _iso(NOW - 1), "data_age_s": 0.2, "cycles": 10,
           "holes": 1, "alarms": 0}


def test_every_state_by_its_rule(tmp_path: Path) -> None:
    run = {"kind": "run", "cycle": -1}
    hole = {"kind": "hole", "cycle": 900, "time": _iso(NOW - 20), "hole": 4,
            "row": {"depth_mm": 20.0, "torque_mean_nm": 3.7}}
    cases = {
        "waiting": (None, []),
        "finished": ({**RUNNING, "state": "finished"}, [run]),
        "stale": ({**RUNNING, "updated": _iso(NOW - 30)}, [run]),
        "silent": ({**RUNNING, "data_age_s": 45.0}, [run]),
        "alarm": (RUNNING, [run, {"kind": "alarm", "cycle": 950, "time": _iso(NOW - 30),
                                  "detector": "PhysicsResidualDetector", "score": 7.5},
                            _torque(NOW - 2, 1000, 0.1)]),
        "old-alarm": (RUNNING, [run, {"kind": "alarm", "cycle": 950, "time": _iso(NOW - 300),
                                      "detector": "X", "score": 7.5},
                                _torque(NOW - 2, 1000, 0.1)]),
        "cutting-hole": (RUNNING, [run, hole, {"kind": "hole_start", "cycle": 990},
                                   _torque(NOW - 2, 1000, 0.1)]),
        "cutting-torque": (RUNNING, [run, hole, _torque(NOW - 2, 1000, 3.7)]),
        # an alarm of an earlier run of the runtime does not count
        "new-run": (RUNNING, [{"kind": "alarm", "cycle": 5, "time": _iso(NOW - 5),
                               "detector": "X", "score": 9.0}, run,
                              _torque(NOW - 2, 1000, 0.1)]),
    }
    want = {"waiting": "waiting", "finished": "finished", "stale": "stale", "silent": "stale",
            "alarm": "alarm", "old-alarm": "running", "cutting-hole": "cutting",
            "cutting-torque": "cutting", "new-run": "running"}
    for name, (status, messages) in cases.items():
        st = machine_state(_state_dir(tmp_path, name, status=status, messages=messages),
                           now_s=NOW)
        assert st["state"] == want[name], (name, st["reason"])
        json.dumps(st, allow_nan=False)  # strict JSON for the API
    st = machine_state(LiveSource(tmp_path / "cutting-torque"), now_s=NOW)
    assert st["torque"]["torque_mean_nm"] == pytest.approx(3.7)  # the None value is skipped
    assert st["hole"] == {"time": hole["time"], "hole": 4, "depth_mm": 20.0,
                          "torque_mean_nm": 3.7, "partial": False}
    assert st["status_age_s"] == pytest.approx(1.0, abs=1e-3)
    loose = machine_state(LiveSource(tmp_path / "stale"), now_s=NOW,
                          options=PlantStatusOptions(stale_s=60.0))
    assert loose["state"] == "running"


def test_a_finished_edge_run(live_dir: Path) -> None:
    """The real `cnctwin edge run` of the 12-hole wear run (tests/web/conftest.py)."""
    st = machine_state(LiveSource(live_dir))
    assert st["state"] == "finished" and st["holes"] == 12
    assert st["hole"]["hole"] == 11 and 19.0 < st["hole"]["depth_mm"] < 21.0
    assert st["torque"] is not None


def test_plant_api_page_and_tiles(tmp_path: Path, live_dir: Path) -> None:
    from fastapi.testclient import TestClient

    from cnctwin.web import create_app

    idle = _state_dir(tmp_path, "M2", status={**RUNNING, "updated": _iso(time.time())},
                      messages=[_torque(time.time(), 10, 0.05)])
    app = create_app(live={"M1": live_dir, "M2": idle.directory})
    with TestClient(app) as client:
        rows = client.get("/api/plant").json()
        assert [(r["label"], r["state"]) for r in rows] == [("M1", "finished"),
                                                            ("M2", "running")]
        page = client.get("/plant").text
        assert page.count('class="tile state-') == 2 and "2 machines: 1 running, 1 finished" \
            in page
        assert "None" not in page and "nan" not in page.lower()
        tiles = client.get("/plant/tiles").text
        assert 'data-machine="M2"' in tiles and "none yet" in tiles  # M2 has no hole yet
        live = client.get("/live", params={"machine": "M2"}).text
        assert '<option value="M2" selected>' in live
        bad = client.get("/api/live/status", params={"machine": "M3"})
        assert bad.status_code == 422 and "known: M1, M2" in bad.json()["detail"]
        overview = client.get("/").text
        assert "Plant now" in overview and "<h2>Recordings</h2>" not in overview


def test_a_malformed_state_directory_degrades_one_tile(tmp_path: Path, live_dir: Path) -> None:
    """Issue 24, pt 7: a malformed value in one machine's state directory (a hand-edited or
    half-migrated file) made `/`, `/plant` and `/plant/tiles` answer 500 for the whole plant.
    Now that machine's tile says what is wrong with which file; the others are untouched."""
    from fastapi.testclient import TestClient

    from cnctwin.web import create_app

    good = _state_dir(tmp_path, "good", status={**RUNNING, "updated": _iso(time.time())},
                      messages=[_torque(time.time(), 10, 0.05)])
    cases: dict[str, tuple[Any, list[Any]]] = {
        "list-status": ([1, 2], []),
        "text-numbers": ({**RUNNING, "cycles": "many", "holes": {"a": 1}, "alarms": [1],
                          "updated": 12, "data_age_s": "slow"}, []),
        "bad-messages": ({**RUNNING, "updated": _iso(time.time())},
                         [{"kind": "run", "cycle": -1},
                          {"kind": "torque", "cycle": 5, "time": "yesterday",
                           "torque_nm": ["abc", {}], "speed_rpm": "fast"},
                          {"kind": "hole", "cycle": "x", "hole": "three", "row": "nope"},
                          {"kind": "hole_start", "cycle": "later"},
                          {"kind": "alarm", "cycle": 7, "time": 5, "score": "high",
                           "detector": ["x"]},
                          [1, 2, 3], "a string"]),
    }
    dirs = {"good": good.directory}
    for name, (status, messages) in cases.items():
        d = tmp_path / name
        d.mkdir()
        (d / "status.json").write_text(json.dumps(status))
        (d / "results.jsonl").write_text("".join(json.dumps(m) + "\n" for m in messages))
        dirs[name] = d
    app = create_app(live={**dirs, "M1": live_dir})
    with TestClient(app) as client:
        for path in ("/", "/plant", "/plant/tiles", "/api/plant"):
            r = client.get(path)
            assert r.status_code == 200, (path, r.text[:500])
        rows = {r["label"]: r for r in client.get("/api/plant").json()}
        assert rows["good"]["state"] == "running" and rows["M1"]["state"] == "finished"
        for name in cases:
            assert rows[name]["state"] in ("error", "running", "stale"), rows[name]
        assert rows["list-status"]["state"] == "error"
        assert "status.json" in rows["list-status"]["reason"]
        for name in cases:
            live = client.get("/live", params={"machine": name})
            assert live.status_code == 200, name


def test_tiles_are_labelled_by_machine_not_by_a_generic_folder(tmp_path: Path) -> None:
    """Issue 24, pt 8: a plant tile was labelled "state" (the folder of --out .../state)."""
    from cnctwin.web.live import directory_labels

    a = tmp_path / "mill-7" / "state"
    b = tmp_path / "mill-8" / "state"
    c = tmp_path / "lathe" / "out"
    for d in (a, b, c):
        d.mkdir(parents=True)
    (a / "status.json").write_text(json.dumps({"machine": "DMC-7", "state": "running"}))
    (c / "status.json").write_text("[broken")
    labels = directory_labels([a, b, c])
    assert list(labels) == ["DMC-7", "mill-8/state", "lathe/out"]

"""Every JSON endpoint and page of the dashboard (TestClient), on a simulated 12-hole wear run
and on the real Capture4Analysis recording; values are checked against the library
(cnctwin.usecases, the Recording) and against the hidden simulator settings."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from cnctwin.edge import load_spindle_model
from cnctwin.recording import Recording
from cnctwin.usecases.holes import hole_records
from cnctwin.usecases.wear import relative_increase
from cnctwin.web.app import DERIVED_TORQUE
from cnctwin.web.decimate import bucket_starts

SIG = "/api/recordings/{}/signals/{}"


def _sig(client: Any, rid: str, name: str, **params: Any) -> Any:
    from urllib.parse import quote

    return client.get(SIG.format(quote(rid, safe=""), quote(name, safe="")), params=params)


# ---------------------------------------------------------------------- overview
def test_recordings_summary(client: Any, wear12_rec: Recording, real_rec: Recording) -> None:
    r = client.get("/api/recordings")
    assert r.status_code == 200
    wear, real = r.json()
    assert (wear["id"], real["id"]) == ("file:0", "file:1")
    for d, rec in ((wear, wear12_rec), (real, real_rec)):
        assert d["n_cycles"] == rec.n_cycles
        assert d["duration_s"] == pytest.approx(rec.duration_s, abs=1e-9)
        assert d["machine"] == rec.meta.machine
        assert d["n_signals"] == len(rec.columns)
        assert d["end_time"] == pd.Timestamp(rec.hf["time"].iloc[-1]).isoformat()
    # signal-quality accounting of the real file (docs/edge.md: one 3859-cycle gap)
    q = real["quality"]
    assert q["n_gaps"] == 1 and q["missing_cycles"] == 3859
    assert q["effective_rate_hz"] == pytest.approx(500.0 * 3818 / (3818 + 3859))
    assert wear["quality"]["coverage"] == 1.0


def test_machines(client: Any, wear12_rec: Recording, real_rec: Recording) -> None:
    rows = {m["machine"]: m for m in client.get("/api/machines").json()}
    assert set(rows) == {wear12_rec.meta.machine, real_rec.meta.machine}
    real = rows[real_rec.meta.machine]
    assert real["n_recordings"] == 1 and real["n_gaps"] == 1
    assert real["last_activity"] == pd.Timestamp(real_rec.hf["time"].iloc[-1]).isoformat()


def test_recording_detail_and_unknown_id(client: Any, real_rec: Recording) -> None:
    d = client.get("/api/recordings/file:1").json()
    assert d["signals"] == real_rec.columns
    assert d["units"]["CURRENT|SP1"] == real_rec.meta.units["CURRENT|SP1"]
    assert d["issues"] == real_rec.meta.issues
    r = client.get("/api/recordings/file:7")
    assert r.status_code == 404
    assert "file:7" in r.json()["detail"] and "file:0" in r.json()["detail"]


# ---------------------------------------------------------------------- signals
def test_signal_envelope_keeps_bucket_extremes(client: Any, wear12_rec: Recording) -> None:
    px = 600
    d = _sig(client, "file:0", "CURRENT|SP1", px=px).json()
    y_all = wear12_rec.hf["CURRENT|SP1"].to_numpy()
    t_all = wear12_rec.time_s
    assert not d["exact"] and d["n_source"] == y_all.size and d["n_gaps"] == 0
    x, y = np.asarray(d["x"], dtype=float), np.asarray(d["y"], dtype=float)
    assert d["n_points"] == x.size <= 2 * px + 2
    # first and last sample, and the exact min and max of every bucket
    assert (x[0], y[0]) == (t_all[0], y_all[0]) and (x[-1], y[-1]) == (t_all[-1], y_all[-1])
    starts = bucket_starts(y_all.size, px)
    for a, b in itertools.pairwise(starts):
        sel = (x >= t_all[a]) & (x <= t_all[b - 1])
        assert y[sel].min() == y_all[a:b].min() and y[sel].max() == y_all[a:b].max()
    assert d["min"] == y_all.min() and d["max"] == y_all.max()
    assert d["unit"] == "A"


def test_zoom_is_full_resolution(client: Any, wear12_rec: Recording) -> None:
    t = wear12_rec.time_s
    y = wear12_rec.hf["ENC_POS|Z1"].to_numpy()
    d = _sig(client, "file:0", "ENC_POS|Z1", px=1000, start_s=10.0, end_s=12.0).json()
    sel = (t >= 10.0) & (t <= 12.0)
    assert d["exact"] and d["n_source"] == int(sel.sum()) == 1001
    assert np.array_equal(np.asarray(d["x"]), t[sel])
    assert np.array_equal(np.asarray(d["y"]), y[sel])


def test_gap_breaks_the_line_on_the_real_file(client: Any, real_rec: Recording) -> None:
    d = _sig(client, "file:1", "CURRENT|SP1", px=5000).json()  # 3818 samples: exact
    assert d["exact"] and d["n_gaps"] == 1 and d["n_source"] == real_rec.n_cycles
    y = d["y"]
    assert y.count(None) == 1  # one null between the two gap-free runs
    k = y.index(None)
    t = real_rec.time_s
    jump = int(np.flatnonzero(np.diff(real_rec.cycles) > 1)[0])
    assert d["x"][k - 1] == t[jump] and d["x"][k + 1] == t[jump + 1]
    assert t[jump] < d["x"][k] < t[jump + 1]


def test_bad_signal_and_px(client: Any) -> None:
    r = _sig(client, "file:0", "CURRENT|SP9")
    assert r.status_code == 404
    assert "'CURRENT|SP9'" in r.json()["detail"] and "CURRENT|SP1" in r.json()["detail"]
    r = _sig(client, "file:0", "CURRENT|SP1", px=0)
    assert r.status_code == 422 and "px" in r.json()["detail"]
    r = _sig(client, "file:0", DERIVED_TORQUE)
    assert r.status_code == 404 and "--model" in r.json()["detail"]


def test_cutting_torque_signal(model_client: Any, wear12_rec: Recording,
                               model_file: Path) -> None:
    m = load_spindle_model(model_file)
    d = _sig(model_client, "file:0", DERIVED_TORQUE, px=20_000).json()
    assert d["exact"] and d["unit"] == "Nm" and d["n_source"] == wear12_rec.n_cycles
    tau = np.asarray(d["y"], dtype=float)
    cur = wear12_rec.hf["CURRENT|SP1"].to_numpy()
    n = wear12_rec.hf["CMD_SPEED|SP1"].to_numpy()
    # thesis Eq. 4.4 where the speed is constant (dOmega/dt = 0 around the sample):
    # tau_c = Kt I - B n - tau_f sign(n)
    steady = np.zeros(n.size, dtype=bool)
    steady[1:-1] = (n[2:] == n[1:-1]) & (n[:-2] == n[1:-1]) & (np.abs(n[1:-1]) > 100)
    assert steady.sum() > 10_000
    expect = m.kt_nm_per_a * cur - m.b_nm_per_rpm * n - m.tau_f_nm * np.sign(n)
    np.testing.assert_allclose(tau[steady], expect[steady], atol=1e-9)


# ---------------------------------------------------------------------- use cases
def _hole_frame(payload: dict[str, Any]) -> pd.DataFrame:
    return pd.DataFrame(payload["rows"], columns=payload["columns"])


def _assert_rows_equal(got: pd.DataFrame, want: pd.DataFrame) -> None:
    assert list(got.columns) == [str(c) for c in want.columns] and len(got) == len(want)
    for c in want.columns:
        w = want[c]
        if pd.api.types.is_numeric_dtype(w) and not pd.api.types.is_bool_dtype(w):
            np.testing.assert_allclose(got[c].astype(float), w.astype(float), rtol=1e-12,
                                       equal_nan=True, err_msg=c)
        elif pd.api.types.is_datetime64_any_dtype(w):
            assert list(got[c]) == [t.isoformat() for t in w], c
        else:
            assert [None if pd.isna(v) else v for v in w] == list(got[c]), c


def test_holes_equal_library(client: Any, wear12: dict[str, Any],
                             wear12_rec: Recording) -> None:
    d = client.get("/api/recordings/file:0/holes").json()
    want = hole_records([wear12_rec])
    _assert_rows_equal(_hole_frame(d), want)
    # the simulator's hidden program: 12 holes of 20 mm in sets of 6 (thesis §5.1)
    assert d["n_holes"] == 12 == len(wear12["truth"]["holes"])
    np.testing.assert_allclose(want["depth_mm"], 20.0, atol=0.05)
    assert not d["calibrated"] and "not calibrated" in d["spindle_model"]


def test_holes_with_model_equal_library(model_client: Any, wear12_rec: Recording,
                                        model_file: Path) -> None:
    d = model_client.get("/api/recordings/file:0/holes").json()
    want = hole_records([wear12_rec], model=load_spindle_model(model_file))
    _assert_rows_equal(_hole_frame(d), want)
    assert d["calibrated"] and d["model_source"] == str(model_file)


def test_trends(client: Any, wear12_rec: Recording) -> None:
    t = client.get("/api/recordings/file:0/trends").json()
    holes = hole_records([wear12_rec])
    torque = holes["torque_mean_nm"].to_numpy()
    assert t["n_holes"] == 12 and t["hole"] == list(range(12))
    np.testing.assert_allclose(t["torque_mean_nm"], torque, rtol=1e-12)
    np.testing.assert_allclose(t["relative_increase"],
                               relative_increase(torque, baseline=12, set_size=6), rtol=1e-12)
    assert t["set_pattern"]["n_sets"] == 2
    # issue 24, pt 8: a 15-hole moving average over 12 holes is one flat line: left out, said
    assert "torque_ma_nm" not in t and t["window"] == 15
    assert any("15-hole moving average needs at least 15 holes (this has 12)" in n
               for n in t["notes"])
    # the camera readings the simulator writes beside the recording (thermal_camera.csv) are
    # found and calibrate the soft sensor (issue 16, point 3); camera noise 4 °C (simulator
    # ThermalCamera), so a fit of 12 readings within 8 °C RMS
    temp = t["temperature"]
    assert temp is not None and temp["n_points"] == 12 and temp["rmse_c"] < 8.0
    assert all(np.isfinite(temp["predicted_c"]))
    assert len(t["quality"]) == 12


def test_real_file_has_no_holes(client: Any) -> None:
    d = client.get("/api/recordings/file:1/holes").json()
    # docs/edge.md: the real file has no drilling; the one plunge is a positioning move
    assert d["n_holes"] == 0 and any("not a hole" in i for i in d["issues"])
    t = client.get("/api/recordings/file:1/trends").json()
    assert t["n_holes"] == 0 and t["notes"]


def test_anomalies(client: Any) -> None:
    d = client.get("/api/recordings/file:0/anomalies", params={"detector": "physics"}).json()
    assert d["detector"].startswith("PhysicsResidualDetector")
    assert len(d["alarm_holes"]) == len(d["alarms_s"])
    assert d["n_scored"] > 0 and len(d["score_x"]) <= 2 * 1500 + 2
    r = client.get("/api/recordings/file:0/anomalies", params={"detector": "magic"})
    assert r.status_code == 422 and "physics" in r.json()["detail"]


# ---------------------------------------------------------------------- pages
def test_pages(client: Any, real_rec: Recording) -> None:
    home = client.get("/")
    assert home.status_code == 200 and "text/html" in home.headers["content-type"]
    assert 'href="/recordings/file%3A1"' in home.text and real_rec.meta.machine in home.text
    assert "1 (7.72 s)" in home.text  # the real file's gap in the recordings table
    page = client.get("/recordings/file:0")
    assert page.status_code == 200
    assert '<script src="/static/plotly.min.js">' in page.text and 'id="plot"' in page.text
    assert 'value="CURRENT|SP1"' in page.text
    assert client.get("/machines/" + real_rec.meta.machine).status_code == 200
    assert client.get("/machines/nope").status_code == 404
    assert "--live DIR" in client.get("/live").text


def test_static_assets_are_local(client: Any) -> None:
    import plotly

    js = client.get("/static/plotly.min.js")
    bundled = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
    assert js.status_code == 200 and js.content == bundled.read_bytes()
    assert "javascript" in js.headers["content-type"]
    assert client.get("/static/app.js").status_code == 200
    assert client.get("/static/style.css").status_code == 200
    assert client.get("/static/..%2Fapp.py").status_code == 404
    assert "https://" not in client.get("/recordings/file:0").text  # no CDN


# ---------------------------------------------------------------------- store
def test_store_backend(store_dir: Path, wear12_rec: Recording) -> None:
    from fastapi.testclient import TestClient

    from cnctwin.web import create_app

    with TestClient(create_app(store_url=str(store_dir))) as c:
        ids = [d["id"] for d in c.get("/api/recordings").json()]
        assert sorted(ids) == ["store:real", "store:wear12"]
        real = next(d for d in c.get("/api/recordings").json() if d["id"] == "store:real")
        assert real["quality"]["missing_cycles"] == 3859  # from the catalog's metadata
        d = _sig(c, "store:wear12", "CURRENT|SP1", px=1000, start_s=5.0, end_s=6.0).json()
        t = wear12_rec.time_s
        sel = (t >= 5.0) & (t <= 6.0)
        assert d["exact"]
        assert np.array_equal(np.asarray(d["y"]), wear12_rec.hf["CURRENT|SP1"].to_numpy()[sel])
        holes = c.get("/api/recordings/store:wear12/holes").json()
        assert holes["n_holes"] == 12
        mh = c.get(f"/api/machines/{wear12_rec.meta.machine}/holes").json()
        assert mh["n_holes"] == 12 and mh["ids"] == ["store:wear12"]


def test_missing_store_says_what_to_do(tmp_path: Path) -> None:
    from cnctwin.exceptions import StoreError
    from cnctwin.web import create_app

    with pytest.raises(StoreError, match="cnctwin ingest"):
        create_app(store_url=str(tmp_path / "nope"))


def test_no_camera_beside_a_recording_is_said(tmp_path: Path, wear12: dict[str, Any],
                                               model_file: Path) -> None:
    """A recording without camera readings beside it: said, not invented."""
    import shutil

    from fastapi.testclient import TestClient

    from cnctwin.web import create_app

    alone = tmp_path / "alone.json"
    shutil.copy(wear12["path"], alone)
    with TestClient(create_app(recordings=[alone], model=model_file)) as c:
        t = c.get("/api/recordings/file:0/trends").json()
    assert t["temperature"] is None and any("thermal-camera" in n for n in t["notes"])


def test_static_names_that_are_no_file_are_404(client: Any) -> None:
    """Issue 24, pt 7: a name longer than the file system allows answered 500."""
    for name in ("x" * 300, "x" * 5000, "..%2Fapp.py", ".hidden", "app.js.bak"):
        r = client.get(f"/static/{name}")
        assert r.status_code == 404, name
        assert len(r.json()["detail"]) < 200
    assert client.get("/static/app.js").status_code == 200

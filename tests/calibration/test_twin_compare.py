"""The calibrated twin beside the machine, through the command line (issue 12 acceptance).

One hidden machine (seed 101) is calibrated from its campaign; then

* ``cnctwin twin compare`` on a new recording of the same machine (another seed, other feeds
  and stroke): residual_ratio <= 0.2 and not flagged on every moving axis;
* after one hidden change, Y1 Coulomb friction x 1.5 or X1 Kv x 0.8, the changed axis is
  flagged and the other is not;
* ``cnctwin simulate --program`` with the calibrated machine file reproduces the air cut's
  spindle current within the calibrated uncertainty.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cnctwin.analysis.segments import speed_plateaus
from cnctwin.iotools import read_recording
from cnctwin.machine import load_machine
from cnctwin.spindle import air_cut_statistics
from tests.calibration._campaign import calibrate, cli, hidden_machine, sets, simulate_campaign

SEED = 101
pytestmark = pytest.mark.xdist_group("twin_compare")


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    d = tmp_path_factory.mktemp("hidden")
    hidden = hidden_machine(SEED)
    simulate_campaign(d, SEED, hidden)
    calibrate(d, d / "machine.toml")
    return d, hidden


def _compare(d: Path, hidden: dict[str, Any], change: dict[str, Any], tag: str
             ) -> dict[str, Any]:
    rec_dir = d / f"new_{tag}"
    assert cli("simulate", "axis_test", "--out", rec_dir, "--seed", SEED + 7,
               *sets({**hidden, **change}), "--option", 'axes=["X1", "Y1"]',
               "--option", "feeds_mm_min=[750, 1500, 3000, 6000]",
               "--option", "stroke_mm=45") == 0
    out = d / f"cmp_{tag}"
    assert cli("twin", "compare", rec_dir / "axis_test.json", "--machine", d / "machine.toml",
               "--out", out) == 0
    assert (out / "compare.html").stat().st_size > 10_000
    return json.loads((out / "compare.json").read_text(encoding="utf-8"))


def test_unchanged_machine_holds(calibrated: tuple[Path, dict[str, Any]]) -> None:
    d, hidden = calibrated
    doc = _compare(d, hidden, {}, "same")
    assert set(doc["axes"]) == {"X1", "Y1"}
    for axis, res in doc["axes"].items():
        assert res["residual_ratio"] <= 0.2, (axis, res)
        assert res["flagged"] is False, (axis, res["reasons"])
    assert doc["flagged"] == []


@pytest.mark.parametrize(("key", "factor", "changed", "other"), [
    ("axes.Y1.coulomb_n", 1.5, "Y1", "X1"),
    ("axes.X1.kv_m_min_per_mm", 0.8, "X1", "Y1"),
])
def test_hidden_change_is_flagged_on_its_axis(calibrated: tuple[Path, dict[str, Any]],
                                              key: str, factor: float, changed: str,
                                              other: str) -> None:
    d, hidden = calibrated
    base = hidden.get(key, load_machine(d / "machine.toml").value(key))
    doc = _compare(d, hidden, {key: round(float(base) * factor, 5)}, key.replace(".", "_"))
    assert doc["axes"][changed]["flagged"] is True
    assert any(key.rsplit(".", 1)[-1] in r for r in doc["axes"][changed]["reasons"])
    assert doc["axes"][other]["flagged"] is False, doc["axes"][other]["reasons"]


def test_simulate_program_reproduces_the_air_cut(calibrated: tuple[Path, dict[str, Any]]
                                                 ) -> None:
    d, _ = calibrated
    assert cli("simulate", "--program", d / "ac" / "air_cut_sweep.mpf", "--machine",
               d / "machine.toml", "--out", d / "replay", "--seed", 5) == 0
    mf = load_machine(d / "machine.toml")
    a = read_recording(d / "ac" / "air_cut_sweep.json")
    b = read_recording(d / "replay" / "air_cut_sweep.json")
    sa = air_cut_statistics(a, speed_plateaus(a))
    sb = air_cut_statistics(b, speed_plateaus(b))
    rb = mf.record("spindle.viscous_friction_nm_per_rpm")
    assert rb is not None and rb.valid_range is not None
    lo, hi = rb.valid_range
    sa = sa[(sa["speed_rpm"] >= lo) & (sa["speed_rpm"] <= hi)].groupby("speed_rpm").mean()
    sb = sb[(sb["speed_rpm"] >= lo) & (sb["speed_rpm"] <= hi)].groupby("speed_rpm").mean()
    n = sa.index.to_numpy(dtype=np.float64)
    assert len(n) >= 15 and list(sa.index) == list(sb.index)
    ia, ib = sa["current_a"].to_numpy(), sb["current_a"].to_numpy()

    def u(key: str) -> float:
        rec = mf.record(key)
        assert rec is not None and rec.uncertainty is not None
        return rec.uncertainty

    kt = mf.value("spindle.kt_nm_per_a")
    # standard uncertainty of the twin's air current I = (B n + tau_f) / Kt at each speed
    u_i = np.sqrt((u("spindle.viscous_friction_nm_per_rpm") * n) ** 2
                  + u("spindle.coulomb_friction_nm") ** 2
                  + (ib * u("spindle.kt_nm_per_a")) ** 2) / kt
    z = (ib - ia) / u_i
    assert np.all(np.abs(z) <= 2.0), np.c_[n, ia, ib, z]


def test_edge_runtime_uses_the_machine_file(calibrated: tuple[Path, dict[str, Any]]) -> None:
    """``cnctwin edge run --machine machine.toml``: the calibrated spindle's cutting torque
    matches the simulator's true cutting torque over the fully engaged cut (within 2 %)."""
    import pandas as pd

    d, _ = calibrated
    ref = "drill_1_aisi1045_2400rpm_0p16"
    out = d / "edge_state"
    assert cli("edge", "run", "--source", d / "dv" / f"{ref}.json", "--machine",
               d / "machine.toml", "--out", out, "--no-anomaly") == 0
    msgs = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
    cyc: list[int] = []
    tq: list[float] = []
    for m in msgs:
        if m["kind"] == "torque":
            cyc += range(m["first_cycle"], m["first_cycle"] + m["n"])
            tq += m["torque_nm"]
    est = pd.Series(tq, index=cyc)
    truth = pd.read_parquet(d / "dv" / f"truth_per_cycle_{ref[6:]}.parquet").set_index("cycle")
    cut = json.loads((d / "dv" / "truth.json").read_text())["cuts"][0]
    a, b = cut["full_engagement_first_cycle"] + 100, cut["cut_last_cycle"] - 100
    t_true = truth.loc[a:b, "cutting_torque_nm"].mean()
    t_est = est.loc[a:b].mean()
    assert t_est == pytest.approx(t_true, rel=0.02)
    assert all(m["machine"] == load_machine(d / "machine.toml").machine.name for m in msgs)


def test_dashboard_compares_a_recording_with_the_twin(calibrated: tuple[Path, dict[str, Any]]
                                                      ) -> None:
    pytest.importorskip("fastapi", reason="the web extra: pip install 'cnctwin[web]'")
    from fastapi.testclient import TestClient

    from cnctwin.web.app import create_app

    d, hidden = calibrated
    rec = d / "new_same" / "axis_test.json"
    if not rec.exists():
        _compare(d, hidden, {}, "same")
    app = create_app(recordings=[rec], machine=d / "machine.toml")
    with TestClient(app) as client:
        rid = client.get("/api/recordings").json()[0]["id"]
        doc = client.get(f"/api/recordings/{rid}/compare").json()
        assert set(doc["axes"]) == {"X1", "Y1"}
        assert not any(a["flagged"] for a in doc["axes"].values())
        page = client.get(f"/recordings/{rid}/compare")
        assert page.status_code == 200 and "holds" in page.text
        assert "departs</b>" not in page.text
        assert "compare with the calibrated twin" in client.get(f"/recordings/{rid}").text


def test_edge_runtime_compares_live_with_the_twin(calibrated: tuple[Path, dict[str, Any]]
                                                  ) -> None:
    """``twin`` results of ``cnctwin edge run --machine``: Y1 Coulomb x 1.5 is flagged in the
    windows where Y1 moves, X1 never; every window says which cycles it covers."""
    d, hidden = calibrated
    worn = d / "edge_worn"
    y1 = "axes.Y1.coulomb_n"
    assert cli("simulate", "axis_test", "--out", worn, "--seed", SEED + 3,
               *sets({**hidden, y1: round(float(load_machine(d / "machine.toml").value(y1))
                                          * 1.5, 3)}),
               "--option", 'axes=["X1", "Y1"]') == 0
    out = d / "edge_twin"
    assert cli("edge", "run", "--source", worn / "axis_test.json", "--machine",
               d / "machine.toml", "--out", out, "--no-anomaly", "--no-holes",
               "--twin-window-s", "20") == 0
    twins = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()
             if '"kind":"twin"' in x.replace(" ", "")]
    assert len(twins) >= 3
    covered = sorted((t["first_cycle"], t["n"]) for t in twins)
    for (a, n), (b, _) in itertools.pairwise(covered):
        assert a + n == b  # windows back to back: every cycle compared once
    assert any("Y1" in t["flagged"] for t in twins)
    assert not any("X1" in t["flagged"] for t in twins)


def test_without_a_dynamometer_the_motor_kt_and_its_tolerance(
        calibrated: tuple[Path, dict[str, Any]], capsys: pytest.CaptureFixture[str]) -> None:
    """``calibrate spindle --kt-nm-per-a`` (the drive's motor data, no reference cut): friction
    referred to it, every value's uncertainty carries the stated tolerance, and the note says
    what accuracy the torque then has (issue 13)."""
    d, hidden = calibrated
    kt_sheet = round(hidden["spindle.kt_nm_per_a"] * 1.03, 4)  # a data sheet 3 % off
    m = d / "motor_kt.toml"
    assert cli("calibrate", "spindle", "--air-cut", d / "ac" / "air_cut_sweep.json",
               "--kt-nm-per-a", kt_sheet, "--kt-tolerance-pct", 5, "--machine", m) == 0
    out = capsys.readouterr().out
    assert "standard uncertainty 2.9 %" in out
    mf = load_machine(m)
    for key in ("spindle.viscous_friction_nm_per_rpm", "spindle.coulomb_friction_nm"):
        rec = mf.record(key)
        assert rec is not None and rec.uncertainty is not None
        # the 3 % data-sheet error moves friction by 3 %: inside the stated 95 % interval
        assert abs(rec.value - hidden[key]) <= 1.96 * rec.uncertainty, key
    kt = mf.record("spindle.kt_nm_per_a")
    assert kt is not None and kt.value == kt_sheet
    assert kt.uncertainty == pytest.approx(kt_sheet * 0.05 / 3 ** 0.5, rel=0.01)  # 3 digits
    assert not mf.record("spindle.flux_base_speed_rpm").identified

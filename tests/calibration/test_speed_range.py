"""A twin that holds across the spindle's speed range (issue 13 acceptance).

A simulated induction-type spindle with a hidden base speed (drawn inside the calibration
range) weakens its flux as 1/n above it: the torque per reported current falls with speed, as
the KIT DMC 60H data show (Kt x speed constant over 2400-4000 rpm). Calibrated through the
command line from cuts at two speeds, the machine file's twin (run by the edge runtime, as a
user runs it) predicts the cutting torque of cuts at three other speeds, one above the highest
calibration speed, within 2 % of the simulator's true cutting torque; the thesis method
(one Kt from the 2400 rpm cut) on the same cuts is reported beside it and misses by far more.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from cnctwin.iotools import read_recording
from cnctwin.iotools.dynamometer import attach_external, read_dynamometer_csv
from cnctwin.machine import load_machine
from cnctwin.twin import TwinChain
from tests.calibration._campaign import SPEEDS_RPM, cli, sets

CAL = (1600, 4000)
VAL = (2400, 3200, 4800)
CAL3 = (1600, 3200, 4000)  # three speeds: the exponent of the flux law is fitted too
VAL3 = (2000, 2400, 4800)
pytestmark = pytest.mark.xdist_group("speed_range")


def _edge_torque_error(d: Path, machine: Path, tag: str, truth: dict, out: Path) -> float:
    """Relative error of the edge runtime's mean cutting torque over the engaged cut [%]."""
    state = out / f"edge_{machine.stem}_{tag}"
    assert cli("edge", "run", "--source", d / f"drill_{tag}.json", "--machine", machine,
               "--out", state, "--no-anomaly", "--no-holes", "--no-twin") == 0
    cyc: list[int] = []
    tq: list[float] = []
    for line in (state / "results.jsonl").read_text().splitlines():
        m = json.loads(line)
        if m["kind"] == "torque":
            cyc += range(m["first_cycle"], m["first_cycle"] + m["n"])
            tq += m["torque_nm"]
    est = pd.Series(tq, index=cyc)
    per = pd.read_parquet(d / f"truth_per_cycle_{tag}.parquet").set_index("cycle")
    a, b = truth["full_engagement_first_cycle"] + 100, truth["cut_last_cycle"] - 100
    t_true = float(per.loc[a:b, "cutting_torque_nm"].mean())
    return float(100.0 * (est.loc[a:b].mean() / t_true - 1.0))


@pytest.mark.slow
@pytest.mark.parametrize(("seed", "cal", "val", "random_exponent"), [
    (3, CAL, VAL, False), (8, CAL, VAL, False), (5, CAL3, VAL3, True)])
def test_speed_law_recovered_and_predicts_other_speeds(
        seed: int, cal: tuple[int, ...], val: tuple[int, ...], random_exponent: bool,
        tmp_path: Path) -> None:
    rng = np.random.default_rng([seed, 13])
    # hidden base speed inside the calibration speeds (below the second one)
    nb = round(float(rng.uniform(1.25 * cal[0], 0.9 * cal[1])), 1)
    hidden = {"spindle.flux_base_speed_rpm": nb,
              "spindle.kt_nm_per_a": round(float(rng.uniform(0.8, 1.3)), 4)}
    if random_exponent:
        hidden["spindle.flux_exponent"] = round(float(rng.uniform(0.7, 1.2)), 3)
    s = sets(hidden)
    assert cli("simulate", "air_cut_sweep", "--out", tmp_path / "ac", "--seed", seed, *s,
               "--option", f"speeds_rpm={SPEEDS_RPM}") == 0
    cuts = [["aisi1045", n, 0.16] for n in (*cal, *val)]
    assert cli("simulate", "drilling_validation", "--out", tmp_path / "dv", "--seed", seed, *s,
               "--option", f"cuts={json.dumps(cuts)}") == 0
    dv = tmp_path / "dv"
    truth = json.loads((dv / "truth.json").read_text())["cuts"]
    tags = {c["speed_rpm"]: c["recording"].removeprefix("drill_").removesuffix(".json")
            for c in truth}
    by_speed = {c["speed_rpm"]: c for c in truth}
    new = tmp_path / "new.toml"
    assert cli("calibrate", "spindle", "--air-cut", tmp_path / "ac" / "air_cut_sweep.json",
               "--reference", *(dv / f"drill_{tags[n]}.json" for n in cal),
               "--dynamometer", *(dv / f"dynamometer_{tags[n]}.csv" for n in cal),
               "--machine", new) == 0
    mf = load_machine(new)
    rec = mf.record("spindle.flux_base_speed_rpm")
    assert rec is not None and rec.identified and rec.uncertainty is not None
    assert rec.value == pytest.approx(nb, rel=0.02)
    assert abs(rec.value - nb) <= 3 * rec.uncertainty + 0.005 * nb
    kt_rec = mf.record("spindle.kt_nm_per_a")
    assert kt_rec is not None and kt_rec.valid_range == pytest.approx((cal[0], cal[-1]), abs=1.0)
    if random_exponent:
        ex = mf.record("spindle.flux_exponent")
        assert ex is not None and ex.identified
        assert ex.value == pytest.approx(hidden["spindle.flux_exponent"], abs=0.05)
    errors = {n: _edge_torque_error(dv, new, tags[n], by_speed[n], tmp_path) for n in val}
    # beside it the thesis method (one Kt from the 2400 rpm cut, Eq. 4.2-4.4) on the same cuts,
    # through the API: on this spindle its friction line runs through the bend of the air
    # current, and the command line refuses to write it (negative friction)
    air = read_recording(tmp_path / "ac" / "air_cut_sweep.json")

    def with_dyn(n: int) -> Any:
        return attach_external(read_recording(dv / f"drill_{tags[n]}.json"),
                               read_dynamometer_csv(dv / f"dynamometer_{tags[n]}.csv"))

    th = TwinChain.thesis_method().calibrate(air, with_dyn(2400))
    th.run_model_from_measured([with_dyn(n) for n in val], labels=[str(n) for n in val])
    thesis = dict(zip(val, th.results.validation["error_pct"].tolist(), strict=True))
    print(f"hidden {hidden}; error at {val} rpm: new model {errors} %, "
          f"thesis method {thesis} %")
    for n, e_new in errors.items():
        assert abs(e_new) <= 2.0, (n, e_new)
    # the thesis' single Kt cannot follow the flux law above the base speed
    assert max(abs(e) for e in thesis.values()) > 10.0

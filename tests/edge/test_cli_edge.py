"""``cnctwin edge run`` on a simulated recording file and ``cnctwin edge status``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from cnctwin.cli import main
from cnctwin.edge import save_spindle_model
from cnctwin.spindle import SpindleModel
from cnctwin.usecases.holes import hole_records


def test_edge_run_and_status(tmp_path: Path, wear_run: dict[str, Any], wear_recording: Any,
                             capsys: pytest.CaptureFixture[str]) -> None:
    model = SpindleModel(1.01, 8.3e-5, 0.34, j_kgm2=0.0045)
    mfile = save_spindle_model(model, tmp_path / "spindle.toml")
    out = tmp_path / "state"
    code = main(["edge", "run", "--source", str(wear_run["path"]), "--model", str(mfile),
                 "--out", str(out), "--quiet", "--store", str(tmp_path / "store"),
                 "--learn-s", "3"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    batch = hole_records([wear_recording], model=model)
    assert summary["holes"] == len(batch) == 3 and summary["gaps"] == 0
    # a fault-free run (the simulator injects nothing): no alarm, also not at the spindle
    # stop, where the constant-speed twin misses the braking current (issue 14)
    assert summary["alarms"] == 0
    lines = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
    rows = [m["row"] for m in lines if m["kind"] == "hole"]
    assert [r["torque_mean_nm"] for r in rows] == pytest.approx(
        batch["torque_mean_nm"].tolist(), rel=1e-12)
    # status.json is strict JSON (RFC 8259 has no NaN: unknown values are null)
    def no_constant(name: str) -> Any:
        raise AssertionError(f"status.json holds a bare {name}")

    status = json.loads((out / "status.json").read_text(), parse_constant=no_constant)
    assert status["state"] == "finished"
    assert main(["edge", "status", str(out)]) == 0
    text = capsys.readouterr().out
    assert "holes" in text and "finished" in text
    assert main(["edge", "status", str(tmp_path / "nothing")]) == 2


def test_edge_run_status_interval(tmp_path: Path, wear_run: dict[str, Any],
                                  capsys: pytest.CaptureFixture[str]) -> None:
    """``--status-s`` above 5 s is refused with what to give (the dashboard calls a machine
    stale after 10 s without a status); one within the range runs."""
    mfile = save_spindle_model(SpindleModel(1.01, 8.3e-5, 0.34), tmp_path / "spindle.toml")
    args = ["edge", "run", "--source", str(wear_run["path"]), "--model", str(mfile),
            "--quiet", "--no-holes", "--no-anomaly"]
    assert main([*args, "--out", str(tmp_path / "a"), "--status-s", "30"]) == 2
    assert "--status-s 30.0: give a number of seconds above 0 and at most 5" in \
        capsys.readouterr().err
    assert main([*args, "--out", str(tmp_path / "b"), "--status-s", "5"]) == 0
    status = json.loads((tmp_path / "b" / "status.json").read_text())
    assert status["state"] == "finished" and status["cpu_s"] > 0


def test_status_table_reads_as_an_engineer_writes() -> None:
    """Issue 24, pt 8: ``overload │ NONEinput dropped 0`` and ``1.78e+04 ms`` beside seconds."""
    import io

    from rich.console import Console

    from cnctwin.cli.edge import status_table

    st = {"machine": "m", "state": "running", "cycles": 10, "last_cycle": 9,
          "cycles_per_s": 500.0, "lag_s": 17.8, "latency_ms": {"p99": 17_800.0},
          "data_age_s": 0.25, "overload": {"input_dropped": 0, "forward_dropped": 0},
          "updated": "2026-11-27T07:00:00Z"}
    buf = io.StringIO()
    Console(file=buf, width=120).print(status_table(st))
    text = buf.getvalue()
    assert "17.8 s (arrival to publish; p99 17.8 s), data age 250 ms" in text
    assert "none (input dropped 0, forward dropped 0)" in text
    assert "e+" not in text and "NONE" not in text

"""What ``cnctwin calibrate axes`` states (issue 29, point 5), as a user runs it.

* it writes its HTML report beside the machine file (or where ``--report`` says);
* axes of the machine that move in no recording are marked not identified with the reason in
  the machine file (not left as empty ``[axes.C1]`` sections) and listed in the table;
* a later calibration on a recording where an axis does not move keeps what an earlier one
  identified for it;
* the table's parameter names are the machine file's keys, whole.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

from cnctwin.cli import main
from cnctwin.machine import load_machine

FAST = ["--option", "feeds_mm_min=[1500.0, 4000.0]", "--option", "stroke_mm=30.0"]


def _run(*args: object) -> str:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main([str(a) for a in args]) == 0
    return buf.getvalue()


def test_calibrate_axes_states_what_it_did(tmp_path: Path) -> None:
    assert main(["simulate", "axis_test", "--out", str(tmp_path / "x"), "--seed", "3",
                 "--option", 'axes=["X1"]', *FAST]) == 0
    m = tmp_path / "m.toml"
    out = _run("calibrate", "axes", tmp_path / "x" / "axis_test.json", "--machine", m)
    report = tmp_path / "m.axes-report.html"
    assert report.stat().st_size > 20_000  # the parameters, X1's friction and error figures
    html = report.read_text(encoding="utf-8")
    assert "Axis X1" in html and "did not move" in html
    mf = load_machine(m)
    assert mf.record("axes.X1.kv_m_min_per_mm").identified
    for ax in ("Y1", "Z1", "C1", "B1"):
        r = mf.record(f"axes.{ax}.kv_m_min_per_mm")
        assert r is not None and not r.identified and "does not move" in r.reason, ax
        assert ax in out
    # the parameter names, whole, as in the machine file
    for key in ("kv_m_min_per_mm", "equiv_speedctrl_time_s", "viscous_n_per_mm_s"):
        assert key in out
    assert "did not move in the recordings" in out
    # a second calibration on a recording where only Y1 moves keeps X1's values
    assert main(["simulate", "axis_test", "--out", str(tmp_path / "y"), "--seed", "4",
                 "--option", 'axes=["Y1"]', *FAST]) == 0
    kv_x1 = mf.record("axes.X1.kv_m_min_per_mm").value
    out2 = _run("calibrate", "axes", tmp_path / "y" / "axis_test.json", "--machine", m,
                "--report", tmp_path / "second.html")
    mf2 = load_machine(m)
    assert mf2.record("axes.X1.kv_m_min_per_mm").identified
    assert mf2.record("axes.X1.kv_m_min_per_mm").value == kv_x1
    assert mf2.record("axes.Y1.kv_m_min_per_mm").identified
    assert "earlier values kept" in out2
    assert (tmp_path / "second.html").exists()

"""Servo analyses on the REAL recordings (tests/data/real; facts written up in
docs/real-data-servo.md). Values asserted here were found by the analysis on these files."""

from __future__ import annotations

import numpy as np
import pytest

from cnctwin.iotools import read_capture4analysis, read_sinumerik_trace
from cnctwin.recording import Recording
from cnctwin.servo import check_relations, identify_axis
from cnctwin.servo._common import axis_data, derivative, detect_velocity_unit

from ..conftest import C4A_FILE, TRACE_FILE


@pytest.fixture(scope="module")
def c4a() -> Recording:
    return read_capture4analysis(C4A_FILE)


@pytest.fixture(scope="module")
def trace() -> Recording:
    return read_sinumerik_trace(TRACE_FILE)


@pytest.mark.parametrize("axis", ["X1", "Y1", "C1", "SP1"])
def test_c4a_vel_ffw_is_per_second_not_per_minute(c4a: Recording, axis: str) -> None:
    # docs/reference/data-formats.md §1.3 (Siemens): VEL_FFW in mm/s (deg/s), as the catalog now
    # declares.
    # The file says per second: VEL_FFW / (d(DES_POS)/dt in unit/s) = 1.000.
    d = axis_data(c4a, axis)
    v = derivative(d.signals["DES_POS"], d.segments, d.cycle_time_s, kind="backward")
    vu = detect_velocity_unit(d.signals["VEL_FFW"], v, declared=d.units["VEL_FFW"], kind=d.kind)
    assert vu.ratio == pytest.approx(1.0, abs=2e-3)
    assert vu.detected in ("mm/s", "deg/s")
    # the catalog agrees on the feed axes; on the spindle it declares rpm (the simulated
    # spindle in speed control), while this file's SP1 (positioning) records deg/s
    assert vu.declared == (vu.detected if axis != "SP1" else "rpm")


def test_c4a_relations_and_contour_model(c4a: Recording) -> None:
    rep = check_relations(c4a, "X1")
    assert not rep["ctrl_diff2"].checkable and "CTRL_POS|X1" in rep["ctrl_diff2"].reason
    cd = rep["contour_deviation"]
    # CONT_DEV = ENC_model - ENC with the NC model ~ 7.7 ms delay + 0.56 ms PT1 of DES_POS;
    # found: residual 3.3e-6 mm rms against 5.8e-3 mm CONT_DEV rms
    assert cd.details["model_delay_s"] == pytest.approx(0.0077, abs=3e-4)
    assert cd.rms < 1e-5
    assert cd.rms < 0.01 * cd.reference_rms
    assert rep["vel_ffw"].details["detected_unit"] == "mm/s"


@pytest.mark.parametrize("axis", ["X1", "Y1"])
def test_c4a_kv_identified_without_ctrl_pos(c4a: Recording, axis: str) -> None:
    ident = identify_axis(c4a, axis, n_bootstrap=40)
    # CMD_SPEED is 1.175 x the actual speed at steady velocity on every moving feed axis
    assert ident.value("speed_gain") == pytest.approx(0.851, abs=0.003)
    # Kv in CMD_SPEED units: 33.3 1/s = 2.00 (m/min)/mm, a typical MD32200 value
    # (docs/reference/physics-and-performance.md §1.2: 808D default 33.33 = 2 (m/min)/mm); 3 %
    # tolerance
    assert ident.value("kv_command_1_s") == pytest.approx(33.33, rel=0.03)
    # referred to the actual speed: 28.4 1/s = 1.70 (m/min)/mm
    assert ident.value("kv_m_min_mm") == pytest.approx(1.70, rel=0.03)
    assert ident.ffw_mode == "speed"
    for name in ("jerk_time_s", "setpoint_delay_s", "ffw_weight"):
        assert "CTRL_POS" in ident.not_identified[name]


@pytest.mark.parametrize("axis", ["Z1", "B1"])
def test_c4a_spindle_like_axes_not_identified(c4a: Recording, axis: str) -> None:
    # Z1 and B1 turn continuously (4200 and 10098 units/s) although named like feed axes;
    # the P law does not hold there, so Kv is refused with a reason, not invented
    ident = identify_axis(c4a, axis, n_bootstrap=20)
    assert "kv_1_s" in ident.not_identified
    assert "kv_1_s" not in ident.params


def test_trace_cmd_speed_is_a_setpoint_velocity(trace: Recording) -> None:
    ident = identify_axis(trace, "AX7", n_bootstrap=20)
    assert "setpoint velocity" in ident.not_identified["kv_1_s"]
    # steady following error per velocity from the recorded FOLLOWING_ERROR: 6.15 ms
    assert ident.value("lag_time_s") == pytest.approx(0.00615, abs=2e-4)
    rep = check_relations(trace, "AX7")
    assert not rep["vel_ffw"].checkable
    # the recorded following error is not DES_POS - ENC (positions are 4 ms IPO samples)
    fe = rep["following_error"]
    assert fe.checkable and fe.fraction_within < 0.01
    assert np.isfinite(fe.rms)

"""Contour error and circle test on analytic paths (exact geometry, no simulator)."""

from __future__ import annotations

import numpy as np
import pytest

from cnctwin.recording import Recording
from cnctwin.servo.geometry import (
    circle_test,
    contour_error,
    fit_circle_lsq,
    signed_distance_to_polyline,
)


def _rec(des_x, des_y, enc_x, enc_y, **extra) -> Recording:
    n = len(des_x)
    sig = {"DES_POS|X1": des_x, "DES_POS|Y1": des_y, "ENC_POS|X1": enc_x, "ENC_POS|Y1": enc_y}
    sig.update(extra)
    return Recording.from_arrays(np.arange(n), sig)


def test_signed_distance_left_positive() -> None:
    path = np.array([[0.0, 0.0], [10.0, 0.0]])
    d = signed_distance_to_polyline(np.array([[5.0, 0.3], [5.0, -0.2], [12.0, 0.0]]), path)
    np.testing.assert_allclose(d, [0.3, -0.2, 2.0], atol=1e-12)


def test_square_offset_and_corner_rounding() -> None:
    # programmed square 0..20 mm; actual path = the square shifted 0.01 mm inward on every side
    # plus a cut corner: distance known exactly
    t = np.linspace(0, 20, 2001)
    side = [np.column_stack([t, 0 * t]), np.column_stack([20 + 0 * t, t]),
            np.column_stack([t[::-1], 20 + 0 * t]), np.column_stack([0 * t, t[::-1]])]
    des = np.vstack(side)
    act = des.copy()
    # bottom edge 0.01 inward (left of travel = +y)
    act[:2001, 1] += 0.01
    rec = _rec(des[:, 0], des[:, 1], act[:, 0], act[:, 1])
    res = contour_error(rec, path=np.array([[0, 0], [20, 0], [20, 20], [0, 20], [0, 0]]))
    assert np.nanmedian(res.distance_mm[100:1900]) == pytest.approx(0.01, abs=1e-9)
    assert np.nanmedian(res.distance_mm[2100:3900]) == pytest.approx(0.0, abs=1e-9)
    assert len(res.corners) == 3  # (20,0), (20,20), (0,20); the start/end point is no corner
    c = res.corners[0]
    assert (c.x_mm, c.y_mm) == (20.0, 0.0)
    assert c.angle_deg == pytest.approx(90.0)
    assert c.overshoot_mm == pytest.approx(0.0, abs=1e-12)


def test_corner_overshoot_detected() -> None:
    t = np.linspace(0, 10, 1001)
    des = np.vstack([np.column_stack([t, 0 * t]), np.column_stack([10 + 0 * t, t])])
    act = des.copy()
    # actual path overshoots past x = 10 by up to 0.02 mm just after the corner (outer side)
    bump = 0.02 * np.exp(-((t - 0.5) / 0.2) ** 2)
    act[1001:, 0] += bump
    rec = _rec(des[:, 0], des[:, 1], act[:, 0], act[:, 1])
    res = contour_error(rec)
    assert res.corners[0].overshoot_mm == pytest.approx(0.02, rel=1e-3)
    assert res.max_abs_mm == pytest.approx(0.02, rel=1e-3)


def test_circle_lsq_and_iso230_4_deviation() -> None:
    # ellipse-like actual path: r(theta) = R + a cos(2 theta) (unequal axis gains -> ellipse,
    # Siemens A3 p. 73): G = 2a about the centre, F = 0
    th = np.linspace(0, 2 * np.pi, 3600, endpoint=False)
    r_nom, a = 25.0, 0.004
    dx, dy = 5 + r_nom * np.cos(th), -3 + r_nom * np.sin(th)
    r_act = r_nom + a * np.cos(2 * th)
    ex, ey = 5 + r_act * np.cos(th), -3 + r_act * np.sin(th)
    # CONT_DEV = expected - actual = radial -(a cos 2 theta)
    cdx, cdy = -(a * np.cos(2 * th)) * np.cos(th), -(a * np.cos(2 * th)) * np.sin(th)
    rec = _rec(dx, dy, ex, ey, **{"CONT_DEV|X1": cdx, "CONT_DEV|Y1": cdy})
    res = circle_test(rec)
    assert res.center_mm == pytest.approx((5.0, -3.0), abs=1e-5)  # first sample unused
    assert res.nominal_radius_mm == pytest.approx(25.0, abs=1e-9)
    assert res.radius_deviation_mm == pytest.approx(0.0, abs=1e-5)
    assert res.circular_deviation_lsc_mm == pytest.approx(2 * a, rel=1e-3)
    assert res.circular_deviation_mz_mm <= res.circular_deviation_lsc_mm + 1e-12
    assert res.cont_dev_correlation == pytest.approx(1.0, abs=1e-6)
    xc, yc, r = fit_circle_lsq(dx, dy)
    assert (xc, yc, r) == pytest.approx((5.0, -3.0, 25.0), abs=1e-9)


def test_circle_radius_shrink() -> None:
    # lag of a P loop on a circle shrinks the radius: r_act = R - dR
    th = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    rec = _rec(10 * np.cos(th), 10 * np.sin(th), 9.99 * np.cos(th), 9.99 * np.sin(th))
    res = circle_test(rec, center=(0.0, 0.0), radius=10.0)
    assert res.radius_deviation_mm == pytest.approx(-0.01, abs=1e-9)
    assert res.circular_deviation_lsc_mm == pytest.approx(0.0, abs=1e-9)

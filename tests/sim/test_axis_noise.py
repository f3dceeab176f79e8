"""The feed axes record what a real drive records: measurement noise, torque from the measured
current, a position-periodic force, all drawn from the scenario seed (issue 29, point 1).

Independent truths: the statistics of white noise (a first difference of white noise of std s
has std s sqrt 2; a quantiser of step q adds q^2 / 12 of variance), the statics of a standing
slide (the drive holds the ripple force: TORQUE = F_ripple), the unit chain of the torque actual
value (TORQUE [N] = Kt [Nm/A] x I [A] x 2 pi / lead [m]), and the bytes of two recordings.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from cnctwin.cli import main
from cnctwin.iotools import read_recording
from cnctwin.machine import Machine
from cnctwin.sim.servo import simulate_servo

SHORT = ["--option", 'axes=["X1", "Y1"]', "--option", "feeds_mm_min=[2000.0]",
         "--option", "stroke_mm=20.0"]


def _simulate(out: Path, seed: int) -> dict[str, np.ndarray]:
    assert main(["simulate", "axis_test", "--out", str(out), "--seed", str(seed), *SHORT]) == 0
    hf = read_recording(out / "axis_test.json").hf
    return {c: hf[c].to_numpy() for c in hf.columns if c.endswith(("|X1", "|Y1"))}


def test_two_seeds_give_independent_axis_noise_one_seed_the_same_bits(tmp_path: Path) -> None:
    a = _simulate(tmp_path / "s0", 0)
    b = _simulate(tmp_path / "s2", 2)
    again = _simulate(tmp_path / "s0b", 0)
    for ax in ("X1", "Y1"):
        # the setpoints are the program's: the same for every seed
        np.testing.assert_array_equal(a[f"DES_POS|{ax}"], b[f"DES_POS|{ax}"])
        for code in ("TORQUE", "ENC_POS", "CMD_SPEED", "CURRENT", "CONT_DEV"):
            c = f"{code}|{ax}"
            # differ in most cycles, not by a constant: independent noise
            assert np.mean(a[c] != b[c]) > 0.5, c
            np.testing.assert_array_equal(a[c], again[c], err_msg=c)
    # and the files are byte for byte the same
    assert (tmp_path / "s0" / "axis_test.json").read_bytes() == \
        (tmp_path / "s0b" / "axis_test.json").read_bytes()


def _standing(n: int, x_mm: float, **changes: object) -> dict[str, np.ndarray]:
    ax = dataclasses.replace(Machine.thesis_default().axis("X1"), **changes)  # type: ignore[arg-type]
    tr = simulate_servo(np.full((1, n), x_mm), [ax], rng=np.random.default_rng(11))
    return {c: tr.signals[c][0] for c in ("ENC_POS", "CMD_SPEED", "TORQUE", "CURRENT")}


def test_standing_axis_noise_levels_follow_from_the_axis_description() -> None:
    ax = Machine.thesis_default().axis("X1")
    s = _standing(6000, 12.3456, ripple_n=0.0)
    # white measuring noise, quantised: increments of std sqrt(2 (s^2 + q^2/12))
    sd = math.sqrt(ax.encoder_noise**2 + ax.encoder_resolution**2 / 12.0)
    d = np.diff(s["ENC_POS"][1000:])
    assert abs(np.std(d) / math.sqrt(2.0) / sd - 1.0) < 0.05  # 5000 samples: 1 % std error
    # the NC's speed setpoint is Kv x the difference: its increments Kv times the encoder's
    dv = np.diff(s["CMD_SPEED"][1000:])
    assert abs(np.std(dv) / (ax.kv_per_s * np.std(d)) - 1.0) < 0.02
    # the torque actual value is Kt x the measured current, at the slide: 1.4 x 2 pi / 0.010
    np.testing.assert_allclose(s["TORQUE"], s["CURRENT"] * 1.4 * 2.0 * math.pi / 0.010,
                               rtol=1e-12)
    assert abs(np.std(np.diff(s["CURRENT"])) / math.sqrt(2.0) / ax.current_noise_a - 1.0) < 0.05


def test_a_standing_slide_holds_the_ripple_force() -> None:
    # one ripple period per motor revolution = one screw lead (10 mm); the drive's integrator
    # carries the force at rest, so the mean TORQUE is the ripple at that position
    amp, phase = 25.0, 0.7
    for x in (0.0, 1.25, 2.5, 6.0, 8.75):
        s = _standing(1500, x, ripple_n=amp, ripple_phase_rad=phase)
        expected = amp * math.sin(2.0 * math.pi * x / 10.0 + phase)
        # noise of the mean: 44 N per sample / sqrt(1000) = 1.4 N; 4.5 N is 3 of those
        assert abs(np.mean(s["TORQUE"][500:]) - expected) < 4.5, (x, expected)


def test_acceleration_current_is_newtons() -> None:
    """The current sampled at the end of each 2 ms cycle during a constant acceleration is
    (J alpha + r F_friction) / Kt (Newton; J = J_motor + m (lead / 2 pi)^2): within 5 % with the
    DSC spline of the speed feedforward (S120 p1191, the default); holding the feedforward over
    the cycle kicks the speed loop every 2 ms and the end-of-cycle sample missed a third."""
    for spline, lo, hi in ((True, 0.95, 1.05), (False, 0.5, 0.8)):
        ax = dataclasses.replace(Machine.thesis_default().axis("Y1"), ripple_n=0.0,
                                 encoder_noise=0.0, current_noise_a=0.0, dsc_spline=spline)
        acc = 2000.0  # mm/s^2
        t = np.arange(1000) * 0.002
        x = np.where(t > 0.5, 0.5 * acc * (t - 0.5) ** 2, 0.0)
        i = simulate_servo(x[None, :], [ax]).signals["CURRENT"][0]
        k = (t > 0.8) & (t < 0.9)
        v = acc * 0.35  # mean speed in the window [mm/s]
        j = ax.motor_inertia_kgm2 + ax.mass_kg * (ax.screw_pitch_mm / 1000.0 / (2 * math.pi)) ** 2
        r = ax.screw_pitch_mm / 1000.0 / (2.0 * math.pi)  # m per rad
        newton = (j * acc / 1000.0 / r + (ax.coulomb_n + ax.viscous_n_per_mm_s * v) * r) \
            / ax.kt_nm_per_a
        assert lo < np.mean(i[k]) / newton < hi, (spline, np.mean(i[k]), newton)

"""External sensors: own clocks, CSV formats readable by cnctwin.iotools."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cnctwin.exceptions import ConfigError
from cnctwin.iotools.dynamometer import read_dynamometer_csv
from cnctwin.iotools.thermal import read_thermal_camera_csv
from cnctwin.sim.sensors import (
    Dynamometer,
    ThermalCamera,
    dynamometer_channel,
    thermal_camera_channel,
    write_dynamometer_csv,
    write_thermal_camera_csv,
)


def test_dynamometer_clock_and_csv_roundtrip(tmp_path: Path) -> None:
    t = np.arange(0, 20, 0.002)
    mz = np.where((t > 5) & (t < 8), 4.0, 0.0)
    sensor = Dynamometer(clock_offset_s=-1.7, clock_drift_ppm=500.0, torque_noise_nm=0.0,
                         torque_drift_nm_per_s=0.0)
    ch = dynamometer_channel(t, mz, 1000 * mz, sensor=sensor)
    assert not ch.aligned and ch.offset_s == 0.0
    own = np.asarray(ch.data.index)
    # the step at recording time 5 s appears at own time (5 + 1.7) / (1 + 500e-6)
    first = own[np.argmax(ch.data["mz_nm"].to_numpy() > 2.0)]
    assert first == pytest.approx((5.0 + 1.7) / (1 + 500e-6), abs=1.5e-3)
    assert np.median(np.diff(own)) == pytest.approx(1e-3)
    back = read_dynamometer_csv(write_dynamometer_csv(ch, tmp_path / "dyn.csv"))
    assert list(back.data.columns)[:4] == ["fx_n", "fy_n", "fz_n", "mz_nm"]
    np.testing.assert_allclose(back.data["mz_nm"].to_numpy(), ch.data["mz_nm"].to_numpy(),
                               rtol=1e-5, atol=1e-6)


def test_thermal_camera_csv_roundtrip(tmp_path: Path) -> None:
    ch = thermal_camera_channel([10.0, 16.0], [0, 1], [120.0, 180.0],
                                camera=ThermalCamera(noise_c=0.0))
    back = read_thermal_camera_csv(write_thermal_camera_csv(ch, tmp_path / "cam.csv"))
    np.testing.assert_allclose(back.data["temperature_c"].to_numpy(), [120.0, 180.0])
    np.testing.assert_allclose(back.data["hole"].to_numpy(), [0, 1])


def test_format_csv_fixed_reads_back_within_half_a_digit() -> None:
    """The fast dynamometer CSV formatter: every value read back within 0.5 units of its last
    digit, NaN/inf kept, negative zero written without a sign."""
    from cnctwin.sim.sensors import format_csv_fixed

    rng = np.random.default_rng(0)
    vals = np.column_stack([np.arange(500) * 1e-3 + 1234.5, rng.normal(0, 80, (500, 3)),
                            rng.normal(0, 3, 500)])
    vals[3, 1] = np.nan
    vals[4, 2] = -np.inf
    vals[5, 3] = -1e-9
    dec = (6, 4, 4, 4, 5)
    text = format_csv_fixed(vals, dec)
    rows = text.splitlines()
    assert len(rows) == 500 and text.endswith("\n")
    back = np.array([[float(x) for x in r.split(",")] for r in rows])
    fin = np.isfinite(vals)
    assert np.array_equal(np.isnan(back), np.isnan(vals))
    assert back[4, 2] == -np.inf
    assert rows[5].split(",")[3] == "0.0000"
    tol = 0.5 * 10.0 ** -np.array(dec, dtype=float) * (1 + 1e-9)
    err = np.abs(back[fin] - vals[fin])
    assert np.all(err <= np.broadcast_to(tol, vals.shape)[fin] + 1e-12)
    with pytest.raises(ConfigError):
        format_csv_fixed(vals, (6, 4))


def test_dynamometer_csv_decimals_below_the_noise(tmp_path: Path) -> None:
    """Digits of the dynamometer CSV: the quantisation step is <= 1/100 of the noise std (so it
    adds <= noise/346 rms), and times k/fs are written exactly."""
    from cnctwin.sim.sensors import dynamometer_csv_decimals

    # defaults of Dynamometer: 1 kHz, 8 N force noise, 0.05 Nm torque noise
    assert dynamometer_csv_decimals(fs_hz=1000.0, force_noise_n=8.0,
                                    torque_noise_nm=0.05) == (3, 2, 2, 2, 4)
    assert dynamometer_csv_decimals(fs_hz=2000.0)[0] == 4
    assert dynamometer_csv_decimals(fs_hz=3000.0)[0] == 6  # 1/3 ms: 1 us rounding
    # no noise figure or a noiseless sensor: 0.1 mN and 10 uNm
    assert dynamometer_csv_decimals(fs_hz=None, force_noise_n=0.0)[1:] == (4, 4, 4, 5)
    sensor = Dynamometer(clock_offset_s=0.3, clock_drift_ppm=-20.0)
    t = np.arange(0, 3, 0.002)
    ch = dynamometer_channel(t, 5.0 + np.sin(t), 900.0 + 50 * np.cos(t), sensor=sensor,
                             rng=np.random.default_rng(4))
    dec = dynamometer_csv_decimals(fs_hz=sensor.fs_hz, force_noise_n=sensor.force_noise_n,
                                   torque_noise_nm=sensor.torque_noise_nm)
    back = read_dynamometer_csv(write_dynamometer_csv(ch, tmp_path / "d.csv", decimals=dec))
    np.testing.assert_array_equal(np.asarray(back.data.index), np.asarray(ch.data.index))
    for col, d in zip(("fz_n", "mz_nm"), (dec[3], dec[4]), strict=True):
        err = back.data[col].to_numpy() - ch.data[col].to_numpy()
        assert np.abs(err).max() <= 0.5 * 10.0**-d * (1 + 1e-9)
        noise = sensor.force_noise_n if col == "fz_n" else sensor.torque_noise_nm
        assert err.std() < noise / 300.0

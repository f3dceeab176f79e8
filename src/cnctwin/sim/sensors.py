"""External sensors with their own clocks: rotary dynamometer and thermal camera.

Each sensor samples the *true* process signals on its own clock (offset + drift against the
recording time base), adds its own noise/drift, and returns a
:class:`cnctwin.ExternalChannel` that is *not* aligned (``offset_s = drift_ppm = 0``,
``aligned = False``): recovering offset and drift is the job of the alignment code. The true
clock parameters go into ``truth.json``. CSV writers match the readers
:func:`cnctwin.iotools.dynamometer.read_dynamometer_csv` and
:func:`cnctwin.iotools.thermal.read_thermal_camera_csv`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
import pandas as pd
from numba import njit
from numpy.typing import ArrayLike, NDArray

from cnctwin.exceptions import ConfigError
from cnctwin.recording import ExternalChannel

__all__ = [
    "Dynamometer",
    "ThermalCamera",
    "dynamometer_channel",
    "format_csv_fixed",
    "thermal_camera_channel",
    "write_dynamometer_csv",
    "write_thermal_camera_csv",
]


@dataclass(frozen=True)
class Dynamometer:
    """Rotary dynamometer (Kistler-type, thesis Fig. 3.5) with charge amplifier and DAQ.

    Attributes
    ----------
    fs_hz : float
        Sample rate of its DAQ [Hz]. [E] 1000
    clock_offset_s : float
        Recording time of its own t = 0 [s] (negative: started before the edge recording).
        [E] -1.7
    clock_drift_ppm : float
        Its clock runs fast by this much [ppm]. [E] 35
    torque_noise_nm : float
        Torque noise std [Nm]. [E] 0.05
    force_noise_n : float
        Force noise std [N]. [E] 8
    torque_drift_nm_per_s : float
        Charge-amplifier drift of the torque zero [Nm/s]. [E] 2e-4
    force_drift_n_per_s : float
        Drift of the force zeros [N/s]. [E] 0.05
    """

    fs_hz: float = 1000.0
    clock_offset_s: float = -1.7
    clock_drift_ppm: float = 35.0
    torque_noise_nm: float = 0.05
    force_noise_n: float = 8.0
    torque_drift_nm_per_s: float = 2e-4
    force_drift_n_per_s: float = 0.05


@dataclass(frozen=True)
class ThermalCamera:
    """FLIR thermal camera reading the tool tip right after extraction (thesis §5.2).

    Attributes
    ----------
    clock_offset_s : float
        Recording time of its own t = 0 [s] (negative: started before the recording). [E] -12.5
    clock_drift_ppm : float
        Clock drift [ppm]. [E] -60
    noise_c : float
        Reading noise std [degC]. [E] 4 (emissivity/ROI uncertainty)
    delay_s : float
        Reading taken this long after the tool leaves the hole [s]. [E] 0.3
    """

    clock_offset_s: float = -12.5
    clock_drift_ppm: float = -60.0
    noise_c: float = 4.0
    delay_s: float = 0.3


def _own_to_recording(
    own_s: NDArray[np.float64], offset_s: float, drift_ppm: float
) -> NDArray[np.float64]:
    return own_s * (1.0 + drift_ppm * 1e-6) + offset_s


def dynamometer_channel(
    time_s: ArrayLike,
    mz_nm: ArrayLike,
    fz_n: ArrayLike,
    *,
    fx_n: ArrayLike | None = None,
    fy_n: ArrayLike | None = None,
    sensor: Dynamometer | None = None,
    rng: np.random.Generator | None = None,
    source: str = "cnctwin.sim",
) -> ExternalChannel:
    """Sample true torque/forces on the dynamometer's own clock.

    Parameters
    ----------
    time_s : array-like
        Recording time of the true signals (seconds after the first HF cycle) [s].
    mz_nm, fz_n : array-like
        True torque [Nm] and thrust [N] on that time base.
    fx_n, fy_n : array-like, optional
        True lateral forces [N] (milling).
    sensor : Dynamometer, optional
        Sensor and clock parameters.
    rng : numpy.random.Generator, optional
        Noise source (default seed 0).
    source : str
        Written to ``channel.source``.

    Returns
    -------
    ExternalChannel
        ``"dynamometer"``, columns ``fx_n, fy_n, fz_n, mz_nm`` indexed by own ``time_s``;
        not aligned.
    """
    s = sensor if sensor is not None else Dynamometer()
    g = rng if rng is not None else np.random.default_rng(0)
    t = np.asarray(time_s, dtype=np.float64)
    if t.size < 2:
        raise ConfigError("dynamometer_channel needs at least two true samples")
    t0_own = (t[0] - s.clock_offset_s) / (1.0 + s.clock_drift_ppm * 1e-6)
    t1_own = (t[-1] - s.clock_offset_s) / (1.0 + s.clock_drift_ppm * 1e-6)
    k0 = max(0, math.ceil(t0_own * s.fs_hz))
    k1 = math.floor(t1_own * s.fs_hz)
    own = np.arange(k0, k1 + 1, dtype=np.float64) / s.fs_hz
    tr = _own_to_recording(own, s.clock_offset_s, s.clock_drift_ppm)
    noise = g.standard_normal((own.size, 4))
    cols: dict[str, NDArray[np.float64]] = {}
    zero = np.zeros(t.size)
    for j, (name, true, sd, drift) in enumerate(
        (
            ("fx_n", fx_n, s.force_noise_n, s.force_drift_n_per_s),
            ("fy_n", fy_n, s.force_noise_n, s.force_drift_n_per_s),
            ("fz_n", fz_n, s.force_noise_n, s.force_drift_n_per_s),
            ("mz_nm", mz_nm, s.torque_noise_nm, s.torque_drift_nm_per_s),
        )
    ):
        x = zero if true is None else np.asarray(true, dtype=np.float64)
        cols[name] = np.interp(tr, t, x) + sd * noise[:, j] + drift * own
    data = pd.DataFrame(cols, index=pd.Index(own, name="time_s"))
    return ExternalChannel(
        name="dynamometer",
        data=data,
        units={"fx_n": "N", "fy_n": "N", "fz_n": "N", "mz_nm": "N*m"},
        fs_hz=s.fs_hz,
        source=source,
    )


def thermal_camera_channel(
    extraction_time_s: ArrayLike,
    hole: ArrayLike,
    temperature_c: ArrayLike,
    *,
    camera: ThermalCamera | None = None,
    rng: np.random.Generator | None = None,
    source: str = "cnctwin.sim",
) -> ExternalChannel:
    """One reading per hole, ``delay_s`` after extraction, on the camera's own clock.

    Parameters
    ----------
    extraction_time_s : array-like
        Recording time at which each hole's tool left the workpiece [s].
    hole : array-like of int
        Hole numbers.
    temperature_c : array-like
        True tool-tip temperature at the reading [degC].
    camera : ThermalCamera, optional
        Sensor parameters.
    rng : numpy.random.Generator, optional
        Noise source.
    source : str
        Written to ``channel.source``.
    """
    c = camera if camera is not None else ThermalCamera()
    g = rng if rng is not None else np.random.default_rng(0)
    tr = np.asarray(extraction_time_s, dtype=np.float64) + c.delay_s
    own = (tr - c.clock_offset_s) / (1.0 + c.clock_drift_ppm * 1e-6)
    temp = np.asarray(temperature_c, dtype=np.float64) + c.noise_c * g.standard_normal(tr.size)
    data = pd.DataFrame(
        {"hole": np.asarray(hole, dtype=np.int64), "temperature_c": temp},
        index=pd.Index(own, name="time_s"),
    )
    return ExternalChannel(
        name="thermal_camera", data=data, units={"temperature_c": "degC"}, fs_hz=None, source=source
    )


def write_dynamometer_csv(channel: ExternalChannel, path: str | PathLike[str]) -> Path:
    """Write ``time_s,fx_n,fy_n,fz_n,mz_nm`` (header line, SI units)."""
    p = Path(path)
    df = channel.data.reindex(columns=["fx_n", "fy_n", "fz_n", "mz_nm"]).fillna(0.0)
    df.to_csv(p, index=True, index_label="time_s", float_format="%.6g")
    return p


def write_thermal_camera_csv(channel: ExternalChannel, path: str | PathLike[str]) -> Path:
    """Write ``time_s,hole,temperature_c``."""
    p = Path(path)
    channel.data[["hole", "temperature_c"]].to_csv(
        p, index=True, index_label="time_s", float_format="%.6g"
    )
    return p


@njit(cache=True)
def _fixed_csv_kernel(
    values: NDArray[np.float64], decimals: NDArray[np.int64]
) -> NDArray[np.uint8]:  # pragma: no cover - compiled
    n, m = values.shape
    width = 24 + int(decimals.max()) if m else 1
    buf = np.empty(n * m * width + 1, dtype=np.uint8)
    digits = np.empty(24, dtype=np.uint8)
    pos = 0
    for i in range(n):
        for j in range(m):
            d = decimals[j]
            x = values[i, j]
            if not math.isfinite(x):  # 'nan', 'inf', '-inf' as np.savetxt writes them
                if x != x:
                    buf[pos] = 110
                    buf[pos + 1] = 97
                    buf[pos + 2] = 110
                    pos += 3
                else:
                    if x < 0.0:
                        buf[pos] = 45
                        pos += 1
                    buf[pos] = 105
                    buf[pos + 1] = 110
                    buf[pos + 2] = 102
                    pos += 3
            else:
                scale = 1
                for _ in range(d):
                    scale *= 10
                q = int(round(abs(x) * scale))  # noqa: RUF046 - numba typing
                ip = q // scale
                fp = q - ip * scale
                if x < 0.0 and q != 0:
                    buf[pos] = 45
                    pos += 1
                k = 0
                if ip == 0:
                    digits[0] = 48
                    k = 1
                while ip > 0:
                    digits[k] = 48 + ip % 10
                    ip //= 10
                    k += 1
                for t in range(k - 1, -1, -1):
                    buf[pos] = digits[t]
                    pos += 1
                if d > 0:
                    buf[pos] = 46
                    pos += 1
                    for t in range(d - 1, -1, -1):
                        buf[pos + t] = 48 + fp % 10
                        fp //= 10
                    pos += d
            buf[pos] = 44 if j < m - 1 else 10
            pos += 1
    return buf[:pos]


def format_csv_fixed(values: ArrayLike, decimals: ArrayLike) -> str:
    """CSV rows of fixed-point numbers, one row per line (what ``%.{d}f`` gives per column).

    About 7x faster than ``np.savetxt`` / ``%``-formatting for the 1 kHz dynamometer files of
    the long scenarios (the simulator's largest cost after the kernels, session 2).

    Parameters
    ----------
    values : array-like, shape (n, m)
        Values; NaN and infinities are written as ``nan``, ``inf``, ``-inf``.
    decimals : array-like of int, shape (m,)
        Digits after the decimal point per column (0-12); choose them below the channel's
        noise (dynamometer: forces 1e-4 N against 8 N noise, torque 1e-5 Nm against 0.05 Nm).

    Returns
    -------
    str
        The rows, each ended by ``\\n``.
    """
    arr = np.ascontiguousarray(values, dtype=np.float64)
    dec = np.ascontiguousarray(decimals, dtype=np.int64)
    if arr.ndim != 2 or dec.shape != (arr.shape[1],):
        raise ConfigError(f"format_csv_fixed: values must be (n, m) and decimals (m,), got "
                          f"{arr.shape} and {dec.shape}")
    if dec.size and (dec.min() < 0 or dec.max() > 12):
        raise ConfigError(f"format_csv_fixed: decimals must be 0-12, got {dec.tolist()}")
    if arr.size and np.nanmax(np.abs(np.where(np.isfinite(arr), arr, 0.0))) * 10.0 ** (
            dec.max()) >= 9e18:
        raise ConfigError("format_csv_fixed: a value is too large for fixed-point output")
    return bytes(_fixed_csv_kernel(arr, dec)).decode("ascii")

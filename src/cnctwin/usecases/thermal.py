"""Tool-tip temperature: camera readings per hole and a soft sensor for every hole.

Thesis chapter 5.2 (Figure 5.5): a FLIR camera reads the drill tip right after it leaves each
hole; over a set of 6 consecutive holes the tip heats up to about 300 °C, and the spindle
current of the last holes of every set rises with it (chapter 5.1). A camera is not there in
production, so :class:`ToolThermalModel` predicts the tip temperature of every hole from what the
drive records: the cutting energy of the hole (heat in) and the time since the previous hole
(cooling), calibrated once on camera readings.

Model (lumped, first order, one step per hole)::

    T_k = T_amb + (T_{k-1} - T_amb) exp(-dt_k / tau) + E_k / C_eff

``E_k`` is the cutting energy of hole k [J] (:func:`cnctwin.usecases.holes.hole_record`),
``C_eff = C / eta`` the heat capacity of the tip divided by the fraction of the cutting energy
that flows into the tool [J/K], ``tau = R C`` the cooling time constant [s], and ``dt_k`` the
time between the ends of holes k-1 and k [s].

References
----------
.. [1] Thesis, Koç University, chapter 5.2, Figure 5.5.
.. [2] Komanduri, R., Hou, Z. B., "Thermal modeling of the metal cutting process", Int. J.
   Mech. Sci. 43 (2001): only a small fraction (about 5-15 %) of the cutting energy goes into a
   carbide tool.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from cnctwin.exceptions import ConfigError, IdentificationError
from cnctwin.recording import ExternalChannel

__all__ = [
    "ToolThermalModel",
    "estimate_camera_offset",
    "merge_camera",
    "simulate_tool_temperature",
]


def _camera_frame(channel_or_df: ExternalChannel | pd.DataFrame) -> pd.DataFrame:
    """Camera readings as ``time_s`` (recording time), ``hole``, ``temperature_c``."""
    if isinstance(channel_or_df, ExternalChannel):
        d = channel_or_df.data
        t = channel_or_df.time_on_recording_s()
    else:
        d = channel_or_df
        if "time_s" in d.columns:
            t = d["time_s"].to_numpy(dtype=np.float64)
        else:
            t = np.asarray(d.index, dtype=np.float64)
    if "temperature_c" not in d.columns:
        raise ConfigError(
            f"camera readings need a 'temperature_c' column; found {list(d.columns)}"
        )
    out = pd.DataFrame(
        {"time_s": t, "temperature_c": d["temperature_c"].to_numpy(dtype=np.float64)}
    )
    if "hole" in d.columns:
        out["hole"] = d["hole"].to_numpy()
    return out


def estimate_camera_offset(
    extraction_s: ArrayLike,
    reading_s: ArrayLike,
    *,
    max_delay_s: float = 2.0,
    max_offset_s: float = 600.0,
) -> float:
    """Clock offset that puts most camera readings just after a hole's extraction [s].

    Candidates are the differences between every extraction and every reading of the first 30
    of each (within ``max_offset_s``); the winner puts the most readings within
    ``(0, max_delay_s]`` after an extraction, ties broken by the smaller median delay.

    Parameters
    ----------
    extraction_s : array-like
        Times at which the tool left each hole (recording clock) [s].
    reading_s : array-like
        Camera reading times on the camera clock (or with a wrong offset) [s].
    max_delay_s : float, default 2
        Longest delay between extraction and reading [s].
    max_offset_s : float, default 600
        Largest offset considered [s].

    Returns
    -------
    float
        Offset to add to the reading times [s].
    """
    ext = np.sort(np.asarray(extraction_s, dtype=np.float64))
    rd = np.sort(np.asarray(reading_s, dtype=np.float64))
    if ext.size == 0 or rd.size == 0:
        raise IdentificationError("need extraction and reading times to align the camera")
    cands = (ext[:30, None] - rd[None, :30]).ravel()
    cands = cands[np.abs(cands) <= max_offset_s]
    best = (-1, math.inf, 0.0)
    for c in np.unique(np.round(cands, 6)):
        # shift so that the reading sits mid-way in the delay window of its extraction
        for shift in (c + 1e-3, c + 0.5 * max_delay_s):
            t = rd + shift
            j = np.searchsorted(ext, t, side="left") - 1
            ok = j >= 0
            delay = np.where(ok, t - ext[np.maximum(j, 0)], np.inf)
            hit = (delay > 0) & (delay <= max_delay_s)
            n = int(hit.sum())
            med = float(np.median(delay[hit])) if n else math.inf
            if n > best[0] or (n == best[0] and med < best[1]):
                best = (n, med, float(shift))
    # refine: move so that the smallest delay is just above zero
    t = rd + best[2]
    j = np.searchsorted(ext, t, side="left") - 1
    ok = j >= 0
    delay = t[ok] - ext[j[ok]]
    delay = delay[(delay > 0) & (delay <= max_delay_s)]
    return best[2] - float(delay.min()) + 1e-6 if delay.size else best[2]


def merge_camera(
    holes: pd.DataFrame,
    channel_or_df: ExternalChannel | pd.DataFrame,
    *,
    on: str = "hole",
    time_column: str = "extraction_s",
    max_delay_s: float = 2.0,
    offset_s: float | None = None,
) -> pd.DataFrame:
    """Camera readings merged into the hole record.

    Parameters
    ----------
    holes : pandas.DataFrame
        Hole record (:func:`~cnctwin.usecases.holes.hole_record`).
    channel_or_df : ExternalChannel or pandas.DataFrame
        The ``"thermal_camera"`` channel (columns ``hole``, ``temperature_c``; index own
        ``time_s``) or a DataFrame with ``temperature_c`` and ``hole`` and/or ``time_s``.
    on : {'hole', 'time'}
        ``'hole'`` joins on the hole index; ``'time'`` assigns each reading to the hole whose
        extraction precedes it by at most ``max_delay_s``.
    time_column : str, default 'extraction_s'
        Hole column with the extraction time (same clock as the readings) [s].
    max_delay_s : float, default 2
        Longest extraction-to-reading delay for ``on='time'`` [s].
    offset_s : float, optional
        Added to the reading times for ``on='time'``. ``None`` uses the channel's own
        ``offset_s``/``drift_ppm`` if it is marked ``aligned``, else estimates the offset with
        :func:`estimate_camera_offset`.

    Returns
    -------
    pandas.DataFrame
        ``holes`` with ``camera_temperature_c`` and ``camera_time_s`` (NaN where no reading);
        ``attrs["camera_offset_s"]`` and ``attrs["camera_unmatched"]`` (readings without a hole).
    """
    cam = _camera_frame(channel_or_df)
    out = holes.copy()
    out.attrs = dict(holes.attrs)
    if on == "hole":
        if "hole" not in cam.columns:
            raise ConfigError("camera readings have no 'hole' column; use on='time'")
        c = cam.groupby("hole", sort=False).last()
        out["camera_temperature_c"] = out["hole"].map(c["temperature_c"]).astype(float)
        out["camera_time_s"] = out["hole"].map(c["time_s"]).astype(float)
        out.attrs["camera_unmatched"] = int((~c.index.isin(out["hole"])).sum())
        return out
    if on != "time":
        raise ConfigError(f"on must be 'hole' or 'time', not {on!r}")
    aligned = isinstance(channel_or_df, ExternalChannel) and channel_or_df.aligned
    ext = holes[time_column].to_numpy(dtype=np.float64)
    t = cam["time_s"].to_numpy(dtype=np.float64)
    if offset_s is None and not aligned:
        offset_s = estimate_camera_offset(ext, t, max_delay_s=max_delay_s)
    t = t + (offset_s or 0.0)
    order = np.argsort(ext)
    j = np.searchsorted(ext[order], t, side="left") - 1
    temp = np.full(len(out), np.nan)
    when = np.full(len(out), np.nan)
    unmatched = 0
    for k, jj in enumerate(j):
        if jj < 0 or not 0 < t[k] - ext[order][jj] <= max_delay_s:
            unmatched += 1
            continue
        temp[order[jj]] = cam["temperature_c"].iloc[k]
        when[order[jj]] = t[k]
    out["camera_temperature_c"] = temp
    out["camera_time_s"] = when
    out.attrs["camera_offset_s"] = float(offset_s or 0.0)
    out.attrs["camera_unmatched"] = unmatched
    return out


def simulate_tool_temperature(
    energy_j: ArrayLike,
    dt_s: ArrayLike,
    *,
    tau_s: float,
    c_eff_j_per_k: float,
    ambient_c: float = 25.0,
    initial_c: float | None = None,
) -> NDArray[np.float64]:
    """Tool-tip temperature after each hole from the lumped per-hole model [°C].

    Parameters
    ----------
    energy_j : array-like
        Cutting energy of each hole [J].
    dt_s : array-like
        Time since the previous hole (first value ignored unless ``initial_c`` is given) [s].
    tau_s : float
        Cooling time constant [s].
    c_eff_j_per_k : float
        Effective heat capacity C / eta [J/K].
    ambient_c : float, default 25
        Ambient temperature [°C].
    initial_c : float, optional
        Temperature before the first hole; default ambient.

    Returns
    -------
    numpy.ndarray
        Temperature after each hole [°C].

    Notes
    -----
    ``T_k = T_amb + (T_{k-1} - T_amb) exp(-dt_k / tau) + E_k / C_eff``.
    """
    e = np.asarray(energy_j, dtype=np.float64)
    dt = np.asarray(dt_s, dtype=np.float64)
    if e.shape != dt.shape:
        raise ConfigError(f"energy_j has {e.size} values, dt_s {dt.size}")
    a = np.exp(-np.where(np.isfinite(dt), dt, np.inf) / tau_s)
    y = 0.0 if initial_c is None else initial_c - ambient_c
    out = np.empty(e.size)
    for k in range(e.size):
        y = y * a[k] + (e[k] if np.isfinite(e[k]) else 0.0) / c_eff_j_per_k
        out[k] = y
    return out + ambient_c


@dataclass
class ToolThermalModel:
    """Per-hole lumped tool-temperature model (soft sensor), calibrated on camera readings.

    Attributes
    ----------
    tau_s : float
        Cooling time constant [s].
    c_eff_j_per_k : float
        Effective heat capacity C / eta [J/K] (larger = less heating per joule).
    ambient_c : float
        Ambient temperature [°C].
    energy_column : str
        Hole-record column with the cutting energy [J].
    time_column : str
        Hole-record column with the time at the end of each hole [s].
    rmse_c : float
        RMS residual of the calibration [°C].
    n_points : int
        Camera readings used in the fit.
    std : dict
        Standard errors of the fitted parameters (from the Jacobian).
    """

    tau_s: float = float("nan")
    c_eff_j_per_k: float = float("nan")
    ambient_c: float = 25.0
    energy_column: str = "energy_j"
    time_column: str = "end_s"
    rmse_c: float = float("nan")
    n_points: int = 0
    std: dict[str, float] = field(default_factory=dict)

    def _inputs(self, holes: pd.DataFrame) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        for c in (self.energy_column, self.time_column):
            if c not in holes.columns:
                raise ConfigError(f"hole record has no column {c!r}; run hole_record first")
        e = holes[self.energy_column].to_numpy(dtype=np.float64)
        t = holes[self.time_column].to_numpy(dtype=np.float64)
        dt = np.concatenate([[np.inf], np.diff(t)])
        return e, dt

    def fit(
        self,
        holes: pd.DataFrame,
        camera_temperature_c: ArrayLike,
        *,
        fit_ambient: bool = False,
        tau0_s: float = 30.0,
    ) -> ToolThermalModel:
        """Least-squares calibration of ``tau_s``, ``1/C_eff`` (and the ambient) on readings.

        Parameters
        ----------
        holes : pandas.DataFrame
            Hole record in drilling order (every hole, also those without a reading: their
            heat still counts).
        camera_temperature_c : array-like
            Reading per hole, NaN where none [°C].
        fit_ambient : bool, default False
            Fit the ambient temperature too; otherwise ``ambient_c`` is kept.
        tau0_s : float, default 30
            Starting value of the time constant [s].

        Returns
        -------
        ToolThermalModel
            ``self``, calibrated.
        """
        e, dt = self._inputs(holes)
        y = np.asarray(camera_temperature_c, dtype=np.float64)
        if y.size != e.size:
            raise ConfigError(f"{y.size} camera values for {e.size} holes")
        ok = np.isfinite(y)
        if ok.sum() < (4 if fit_ambient else 3):
            raise IdentificationError(
                f"need at least {4 if fit_ambient else 3} camera readings, got {int(ok.sum())}"
            )
        e_ok = np.where(np.isfinite(e), e, 0.0)
        first = y[ok][0] - self.ambient_c
        g0 = max(first, 1.0) / max(float(np.median(e_ok[e_ok > 0])) if (e_ok > 0).any()
                                   else 1.0, 1e-9)

        def resid(p: NDArray[np.float64]) -> NDArray[np.float64]:
            tau, g = math.exp(p[0]), math.exp(p[1])
            amb = p[2] if fit_ambient else self.ambient_c
            pred = simulate_tool_temperature(e_ok, dt, tau_s=tau, c_eff_j_per_k=1.0 / g,
                                             ambient_c=amb)
            return np.asarray(pred[ok] - y[ok])

        x0 = [math.log(tau0_s), math.log(g0)] + ([self.ambient_c] if fit_ambient else [])
        sol = least_squares(resid, np.asarray(x0, dtype=np.float64), method="lm")
        if not sol.success:
            raise IdentificationError(f"thermal fit did not converge: {sol.message}")
        tau, g = math.exp(sol.x[0]), math.exp(sol.x[1])
        self.tau_s = tau
        self.c_eff_j_per_k = 1.0 / g
        if fit_ambient:
            self.ambient_c = float(sol.x[2])
        r = sol.fun
        self.n_points = int(ok.sum())
        self.rmse_c = float(np.sqrt(np.mean(r * r)))
        dof = max(self.n_points - len(x0), 1)
        try:
            cov = np.linalg.inv(sol.jac.T @ sol.jac) * float(r @ r) / dof
            sd = np.sqrt(np.diag(cov))
            self.std = {"tau_s": tau * float(sd[0]), "c_eff_j_per_k": float(sd[1]) / g}
            if fit_ambient:
                self.std["ambient_c"] = float(sd[2])
        except np.linalg.LinAlgError:
            self.std = {}
        return self

    def predict(self, holes: pd.DataFrame) -> NDArray[np.float64]:
        """Tool-tip temperature at the end of every hole [°C]."""
        if not (np.isfinite(self.tau_s) and np.isfinite(self.c_eff_j_per_k)):
            raise IdentificationError("ToolThermalModel is not calibrated; call fit() first")
        e, dt = self._inputs(holes)
        return simulate_tool_temperature(
            np.where(np.isfinite(e), e, 0.0), dt, tau_s=self.tau_s,
            c_eff_j_per_k=self.c_eff_j_per_k, ambient_c=self.ambient_c,
        )

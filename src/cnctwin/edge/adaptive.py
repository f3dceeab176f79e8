"""Adaptive feed at the edge: ``cnctwin edge run --adaptive ADAPTIVE.toml`` (issue 26).

Per tool (the active tool from the NC events) a target cutting torque, given or taught in;
every chunk the controller (:class:`cnctwin.usecases.adaptive.AdaptiveFeedController`)
turns the chunk's spindle current into a requested feed override, emitted on the results
stream as ``{"kind": "override", "cycle", "tool", "override_pct", "target", "measured",
"heartbeat", "min_pct", "max_pct"}`` (``heartbeat`` counts up by one per message: a PLC
gateway subscribed through ``--publish`` falls back to 100 % when it stops, docs/adaptive.md);
an overload is also an ``alarm`` (detector ``AdaptiveFeed``). A breakage (the torque falls to
the air level in the middle of a cut) is judged where the engagement model expects a cut: with
the stock (``edge run --stock``) and the tool table (``--tools``) the edge sweeps the recorded
tool positions (``ENC_POS`` of X1, Y1, Z1) through a Z-map of the part, so a tool leaving the
part is not a breakage; without them breakage is not judged. On an OPC UA source whose node
file names ``[write]`` nodes the override goes to the control
(:class:`cnctwin.edge.control_write.ControlWriter`). A tool the file does not name is not
adapted (no override message).

ADAPTIVE.toml::

    min_pct = 50          # override bounds [%]
    max_pct = 120
    gain = 0.5            # share of the model's step per update
    update_s = 0.1        # signal time per override update [s] (breakage: every chunk)
    [tools.2]
    target_nm = 2.6       # hold this cutting torque with T2
    [tools.3]
    teach_in = true       # the first steady cut with T3 (>= 1 s) sets its target
    [tools.4]
    target_from = "opt/optimize.json"   # the torque cnctwin optimize planned for T4
    [tools.5]
    target_w = 800        # hold this cutting power (torque = P / omega at the current speed)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cnctwin.edge.pipeline import Chunk, Result
from cnctwin.engagement import Stock, ZMap
from cnctwin.exceptions import ConfigError
from cnctwin.machine.tooltable import read_toml
from cnctwin.recording import CounterGap
from cnctwin.spindle import SpeedChangeFlags, SpindleModel
from cnctwin.usecases.adaptive import AdaptiveFeedController

__all__ = ["AdaptiveConfig", "AdaptiveProcessor", "planned_torque", "read_adaptive_config"]

_MIN_FEED_MM_MIN = 20.0
"""Below this XY feed the engagement model expects no cut [mm/min] (the encoder's noise over a
20 ms interval is a few mm/min)."""

_TOP = {"min_pct", "max_pct", "gain", "update_s", "tools"}
_TOOL = {"target_nm", "target_w", "target_from", "teach_in", "min_pct", "max_pct"}


@dataclass(frozen=True)
class AdaptiveConfig:
    """What ADAPTIVE.toml says.

    Attributes
    ----------
    min_pct, max_pct : float
        Override bounds [%].
    gain : float
        Controller gain (0..1].
    update_s : float
        Signal time per override update [s].
    tools : dict
        T number -> ``{"target_nm": float | None, "teach_in": bool, "min_pct", "max_pct"}``.
    source : str
        The file.
    """

    min_pct: float = 50.0
    max_pct: float = 120.0
    gain: float = 0.5
    update_s: float = 0.1
    tools: dict[int, dict[str, Any]] = field(default_factory=dict)
    source: str = "adaptive config"


def _num(src: str, key: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"{src}: {key} must be a number, got {v!r}")
    return float(v)


def read_adaptive_config(path: str | Path) -> AdaptiveConfig:
    """Read and check ADAPTIVE.toml.

    Parameters
    ----------
    path : str or path
        The file.

    Returns
    -------
    AdaptiveConfig

    Raises
    ------
    ConfigError
        Unreadable, not TOML, an unknown key, bounds inverted or outside 0-200 %, a tool
        without a target or teach-in, a target that is not positive; the message names the
        file and the key.
    """
    src = str(path)
    data = read_toml(path, what="adaptive configuration")
    bad = sorted(set(data) - _TOP)
    if bad:
        raise ConfigError(f"{src}: unknown key {bad[0]!r}; keys: {', '.join(sorted(_TOP))}")
    lo = _num(src, "min_pct", data.get("min_pct", 50.0))
    hi = _num(src, "max_pct", data.get("max_pct", 120.0))
    if not (0.0 < lo <= hi <= 200.0):
        raise ConfigError(f"{src}: override bounds min_pct {lo:g} .. max_pct {hi:g}: give "
                          "0 < min_pct <= max_pct <= 200")
    gain = _num(src, "gain", data.get("gain", 0.5))
    if not (0.0 < gain <= 1.0):
        raise ConfigError(f"{src}: gain {gain:g} must be in (0, 1]")
    update_s = _num(src, "update_s", data.get("update_s", 0.1))
    if not (0.0 < update_s <= 5.0):
        raise ConfigError(f"{src}: update_s {update_s:g} must be in (0, 5] s")
    tools: dict[int, dict[str, Any]] = {}
    raw = data.get("tools", {})
    if not isinstance(raw, dict) or not raw:
        raise ConfigError(f"{src}: no [tools.N] table: name the tools to adapt (target_nm = .. "
                          "or teach_in = true)")
    for key, t in raw.items():
        try:
            num = int(key)
        except ValueError:
            raise ConfigError(f"{src}: [tools.{key}]: the key is the T number") from None
        if not isinstance(t, dict):
            raise ConfigError(f"{src}: [tools.{key}] must be a table")
        unknown = sorted(set(t) - _TOOL)
        if unknown:
            raise ConfigError(f"{src}: tools.{key}.{unknown[0]} is not a key; keys: "
                              f"{', '.join(sorted(_TOOL))}")
        target = t.get("target_nm")
        teach = bool(t.get("teach_in", False))
        target_w = t.get("target_w")
        given = [k for k in ("target_nm", "target_w", "target_from", "teach_in") if k in t]
        if len(given) > 1:
            raise ConfigError(f"{src}: tools.{key}: give one of target_nm, target_w, "
                              f"target_from, teach_in (not {' and '.join(given)})")
        if target_w is not None and not _num(src, f"tools.{key}.target_w", target_w) > 0:
            raise ConfigError(f"{src}: tools.{key}.target_w must be a positive power [W]")
        if "target_from" in t:
            target = planned_torque(Path(src).parent / str(t["target_from"]), num,
                                    where=f"{src}: tools.{key}.target_from")
        if target is None and not teach and target_w is None:
            raise ConfigError(f"{src}: tools.{key}: give target_nm, target_w, target_from "
                              "(optimize.json) or teach_in = true")
        if target is not None and not _num(src, f"tools.{key}.target_nm", target) > 0:
            raise ConfigError(f"{src}: tools.{key}.target_nm must be a positive torque [Nm]")
        tlo = _num(src, f"tools.{key}.min_pct", t.get("min_pct", lo))
        thi = _num(src, f"tools.{key}.max_pct", t.get("max_pct", hi))
        if not (lo <= tlo <= thi <= hi):
            raise ConfigError(f"{src}: tools.{key} bounds {tlo:g} .. {thi:g} % must lie within "
                              f"the file's {lo:g} .. {hi:g} %")
        tools[num] = {"target_nm": None if target is None else float(target),
                      "target_w": None if target_w is None else float(target_w),
                      "teach_in": teach, "min_pct": tlo, "max_pct": thi}
    return AdaptiveConfig(min_pct=lo, max_pct=hi, gain=gain, update_s=update_s, tools=tools,
                          source=src)


def planned_torque(path: str | Path, tool: int, *, where: str = "target_from") -> float:
    """The mean cutting torque ``cnctwin optimize`` planned for a tool [Nm].

    The length-weighted mean over the tool's cutting pieces of ``optimize.json`` (each
    piece's ``cutting_torque_nm``: the engagement model and the calibrated material at the
    new feed, without the margin).

    Parameters
    ----------
    path : str or path
        ``optimize.json``.
    tool : int
        T number.
    where : str
        Named in errors (the config file and key).

    Returns
    -------
    float

    Raises
    ------
    ConfigError
        Unreadable, not an optimize.json, or no cut of this tool in it.
    """
    import json

    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{where}: cannot read {p} ({exc}); give the optimize.json of "
                          "'cnctwin optimize'") from None
    lines = doc.get("lines") if isinstance(doc, dict) else None
    if not isinstance(lines, list):
        raise ConfigError(f"{where}: {p} is not an optimize.json (no 'lines')")
    num = den = 0.0
    for ln in lines:
        for pc in ln.get("pieces", []) if isinstance(ln, dict) else []:
            tq = pc.get("cutting_torque_nm")
            if pc.get("tool") == tool and isinstance(tq, int | float) and tq > 0:
                w = float(pc.get("length_mm") or 0.0) or 1e-9
                num += w * float(tq)
                den += w
    if den <= 0.0:
        raise ConfigError(f"{where}: {p} plans no cut with T{tool} (re-run 'cnctwin optimize' "
                          "with this version, or give target_nm)")
    return num / den


class AdaptiveProcessor:
    """Requested feed override per chunk for the adapted tools (an edge processor).

    Parameters
    ----------
    model : SpindleModel
        The calibrated spindle (the soft sensor).
    config : AdaptiveConfig
        Targets and bounds per tool.
    spindle : str, default 'SP1'
        Spindle axis.
    teach_s : float, default 1.0
        Steady cutting time that teaches a tool's target [s].
    stock : Stock, optional
        The raw part: with ``diameters`` the engagement model that judges breakage.
    diameters : dict, optional
        T number -> tool diameter [mm] (from the tool table).
    coefficients : MillingCoefficients, optional
        The workpiece's milling coefficients (calibrated into the machine file, or the
        library's): with the engagement model the controller's edge torque T_e = k A (A the
        edge term of the mean torque A + B c at the present engagement, k the measured-to-
        model ratio, adapted online) instead of a fixed share of the target.
    flutes : dict, optional
        T number -> flutes (from the tool table).
    """

    name = "adaptive"

    def __init__(self, model: SpindleModel, config: AdaptiveConfig, *, spindle: str = "SP1",
                 teach_s: float = 1.0, stock: Stock | None = None,
                 diameters: dict[int, float] | None = None,
                 coefficients: Any = None, flutes: dict[int, int] | None = None) -> None:
        self.coefficients = coefficients
        self.flutes = dict(flutes or {})
        self._model: tuple[float, float] | None = None  # (A, A + B c) of the last chunk
        self._k: dict[int, float] = {}
        self.zmap = ZMap(stock) if stock is not None and diameters else None
        self.diameters = dict(diameters or {})
        self._last_xy: tuple[float, float] | None = None
        self._feeds: list[float] = []
        self.model = model
        self.config = config
        self.spindle = spindle
        self.teach_s = teach_s
        self._tool = 0
        self._ctrl: dict[int, AdaptiveFeedController] = {}
        self._teach: dict[int, list[float]] = {}
        self._teach_flags: SpeedChangeFlags | None = None
        self._alarmed: set[tuple[int, str]] = set()
        self.heartbeat = 0

    def _controller(self, tool: int, fs: float, *, taught_nm: float | None = None,
                    speed_rpm: float | None = None) -> AdaptiveFeedController | None:
        spec = self.config.tools.get(tool)
        if spec is None:
            return None
        target = spec["target_nm"] if spec["target_nm"] is not None else taught_nm
        if target is None and spec.get("target_w") is not None and speed_rpm:
            target = spec["target_w"] / (abs(speed_rpm) * 2.0 * math.pi / 60.0)
        if tool not in self._ctrl and target is not None:
            self._ctrl[tool] = AdaptiveFeedController(
                self.model, target_nm=target, min_pct=spec["min_pct"],
                max_pct=spec["max_pct"], gain=self.config.gain, fs_hz=fs,
                update_s=self.config.update_s)
        return self._ctrl.get(tool)

    def _track_tool(self, chunk: Chunk) -> None:
        ev = chunk.events
        if len(ev) and "active_tool" in ev:
            t = ev["active_tool"].dropna()
            if len(t):
                self._tool = int(t.iloc[-1])

    def _expect_cut(self, chunk: Chunk) -> bool | None:
        """The engagement model: is the active tool in the material at the chunk's end?
        (Every tool's path removes material, adapted or not.) None: no model."""
        if self.zmap is None:
            return None
        cols = [f"ENC_POS|{a}" for a in ("X1", "Y1", "Z1")]
        d = self.diameters.get(self._tool)
        if d is None or not all(c in chunk.signals for c in cols):
            return None
        x, y, z = (np.asarray(chunk.signals[c], dtype=np.float64) for c in cols)
        ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
        if not ok.any():
            return None
        x, y, z = x[ok], y[ok], z[ok]
        eng = self.zmap.sweep(x, y, z, diameter_mm=d)
        k = eng.engaged.size
        tail = slice(min(int(0.8 * k), k - 1), None)
        # the feed: XY speed per sample (from the previous chunk's last position); a tool
        # that stops in the material (the end of a cut inside the part) cuts nothing, so
        # the model expects a cut only while the feed is at least half the cut's own
        px = np.concatenate([[self._last_xy[0]], x]) if self._last_xy else np.r_[x[0], x]
        py = np.concatenate([[self._last_xy[1]], y]) if self._last_xy else np.r_[y[0], y]
        self._last_xy = (float(x[-1]), float(y[-1]))
        v = np.hypot(np.diff(px), np.diff(py)) / chunk.cycle_time_s * 60.0  # [mm/min]
        engaged_now = bool(eng.engaged[tail].all())
        self._model = self._model_torque(eng, v, chunk)
        ref = float(np.median(self._feeds)) if self._feeds else 0.0
        moving = bool(v[tail].min() >= max(_MIN_FEED_MM_MIN, 0.5 * ref))
        if engaged_now and moving:
            self._feeds.extend(v[tail].tolist())
            del self._feeds[:-50]
        elif not engaged_now:
            self._feeds.clear()
        return engaged_now and moving

    def _model_torque(self, eng: Any, v_mm_min: np.ndarray, chunk: Chunk
                      ) -> tuple[float, float] | None:
        """Mean (A, A + B c) over the chunk's cutting samples: the edge and the whole mean
        torque of the linear edge-force model at the present engagement [Nm]."""
        k = self.coefficients
        z = self.flutes.get(self._tool)
        d = self.diameters.get(self._tool)
        n_col = f"CMD_SPEED|{self.spindle}"
        if k is None or z is None or d is None or n_col not in chunk.signals:
            return None
        n = np.abs(np.asarray(chunk.signals[n_col], dtype=np.float64))
        if n.size != eng.entry_rad.size:
            return None
        on = (eng.engaged & np.isfinite(eng.entry_rad) & np.isfinite(eng.exit_rad)
              & (n > 50.0) & (v_mm_min > _MIN_FEED_MM_MIN))
        if not on.any():
            return None
        from cnctwin.sim.cutting import mean_milling_load

        p0, p1, a = eng.entry_rad[on], eng.exit_rad[on], eng.axial_depth_mm[on]
        c = v_mm_min[on] / (n[on] * z)
        edge = mean_milling_load(0.0, a, p0, p1, diameter_mm=d, flutes=z, coefficients=k)
        full = mean_milling_load(c, a, p0, p1, diameter_mm=d, flutes=z, coefficients=k)
        return float(np.mean(edge.torque_nm)), float(np.mean(full.torque_nm))

    def process(self, chunk: Chunk) -> list[Result]:
        """Results for this chunk: one ``override`` (and an ``alarm`` on overload/breakage)."""
        self._track_tool(chunk)
        expect = self._expect_cut(chunk) if chunk.cycles.size else None
        i_col, n_col = f"CURRENT|{self.spindle}", f"CMD_SPEED|{self.spindle}"
        if i_col not in chunk.signals or n_col not in chunk.signals or chunk.cycles.size == 0:
            return []
        fs = 1.0 / chunk.cycle_time_s
        spec = self.config.tools.get(self._tool)
        if spec is None:
            return []
        i = np.asarray(chunk.signals[i_col], dtype=np.float64)
        n = np.asarray(chunk.signals[n_col], dtype=np.float64)
        n_mean = float(np.nanmean(np.abs(n))) if np.isfinite(n).any() else 0.0
        ctrl = self._controller(self._tool, fs,
                                speed_rpm=n_mean if n_mean > 50.0 else None)
        if ctrl is not None and spec.get("target_w") is not None and n_mean > 50.0:
            # a power target: the torque that gives it at the current speed
            ctrl.set_target(spec["target_w"] / (n_mean * 2.0 * math.pi / 60.0))
        if ctrl is None and spec.get("target_w") is not None:
            return []  # a power target waits for the spindle to turn
        if ctrl is None:  # teach-in: the mean torque of the first steady cut
            with np.errstate(invalid="ignore"):
                tau = self.model.cutting_torque(i, n, fs_hz=fs) * np.sign(n)
            if self._teach_flags is None:  # a run-up's current is the rotor's, not the cut's
                self._teach_flags = SpeedChangeFlags(fs_hz=fs, settled_at_start=False)
            ok = (np.isfinite(tau) & (np.abs(n) > 50.0) & (tau > 0.3)
                  & (self._teach_flags.update(n) == 0))
            seen = self._teach.setdefault(self._tool, [])
            if ok.mean() > 0.9:
                seen.extend(tau[ok].tolist())
            if len(seen) >= self.teach_s * fs:
                # the taught target lives in this tool's controller, not in the config
                ctrl = self._controller(self._tool, fs, taught_nm=float(np.mean(seen)))
            if ctrl is None:
                return []
        model = self._model
        k = self._k.get(self._tool, 1.0)
        edge = k * model[0] if model is not None else None
        updates = len(ctrl.state.history)
        st = ctrl.update(i, n, expect_cut=expect, edge_nm=edge)
        if (model is not None and len(st.history) > updates and st.cutting and model[1] > 0
                and math.isfinite(st.torque_nm)):
            # online: the measured-to-model ratio (hardness, wear, the material's scatter)
            self._k[self._tool] = 0.8 * k + 0.2 * st.torque_nm / model[1]
        cyc = int(chunk.cycles[-1])
        self.heartbeat += 1
        out = [Result("override", cyc, {
            "tool": self._tool, "override_pct": st.override_pct, "target": ctrl.target_nm,
            **({"target_w": spec["target_w"]} if spec.get("target_w") is not None else {}),
            "heartbeat": self.heartbeat, "min_pct": ctrl.min_pct, "max_pct": ctrl.max_pct,
            "measured": None if not math.isfinite(st.torque_nm) else st.torque_nm,
            "cutting": st.cutting,
            **({"model_nm": model[1] * self._k.get(self._tool, 1.0),
                "model_factor": self._k.get(self._tool, 1.0), "edge_nm": ctrl.edge_nm}
               if model is not None else {}),
            "units": {"target": "Nm", "measured": "Nm",
                                             "override_pct": "%"}})]
        for flag, fault, msg in (
                (st.overload, "overload", "cutting torque above 1.5 x the target: feed hold"),
                (st.breakage, "breakage", "the cut's torque fell to air while feeding: stop")):
            if flag and (self._tool, fault) not in self._alarmed:
                self._alarmed.add((self._tool, fault))
                out.append(Result("alarm", cyc, {"detector": "AdaptiveFeed", "fault": fault,
                                                 "tool": self._tool, "message": msg}))
        return out

    def gap(self, gap: CounterGap) -> list[Result]:
        """A gap: the controllers keep their state (the next chunk measures anew)."""
        return []

    def finish(self) -> list[Result]:
        """Nothing held back."""
        return []

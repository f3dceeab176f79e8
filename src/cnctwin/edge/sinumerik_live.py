"""The simulated control in real time, with the PLC side of the adaptive feed (issue 26).

``cnctwin simulate --program PART.mpf ... --serve-opcua opc.tcp://HOST:PORT --realtime``
simulates the part while serving it: every ``interval_s`` of control time (default 100 ms,
SINUMERIK's OPC UA rate; 20 ms in the closed-loop test) the values of that interval go out on
the SINUMERIK-style nodes of :mod:`cnctwin.edge.sinumerik_opcua` (positions: the last cycle;
currents, loads, power and speed: the mean over the interval, as the drive's smoothed actual
values), paced to the wall clock. The program is played at the feed override the PLC passes
on (:class:`PlcOverride`): the edge writes its request into a data block
(:data:`PLC_NODES`, writable, only over a secured session with a user when the server has
users), the PLC checks the heartbeat, clamps and forwards it; the simulated control's
interpolator ramps to it (:class:`cnctwin.sim.part.LiveOverride`).

The PLC logic, as docs/adaptive.md asks of the real one:

* no heartbeat yet, or the heartbeat counter unchanged for ``heartbeat_s``: 100 %;
* otherwise the requested override clamped to ``min_pct .. max_pct`` (the builder's bounds);
* a stop or feed-hold request (latched until the operator acknowledges): the program stops.

Every write received is logged with its wall-clock time (:attr:`PlcOverride.writes`), every
served interval with the wall-clock time it went out (:attr:`LiveSinumerikServer.served_at`),
so the loop latency is measured end to end (``benchmarks/bench_adaptive_loop.py``).
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
import urllib.parse
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.edge.sinumerik_opcua import (
    data_value,
    node_ids_for,
    sinumerik_server,
    write_nodes,
)
from cnctwin.exceptions import ConfigError
from cnctwin.sim.recorder import RecordedChunk

__all__ = ["PLC_NODES", "LiveSinumerikServer", "PlcOverride", "write_live_node_file"]

PLC_NODES: dict[str, str] = {
    "override_pct": "ns=2;s=/Plc/DB120.DBB0",
    "heartbeat": "ns=2;s=/Plc/DB120.DBW2",
    "feed_hold": "ns=2;s=/Plc/DB120.DBX4.0",
    "stop": "ns=2;s=/Plc/DB120.DBX4.1",
    "data_time": "ns=2;s=/Plc/DB120.DBD8",
}
"""The adaptive-feed data block the edge writes (a user DB the PLC program reads, clamps and
copies to the channel's override; docs/adaptive.md): override [%] (byte), heartbeat (word,
+1 per value), feed hold and stop requests (bits), and the source time of the newest sample
the override was computed from (a diagnostic for the loop latency)."""

_LAST = ("ENC_POS",)  # served as the interval's last value; the rest as its mean


def write_live_node_file(signals: dict[str, str], text: dict[str, str], path: str | Path, *,
                         interval_s: float) -> Path:
    """Write the node file of a live server: :func:`~cnctwin.edge.sinumerik_opcua.
    write_nodes` with the writable ``[write]`` nodes of :data:`PLC_NODES`.

    Parameters
    ----------
    signals, text : dict
        From :func:`~cnctwin.edge.sinumerik_opcua.node_ids_for`.
    path : str or path
        TOML file to write.
    interval_s : float
        The server's interval (a comment: give it to ``edge run --interval-s``).

    Returns
    -------
    pathlib.Path
    """
    return write_nodes(signals, text, path, write=PLC_NODES, comments=(
        "SINUMERIK-like OPC UA server of cnctwin, live (cnctwin.edge.sinumerik_live)",
        f"values every {interval_s:g} s: edge run --interval-s {interval_s:g}"))


@dataclass
class PlcOverride:
    """The PLC's adaptive-feed logic: heartbeat watchdog, clamp, latched stop requests.

    Parameters
    ----------
    min_pct, max_pct : float, default 50 and 120
        The builder's bounds [%]: whatever the edge writes, the override stays within them.
    heartbeat_s : float, default 0.5
        Without a new heartbeat for this long the override falls back to 100 % [s].

    Attributes
    ----------
    writes : list of tuple
        (wall clock [s, ``time.time()``], key, value) of every write received.
    fallbacks : list of float
        Wall-clock times the watchdog fell back to 100 % [s].
    """

    min_pct: float = 50.0
    max_pct: float = 120.0
    heartbeat_s: float = 0.5
    writes: list[tuple[float, str, Any]] = field(default_factory=list)
    fallbacks: list[float] = field(default_factory=list)
    _override: float | None = None
    _beat: Any = None
    _beat_t: float = -math.inf
    _alive: bool = False
    _stop: str | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self) -> None:
        if not (0.0 < self.min_pct <= self.max_pct <= 200.0):
            raise ConfigError(f"PLC override bounds {self.min_pct:g} .. {self.max_pct:g} %: "
                              "give 0 < min <= max <= 200")
        if not self.heartbeat_s > 0:
            raise ConfigError(f"heartbeat_s must be positive, got {self.heartbeat_s}")

    def on_write(self, key: str, value: Any, now: float | None = None) -> None:
        """A value written by a client (the edge)."""
        t = time.time() if now is None else now
        with self._lock:
            self.writes.append((t, key, value))
            if key == "override_pct":
                self._override = float(value)
            elif key == "heartbeat" and value != self._beat:
                self._beat, self._beat_t = value, t
            elif key in ("stop", "feed_hold") and bool(value) and self._stop is None:
                self._stop = key

    @property
    def stop_request(self) -> str | None:
        """``'stop'`` or ``'feed_hold'`` once requested (latched), else None."""
        return self._stop

    def requested(self, now: float | None = None) -> float | None:
        """The override the control applies next [%]; None: stop the program.

        Parameters
        ----------
        now : float, optional
            Wall-clock time [s] (default ``time.time()``).

        Returns
        -------
        float or None
        """
        t = time.time() if now is None else now
        with self._lock:
            if self._stop is not None:
                return None
            alive = self._override is not None and t - self._beat_t <= self.heartbeat_s
            if self._alive and not alive:
                self.fallbacks.append(t)
            self._alive = alive
            if not alive:
                return 100.0
            assert self._override is not None
            return min(max(self._override, self.min_pct), self.max_pct)


_WRITE_TYPES = {"override_pct": "Byte", "heartbeat": "UInt16", "feed_hold": "Boolean",
                "stop": "Boolean", "data_time": "DateTime"}


class LiveSinumerikServer:
    """A SINUMERIK-like OPC UA server the simulator feeds while it runs (a recorder sink).

    Parameters
    ----------
    endpoint : str
        ``opc.tcp://HOST:PORT``.
    plc : PlcOverride
        The PLC logic the written values go to.
    interval_s : float, default 0.1
        Control time between served values [s].
    speed : float, default 1
        Control seconds per wall-clock second (1: real time).
    users : dict, optional
        User name -> password: Basic256Sha256 Sign/SignAndEncrypt with a user only (the
        writable nodes then only from a secured, authenticated session); without: anonymous,
        no security, and the PLC nodes are read-only (nothing can be written unsecured).
    cert_file, key_file : path, optional
        Server certificate (DER) and key (PEM), generated if missing.
    on_listening : callable, optional
        Called with ``(signals, text)`` once the server listens (writes the node file).
    wait_for_client_s : float, default 0
        Before the program starts, wait up to this long for a client's subscription (the
        operator starts the cycle once the edge is connected) [s].

    Attributes
    ----------
    served_at : dict
        Source time of each served interval [ns] -> wall clock when it went out [s].
    """

    def __init__(self, endpoint: str, plc: PlcOverride, *, interval_s: float = 0.1,
                 speed: float = 1.0, users: dict[str, str] | None = None,
                 cert_file: str | Path | None = None, key_file: str | Path | None = None,
                 on_listening: Callable[[dict[str, str], dict[str, str]], Any] | None = None,
                 wait_for_client_s: float = 0.0) -> None:
        u = urllib.parse.urlsplit(endpoint)
        if u.scheme != "opc.tcp" or not u.hostname or not u.port:
            raise ConfigError(f"--serve-opcua {endpoint!r}: expected opc.tcp://HOST:PORT")
        if not (math.isfinite(interval_s) and 0.002 <= interval_s <= 10.0):
            raise ConfigError(f"--serve-interval-s {interval_s}: give 0.002 ... 10 s")
        if not (math.isfinite(speed) and speed > 0):
            raise ConfigError(f"--serve-speed {speed}: give a positive number")
        if users and not (cert_file and key_file):
            raise ConfigError("a secured server needs cert_file and key_file")
        self.endpoint, self.plc, self.interval_s, self.speed = endpoint, plc, interval_s, speed
        self.users, self.cert_file, self.key_file = users, cert_file, key_file
        self.on_listening = on_listening
        self.wait_for_client_s = float(wait_for_client_s)
        self.signals: dict[str, str] = {}
        self.text: dict[str, str] = {}
        self.served_at: dict[int, float] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._nodes: dict[str, Any] = {}
        self._ready = threading.Event()
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self._buf: dict[str, list[np.ndarray]] = {}
        self._buf_cycles: list[np.ndarray] = []
        self._t0_wall: float | None = None
        self._c0: int | None = None
        self._dt = 0.002
        self._t_anchor: tuple[int, int] = (0, 0)
        self._text_now: dict[str, str] = {"program": "", "tool": ""}
        self._text_sent: dict[str, str] = {}
        self._pending: list[Any] = []

    # --------------------------------------------------------------- recorder sink
    def open(self, columns: list[str], meta: Any) -> None:
        """Start serving the columns the simulator records (returns once listening)."""
        self.signals, self.text = node_ids_for(columns, dict(meta.axis_map))
        self._dt = float(meta.cycle_time_s)
        c0, t0 = meta.time_anchors[0]
        self._t_anchor = (int(c0), int(pd.Timestamp(t0).value))
        self._thread = threading.Thread(target=lambda: asyncio.run(self._main()),
                                        name="sinumerik-live", daemon=True)
        self._thread.start()
        self._ready.wait(30)
        if self._error is not None or not self._ready.is_set():
            raise ConfigError(f"the OPC UA server on {self.endpoint} did not start: "
                              f"{self._error or 'no answer within 30 s'}")
        if self.on_listening is not None:
            self.on_listening(self.signals, self.text)
        deadline = time.time() + self.wait_for_client_s
        while time.time() < deadline and not self._subscribed():
            time.sleep(0.05)

    def _subscribed(self) -> bool:
        try:
            subs = self._server.iserver.subscription_service.subscriptions
        except AttributeError:
            return False
        return bool(subs)

    def write(self, chunk: RecordedChunk) -> None:
        """Serve a chunk's intervals, each when its control time has come on the wall clock."""
        if chunk.cycles.size == 0:
            return
        self._track_text(chunk.events)
        if self._c0 is None:
            self._c0, self._t0_wall = int(chunk.cycles[0]), time.time()
        self._buf_cycles.append(chunk.cycles)
        for c in self.signals:
            self._buf.setdefault(c, []).append(np.asarray(chunk.hf[c], dtype=np.float64))
        step = max(1, round(self.interval_s / self._dt))
        cycles = np.concatenate(self._buf_cycles)
        cols = {c: np.concatenate(v) for c, v in self._buf.items()}
        k = 0
        while cycles.size - k >= step:
            self._serve(cycles[k:k + step], {c: v[k:k + step] for c, v in cols.items()})
            k += step
        self._buf_cycles = [cycles[k:]]
        self._buf = {c: [v[k:]] for c, v in cols.items()}

    def close(self, meta: Any) -> None:
        """Serve what is left, then keep serving the last values until :meth:`stop`."""
        cycles = np.concatenate(self._buf_cycles) if self._buf_cycles else np.zeros(0)
        if cycles.size:
            self._serve(cycles.astype(np.int64), {c: np.concatenate(v)
                                                  for c, v in self._buf.items()})
        self._buf_cycles, self._buf = [], {}

    # --------------------------------------------------------------- serving
    def _track_text(self, events: pd.DataFrame) -> None:
        if events is None or not len(events):
            return
        if "active_tool" in events:
            t = events["active_tool"].dropna()
            if len(t):
                self._text_now["tool"] = str(int(t.iloc[-1]))
        if "kind" in events and "path" in events:
            calls = events[(events["kind"] == "call")].dropna(subset=["path"])
            if len(calls):
                self._text_now["program"] = str(calls["path"].iloc[-1])

    def _serve(self, cycles: np.ndarray, cols: dict[str, np.ndarray]) -> None:
        assert self._c0 is not None and self._t0_wall is not None and self._loop is not None
        last = int(cycles[-1])
        due = self._t0_wall + (last + 1 - self._c0) * self._dt / self.speed
        wait = due - time.time()
        if wait > 0:
            time.sleep(wait)
        c0, t0 = self._t_anchor
        t_ns = t0 + round((last - c0) * self._dt * 1e9)
        vals: dict[str, float] = {}
        for c, v in cols.items():
            x = v[-1] if c.split("|", 1)[0] in _LAST else np.nanmean(v) if np.isfinite(
                v).any() else math.nan
            vals[c] = float(x)
        text = {k: v for k, v in self._text_now.items() if self._text_sent.get(k) != v}
        self._text_sent.update(text)
        fut = asyncio.run_coroutine_threadsafe(self._publish(t_ns, vals, text), self._loop)
        self._pending = [f for f in self._pending if not f.done()] + [fut]
        if len(self._pending) > 50:  # the server fell behind: wait rather than pile up
            self._pending[0].result(10)

    async def _publish(self, t_ns: int, vals: dict[str, float], text: dict[str, str]) -> None:
        ts = pd.Timestamp(t_ns, tz="UTC").to_pydatetime()
        for name, value in {**vals, **text}.items():
            await self._server.write_attribute_value(self._nodes[name], data_value(value, ts))
        self.served_at[t_ns] = time.time()

    # --------------------------------------------------------------- server
    def stop(self) -> None:
        """Stop serving (the port is free afterwards)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(15)

    async def _main(self) -> None:
        import logging

        from asyncua import ua

        for name in ("asyncua", "asyncua.server"):
            logging.getLogger(name).setLevel(logging.ERROR)
        try:
            self._loop = asyncio.get_running_loop()
            server, folder = await sinumerik_server(
                self.endpoint, name="SINUMERIK 840D sl (cnctwin simulator, live)",
                users=self.users, cert_file=self.cert_file, key_file=self.key_file)
            idx = 2
            # no value yet, stamped before the program's first cycle: a client subscribing
            # before the program starts gets "waiting for initial data", not a 0.0 newer
            # than everything the program will serve
            t_init = pd.Timestamp(self._t_anchor[1] - round(self.interval_s * 1e9),
                                  tz="UTC").to_pydatetime()
            for name, nid in {**self.signals, **self.text}.items():
                vt = ua.VariantType.Double if name in self.signals else ua.VariantType.String
                init: Any = 0.0 if name in self.signals else ""
                node = await folder.add_variable(ua.NodeId.from_string(nid),
                                                 ua.QualifiedName(nid.split("s=", 1)[1], idx),
                                                 init, varianttype=vt)
                await server.write_attribute_value(node.nodeid, ua.DataValue(
                    ua.Variant(init, vt), SourceTimestamp=t_init, ServerTimestamp=t_init,
                    StatusCode_=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData)))
                self._nodes[name] = node.nodeid
            plc = await server.nodes.objects.add_folder(ua.NodeId("Plc", idx),
                                                        ua.QualifiedName("Plc", idx))
            for key, nid in PLC_NODES.items():
                vt = getattr(ua.VariantType, _WRITE_TYPES[key])
                init = {"Boolean": False, "DateTime": pd.Timestamp(0, tz="UTC").to_pydatetime()
                        }.get(_WRITE_TYPES[key], 0)
                node = await plc.add_variable(ua.NodeId.from_string(nid),
                                              ua.QualifiedName(nid.split("s=", 1)[1], idx),
                                              init, varianttype=vt)
                if self.users:  # writable only where a user must log in over Sign&Encrypt
                    await node.set_writable()
                server.iserver.aspace.set_attribute_value_setter(
                    node.nodeid, ua.AttributeIds.Value, self._setter(key))
            self._server = server
            async with server:
                self._ready.set()
                while not self._stop.is_set():
                    await asyncio.sleep(0.05)
        except BaseException as exc:
            self._error = exc
            self._ready.set()

    def _setter(self, key: str) -> Callable[..., None]:
        def setter(node: Any, attr: Any, value: Any) -> None:
            node.attributes[attr].value = value
            node.attributes[attr].value_callback = None
            v = value.Value.Value if value.Value is not None else None
            if key == "data_time" and v is not None:
                v = int(pd.Timestamp(v).tz_localize("UTC").value
                        if pd.Timestamp(v).tzinfo is None else pd.Timestamp(v).value)
            self.plc.on_write(key, v)
        return setter

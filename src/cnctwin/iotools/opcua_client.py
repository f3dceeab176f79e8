"""OPC UA client source: the control's OPC UA server (SINUMERIK Access MyMachine / OPC UA) into
a :class:`~cnctwin.recording.Recording`.

The variables to record are named in a node file (TOML)::

    [signals]                        # column -> node id (numeric values)
    "ENC_POS|X1" = "ns=2;s=/Channel/MachineAxis/actToolBasePos[u1,1]"
    "CMD_SPEED|SP1" = "ns=2;s=/Channel/Spindle/cmdSpeed[u1,1]"
    [text]                           # LF text values (program, block, tool)
    program = "ns=2;s=/Channel/ProgramInfo/progName[u1]"
    [units]                          # optional, column -> unit
    "ENC_POS|X1" = "mm"
    [write]                          # optional: what the edge may write (adaptive feed)
    override_pct = "ns=2;s=/Plc/DB120.DBB0"
    heartbeat = "ns=2;s=/Plc/DB120.DBW2"
    feed_hold = "ns=2;s=/Plc/DB120.DBX4.0"
    stop = "ns=2;s=/Plc/DB120.DBX4.1"

Every node is checked at connect: a node id that does not exist or cannot be read is a
:class:`~cnctwin.exceptions.ConfigError` naming it (never a silent column of NaN).

**Time base.** The client subscribes with the trigger *status, value and timestamp*, so every
value the server writes arrives with its source timestamp, and each distinct source timestamp
becomes one row (a "cycle" of the recording): the cycle rate is the rate the server delivers
(SINUMERIK: about 100 ms), stated in ``meta.cycle_time_s`` and ``meta.attrs["opcua"]``, not the
2 ms position-control cycle. Within a connection a node that did not report at a timestamp
holds its last value (OPC UA reports changes); across a lost connection nothing is held: the
missing rows are a :class:`~cnctwin.recording.CounterGap` (estimated from the elapsed time) and
the recording goes on after the reconnect.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import threading
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError, FormatError
from cnctwin.recording import CounterGap, Recording, RecordingMeta

__all__ = ["WRITE_KEYS", "NodeMap", "OpcUaClientOptions", "OpcUaRecorder", "read_node_map",
           "record_opcua"]


WRITE_KEYS = ("override_pct", "heartbeat", "feed_hold", "stop", "data_time")
"""Keys of a node file's ``[write]`` table: the requested feed override [%], its heartbeat
counter, the feed-hold and stop requests (booleans), and the source time of the newest
sample the override was computed from (a diagnostic for the loop latency)."""


@dataclass(frozen=True)
class NodeMap:
    """Which node is which signal (:func:`read_node_map`).

    Attributes
    ----------
    signals : dict
        Column (``CODE|AXIS``) -> node id text (numeric values).
    text : dict
        LF signal name -> node id text (strings: program, block, tool).
    units : dict
        Column -> unit.
    write : dict
        What the edge may write to the control (``override_pct``, ``heartbeat``,
        ``feed_hold``, ``stop``, ``data_time``) -> node id (:data:`WRITE_KEYS`).
    """

    signals: dict[str, str]
    text: dict[str, str] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    write: dict[str, str] = field(default_factory=dict)

    @property
    def all(self) -> dict[str, str]:
        """Every name -> node id."""
        return {**self.signals, **self.text}


def read_node_map(path: str | os.PathLike[str]) -> NodeMap:
    """Read a node file (module docstring).

    Parameters
    ----------
    path : str or path-like
        Node file (TOML) written by ``cnctwin simulate --serve-opcua`` or by hand.

    Returns
    -------
    NodeMap

    Raises
    ------
    FormatError
        Not TOML, no ``[signals]`` table, a value that is not a node id text, or a column
        name that is not ``CODE|AXIS`` (the message names the file and the key).
    """
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the node file ({exc.strerror or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise FormatError(f"not TOML: {exc}", path=str(p)) from None
    sig = doc.get("signals")
    if not isinstance(sig, dict) or not sig:
        raise FormatError("needs a [signals] table: column = \"node id\"", path=str(p))
    tables: dict[str, dict[str, str]] = {}
    for name in ("signals", "text", "units", "write"):
        tab = doc.get(name, {})
        if not isinstance(tab, dict):
            raise FormatError(f"[{name}] must be a table", path=str(p))
        for k, v in tab.items():
            if not isinstance(v, str) or not v.strip():
                raise FormatError(f"[{name}] {k!r}: expected a text value, got {v!r}",
                                  path=str(p))
            if name == "write" and k not in WRITE_KEYS:
                raise FormatError(f"[write] {k!r} is not a key; keys: {', '.join(WRITE_KEYS)}",
                                  path=str(p))
            if name == "signals" and "|" not in k:
                raise FormatError(f"[signals] {k!r}: a column is CODE|AXIS, e.g. ENC_POS|X1",
                                  path=str(p))
        tables[name] = {str(k): str(v).strip() for k, v in tab.items()}
    unknown = sorted(set(doc) - {"signals", "text", "units", "write"})
    if unknown:
        raise FormatError(f"unknown table(s) {unknown}; use [signals], [text], [units], "
                          "[write]", path=str(p))
    return NodeMap(tables["signals"], tables.get("text", {}), tables.get("units", {}),
                   tables.get("write", {}))


@dataclass(frozen=True)
class OpcUaClientOptions:
    """How to connect.

    Attributes
    ----------
    security : str
        ``None``, ``Basic256Sha256_Sign`` or ``Basic256Sha256_SignAndEncrypt``.
    cert_file, key_file : str, optional
        The client's certificate (DER or PEM) and private key (PEM), for a secured channel.
    server_cert_file : str, optional
        The server's certificate to trust (default: the one it presents).
    user : str, optional
        User name (with ``password``).
    password : str, optional
        Password (read from a file or environment variable by the command line).
    timeout_s : float, default 10
        Connect and request timeout [s].
    """

    security: str = "None"
    cert_file: str | None = None
    key_file: str | None = None
    server_cert_file: str | None = None
    user: str | None = None
    password: str | None = field(default=None, repr=False)
    timeout_s: float = 10.0


async def _connect(url: str, opts: OpcUaClientOptions) -> Any:
    from asyncua import Client

    client = Client(url, timeout=opts.timeout_s)
    if opts.user:
        client.set_user(opts.user)
        client.set_password(opts.password or "")
    if opts.security not in ("None", "", None):
        if opts.security not in ("Basic256Sha256_Sign", "Basic256Sha256_SignAndEncrypt"):
            raise ConfigError(f"OPC UA security {opts.security!r} is not supported; use None, "
                              "Basic256Sha256_Sign or Basic256Sha256_SignAndEncrypt")
        if not (opts.cert_file and opts.key_file):
            raise ConfigError(f"OPC UA security {opts.security} needs the client's certificate "
                              "and key (--opcua-cert, --opcua-key)")
        mode = opts.security.split("_", 1)[1]
        sec = f"Basic256Sha256,{mode},{opts.cert_file},{opts.key_file}"
        if opts.server_cert_file:
            sec += f",{opts.server_cert_file}"
        await client.set_security_string(sec)
    try:
        await client.connect()
    except Exception as exc:
        raise ConfigError(_connect_message(url, opts, exc)) from None
    return client


def _connect_message(url: str, opts: OpcUaClientOptions, exc: BaseException) -> str:
    text = f"{type(exc).__name__}: {exc}".strip()
    low = text.lower()
    if "badusernameinvalid" in low or "baduseraccessdenied" in low or "identity" in low:
        return (f"OPC UA server {url} refused the user {opts.user!r}: wrong user name or "
                f"password ({text})")
    if "security" in low or "certificate" in low or "badsecurity" in low:
        return (f"OPC UA server {url} refused the secure channel ({text}): check the "
                "certificate, its key and the security policy")
    if isinstance(exc, asyncio.TimeoutError | TimeoutError) and _reachable(url) \
            and opts.security not in ("None", "", None):
        return (f"OPC UA server {url} did not answer the secured channel within "
                f"{opts.timeout_s:g} s: the server certificate given (--server-cert) is not "
                "the server's, or the server does not offer this security policy")
    if isinstance(exc, OSError | asyncio.TimeoutError | TimeoutError):
        return f"cannot reach the OPC UA server {url} ({text})"
    return f"cannot connect to the OPC UA server {url}: {text}"


def _reachable(url: str) -> bool:
    import socket
    import urllib.parse

    u = urllib.parse.urlsplit(url)
    try:
        with socket.create_connection((u.hostname or "", u.port or 4840), timeout=2):
            return True
    except OSError:
        return False


async def _check_nodes(client: Any, nodes: NodeMap) -> dict[str, Any]:
    from asyncua import ua

    out = {}
    for name, text in nodes.all.items():
        try:
            nid = ua.NodeId.from_string(text)
        except Exception:
            raise ConfigError(f"node {name!r}: {text!r} is not an OPC UA node id (e.g. "
                              "ns=2;s=/Channel/Spindle/actSpeed[u1,1])") from None
        node = client.get_node(nid)
        try:
            await node.read_value()
        except ua.UaStatusCodeError as exc:
            if getattr(exc, "code", None) == _WAITING:
                out[name] = node  # exists, no value yet (the program has not started)
                continue
            raise ConfigError(f"node {name!r} = {text}: cannot be read ({exc}); check the "
                              "node id in the node file and the user's access rights") from None
        out[name] = node
    return out


_WAITING = 0x80320000  # BadWaitingForInitialData (OPC UA Part 4, 7.34)


class _Handler:
    def __init__(self, rec: OpcUaRecorder) -> None:
        self.rec = rec

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        dv = data.monitored_item.Value
        if dv.StatusCode is not None and dv.StatusCode.value == _WAITING:
            return  # no value yet (a server that has not started): not a row
        ts = dv.SourceTimestamp or dv.ServerTimestamp
        self.rec._on_value(str(node.nodeid.to_string()), val, ts)

    def status_change_notification(self, status: Any) -> None:
        self.rec._lost.set()


class OpcUaRecorder:
    """Record an OPC UA server's variables until :meth:`stop` (or ``duration_s``).

    Parameters
    ----------
    url : str
        ``opc.tcp://HOST:PORT[/path]``.
    nodes : NodeMap
        What to record.
    options : OpcUaClientOptions, optional
        Security and user.
    interval_s : float, default 0.1
        Publishing interval asked of the server [s] (SINUMERIK: 100 ms and up).
    machine : str, default ''
        Machine name of the recording.
    reconnect_s : float, default 1.0
        Wait between reconnect attempts after the connection is lost [s].

    Raises
    ------
    ConfigError
        At :meth:`start`: the server cannot be reached, refuses the certificate or the user,
        or a node cannot be read (named).
    """

    def __init__(self, url: str, nodes: NodeMap, *, options: OpcUaClientOptions | None = None,
                 interval_s: float = 0.1, machine: str = "", reconnect_s: float = 1.0) -> None:
        if not url.startswith("opc.tcp://"):
            raise ConfigError(f"OPC UA source {url!r} must look like opc.tcp://HOST:4840")
        if not (math.isfinite(interval_s) and 0.001 <= interval_s <= 60):
            raise ConfigError(f"interval_s must be 0.001 ... 60 s, not {interval_s!r}")
        self.url, self.nodes, self.options = url, nodes, options or OpcUaClientOptions()
        self.interval_s, self.machine, self.reconnect_s = interval_s, machine, reconnect_s
        self._id_to_name: dict[str, str] = {}
        self._latest: dict[str, Any] = {}
        self._pending: dict[int, dict[str, Any]] = {}
        self._arrived: dict[int, int] = {}  # source timestamp -> local arrival [ns]
        self._rows: list[tuple[int, int, dict[str, Any]]] = []  # (cycle, t_ns, values)
        self._gaps: list[CounterGap] = []
        self._issues: list[str] = []
        self._cycle = -1
        self._last_t: int | None = None
        self._resumed = False
        self._lock = threading.Lock()
        self._lost = threading.Event()
        self._flush_soon = False
        self.new_rows = threading.Event()
        """Set when rows were added (a consumer clears it and waits: no polling delay)."""
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self.reconnects = 0

    # ------------------------------------------------------------------ values
    def _on_value(self, node_id: str, value: Any, ts: Any) -> None:
        name = self._id_to_name.get(node_id)
        if name is None or ts is None:
            return
        t_ns = int(pd.Timestamp(ts).tz_localize("UTC").value if pd.Timestamp(ts).tzinfo is None
                   else pd.Timestamp(ts).value)
        with self._lock:
            if t_ns not in self._pending:
                self._arrived[t_ns] = time.time_ns()  # aged by our clock, not the server's
            row = self._pending.setdefault(t_ns, {})
            row[name] = value
            done = all(k in row for k in self.nodes.signals)
        if done and not self._flush_soon:
            # every numeric value of this write is here: a row as soon as the rest of this
            # notification batch (the text values of the same write) has been handled
            self._flush_soon = True
            try:
                asyncio.get_running_loop().call_soon(self._flush_now)
            except RuntimeError:  # not on the client's loop (a test calling directly)
                self._flush_now()

    def _flush_now(self) -> None:
        self._flush_soon = False
        self._flush()

    def _flush(self, *, final: bool = False) -> None:
        """Turn pending timestamps into rows: those older than one interval (all values of a
        server write arrive together), or all of them at the end."""
        # a timestamp waits for the rest of its values up to 3 intervals after its first value
        # arrived here (the server's clock may run ahead of or behind ours)
        horizon = time.time_ns() - int(3 * self.interval_s * 1e9)
        sig = self.nodes.signals

        def complete(t: int) -> bool:  # every numeric value of the write (text: on change)
            return all(k in self._pending[t] for k in sig)

        with self._lock:
            ready = sorted(t for t in self._pending if final or self._arrived[t] <= horizon
                           or complete(t))
            if not final and self._pending:
                newest = max(self._pending)  # still arriving, unless complete or aged
                ready = [t for t in ready if t < newest or self._arrived[t] <= horizon
                         or complete(t)]
            for t in ready:
                vals = self._pending.pop(t)
                self._arrived.pop(t, None)
                if not any(k in vals for k in sig):
                    # text only (a program or tool that changed before we subscribed arrives
                    # with its old timestamp; text is reported on change): held into the
                    # next row, not a row of its own
                    self._latest.update(vals)
                    continue
                if self._last_t is not None and t <= self._last_t:
                    self._issues.append(f"source timestamp {pd.Timestamp(t, tz='UTC')} not "
                                        "after the previous one: values merged into it")
                    self._latest.update(vals)
                    continue
                if self._resumed and self._last_t is not None:
                    # after a lost connection: the rows the server delivered meanwhile are
                    # missing (estimated from the timestamps), nothing is held across it
                    step = self.interval_s * 1e9
                    missing = max(0, round((t - self._last_t) / step) - 1)
                    self._gaps.append(CounterGap(self._cycle, self._cycle + missing + 1))
                    self._cycle += missing
                    self._latest.clear()
                self._resumed = False
                self._latest.update(vals)
                self._cycle += 1
                self._rows.append((self._cycle, t, dict(self._latest)))
                self._last_t = t
            if ready:
                self.new_rows.set()

    # ------------------------------------------------------------------ thread
    def start(self) -> OpcUaRecorder:
        """Connect, check every node, subscribe (raises at once on a bad node or login)."""
        self._thread = threading.Thread(target=self._run, name="opcua-recorder", daemon=True)
        self._thread.start()
        self._ready.wait(self.options.timeout_s * 3 + 5)
        if self._error is not None:
            raise self._error
        if not self._ready.is_set():
            raise ConfigError(f"the OPC UA server {self.url} did not answer within "
                              f"{self.options.timeout_s * 3 + 5:g} s")
        return self

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # reported to start() or recording()
            self._error = exc
            self._ready.set()

    async def _session(self, first: bool) -> Any:
        from asyncua import ua

        client = await _connect(self.url, self.options)
        try:
            nodes = await _check_nodes(client, self.nodes)
        except BaseException:
            await client.disconnect()
            raise
        self._id_to_name = {n.nodeid.to_string(): name for name, n in nodes.items()}
        sub = await client.create_subscription(self.interval_s * 1000, _Handler(self))
        mfilter = ua.DataChangeFilter(Trigger=ua.DataChangeTrigger.StatusValueTimestamp)
        await sub._subscribe(list(nodes.values()), mfilter=mfilter, queuesize=1000,
                             sampling_interval=0.0)
        return client

    async def _main(self) -> None:
        import logging

        for name in ("asyncua", "asyncua.client"):  # a lost server is reported by us
            logging.getLogger(name).setLevel(logging.CRITICAL)
        client = await self._session(True)
        self._ready.set()
        last_check = time.monotonic()
        while not self._stop.is_set():
            await asyncio.sleep(min(self.interval_s / 2.0, 0.05))
            self._flush()
            if not self._lost.is_set():
                if time.monotonic() - last_check < 1.0:
                    continue
                last_check = time.monotonic()
                try:
                    await asyncio.wait_for(client.nodes.server_state.read_value(),
                                           min(self.options.timeout_s, 2.0))
                    continue
                except Exception:
                    self._lost.set()
            self._flush(final=True)
            with contextlib.suppress(Exception):
                await client.disconnect()
            while not self._stop.is_set():
                await asyncio.sleep(self.reconnect_s)
                try:
                    client = await self._session(False)
                except ConfigError as exc:
                    msg = str(exc)
                    if "cannot be read" in msg or "refused" in msg:
                        raise
                    continue
                self.reconnects += 1
                self._lost.clear()
                self._issues.append(f"connection to {self.url} lost and re-established "
                                    f"({self.reconnects})")
                with self._lock:
                    self._resumed = True
                break
        self._flush(final=True)
        with contextlib.suppress(Exception):
            await client.disconnect()

    def stop(self) -> None:
        """Stop recording (returns when the client has disconnected)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(self.options.timeout_s + 5)

    # ------------------------------------------------------------------ result
    def rows(self) -> list[tuple[int, int, dict[str, Any]]]:
        """The finished rows so far: (cycle, time ns, values)."""
        with self._lock:
            return list(self._rows)

    def recording(self) -> Recording:
        """The recording so far (HF: numeric signals per row; LF: the text values)."""
        if self._error is not None and not isinstance(self._error, asyncio.CancelledError):
            raise self._error
        rows = self.rows()
        cycles = np.array([r[0] for r in rows], dtype=np.int64)
        times = pd.to_datetime(np.array([r[1] for r in rows], dtype=np.int64), utc=True)
        hf = pd.DataFrame({"time": times}, index=pd.Index(cycles, name="cycle"))
        for col in self.nodes.signals:
            hf[col] = [_num(r[2].get(col)) for r in rows]
        lf_rows = []
        for name in self.nodes.text:
            prev = object()
            for c, t, vals in rows:
                v = vals.get(name)
                if v is not None and v != prev:
                    lf_rows.append({"cycle": c, "time": pd.Timestamp(t, tz="UTC"),
                                    "signal": name, "value": _num(v), "text": str(v)})
                    prev = v
        lf = pd.DataFrame(lf_rows, columns=["cycle", "time", "signal", "value", "text"])
        meta = RecordingMeta(
            machine=self.machine, cycle_time_s=self.interval_s,
            units={c: self.nodes.units.get(c, "") for c in self.nodes.signals},
            source_files=[self.url], source_format="opcua",
            time_anchors=[(int(cycles[0]), pd.Timestamp(int(rows[0][1]), tz="UTC"))]
            if rows else [],
            gaps=list(self._gaps), issues=list(self._issues), partial=bool(self._gaps),
            attrs={"opcua": {"url": self.url, "publishing_interval_s": self.interval_s,
                             "rate_note": "one row per source timestamp the server delivered; "
                                          "not the 2 ms position-control cycle",
                             "reconnects": self.reconnects}})
        return Recording(hf=hf, lf=lf if len(lf) else None, meta=meta)


def _num(v: Any) -> float:
    if v is None:
        return math.nan
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def record_opcua(
    url: str, nodes: NodeMap, *, duration_s: float, options: OpcUaClientOptions | None = None,
    interval_s: float = 0.1, machine: str = "",
    progress: Callable[[float], None] | None = None,
) -> Recording:
    """Record for ``duration_s`` seconds (:class:`OpcUaRecorder`) and return the recording.

    Parameters
    ----------
    url : str
        Server endpoint (``opc.tcp://host:port``).
    nodes : NodeMap
        Which node is which signal.
    duration_s : float
        Recording time [s].
    options : OpcUaClientOptions, optional
        Security, user and certificates; default anonymous without security.
    interval_s : float, default 0.1
        Sampling interval asked of the server [s].
    machine : str, default ''
        Machine name of the recording.
    progress : callable, optional
        Called with the fraction recorded.

    Returns
    -------
    Recording
    """
    rec = OpcUaRecorder(url, nodes, options=options, interval_s=interval_s,
                        machine=machine).start()
    t0 = time.monotonic()
    try:
        while (left := duration_s - (time.monotonic() - t0)) > 0:
            time.sleep(min(0.2, left))
            if progress is not None:
                progress(min(1.0, (time.monotonic() - t0) / duration_s))
    finally:
        rec.stop()
    return rec.recording()

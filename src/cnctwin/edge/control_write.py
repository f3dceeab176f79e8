"""Write the adaptive feed's override to the control over OPC UA (issue 26, point 2).

``cnctwin edge run --source opc.tcp://... --nodes NODES.toml --adaptive ADAPTIVE.toml``: when
the node file has a ``[write]`` table (:data:`cnctwin.iotools.opcua_client.WRITE_KEYS`), every
``override`` result is written to the control: the override [%] and the heartbeat counter
(+1 per value; the PLC falls back to 100 % when it stops), and the source time of the newest
sample it was computed from (``data_time``, if named); an ``AdaptiveFeed`` alarm writes the
stop (breakage) or feed-hold (overload) request. The newest value wins: a value not yet
written when a newer one comes is replaced (the control needs the latest, not a backlog).

What the edge never does (checked before anything is written, :meth:`ControlWriter.start`):
write without a secured session (Basic256Sha256 Sign or SignAndEncrypt with a user), write a
node the server does not let this user write, or write an override outside the configured
bounds (the controller clamps; the value is clamped again here).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import threading
import time
from typing import Any

import pandas as pd

from cnctwin.edge.pipeline import Chunk
from cnctwin.exceptions import ConfigError

__all__ = ["ControlWriter"]


class ControlWriter:
    """A sink that writes ``override`` results and stop requests to the control.

    Parameters
    ----------
    url : str
        The control's OPC UA server.
    write_nodes : dict
        ``[write]`` key -> node id (``override_pct`` and ``heartbeat`` required).
    options : OpcUaClientOptions
        The session: security other than None and a user are required.
    min_pct, max_pct : float
        The adaptive configuration's bounds [%] (a value outside is clamped, never written).

    Attributes
    ----------
    written : int
        Override values written.
    errors : list of str
        Write failures (the loop goes on; the PLC's watchdog covers a silent edge).
    """

    name = "control"
    needs: tuple[str, ...] = ()  # results only

    def __init__(self, url: str, write_nodes: dict[str, str], *, options: Any,
                 min_pct: float, max_pct: float) -> None:
        missing = [k for k in ("override_pct", "heartbeat") if k not in write_nodes]
        if missing:
            raise ConfigError(f"the node file's [write] table needs {' and '.join(missing)} "
                              "(the override and its heartbeat): nothing is written without "
                              "them")
        if getattr(options, "security", "None") in ("None", "", None) or not getattr(
                options, "user", None):
            raise ConfigError("--adaptive writes the override to the control only over a "
                              "secured session: give --security Basic256Sha256_SignAndEncrypt "
                              "(or _Sign) with --client-cert/--client-key and --user")
        self.url, self.nodes, self.options = url, dict(write_nodes), options
        self.min_pct, self.max_pct = float(min_pct), float(max_pct)
        self.written = 0
        self.errors: list[str] = []
        self._latest: dict[str, Any] | None = None
        self._requests: list[str] = []
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self._types: dict[str, Any] = {}

    # ------------------------------------------------------------------ session
    def start(self) -> ControlWriter:
        """Connect, check every write node exists and this user may write it (raises a
        :class:`ConfigError` naming the node otherwise; nothing is written then)."""
        self._thread = threading.Thread(target=lambda: asyncio.run(self._main()),
                                        name="control-writer", daemon=True)
        self._thread.start()
        self._ready.wait(self.options.timeout_s * 3 + 5)
        if self._error is not None:
            raise self._error
        if not self._ready.is_set():
            raise ConfigError(f"the control's OPC UA server {self.url} did not answer")
        return self

    async def _check(self, client: Any) -> dict[str, Any]:
        from asyncua import ua

        out = {}
        for key, text in self.nodes.items():
            try:
                node = client.get_node(ua.NodeId.from_string(text))
                level = await node.read_attribute(ua.AttributeIds.UserAccessLevel)
                vt = await node.read_data_type_as_variant_type()
            except ua.UaStatusCodeError as exc:
                raise ConfigError(f"[write] {key} = {text}: no such node on {self.url} "
                                  f"({exc}); check the node file") from None
            except Exception as exc:
                raise ConfigError(f"[write] {key} = {text}: {exc}") from None
            bits = int(level.Value.Value or 0)
            if not bits & ua.AccessLevel.CurrentWrite.mask:
                raise ConfigError(f"[write] {key} = {text} is not writable for user "
                                  f"{self.options.user!r} on {self.url}: nothing was written "
                                  "(the PLC data block must be writable over OPC UA)")
            out[key] = node
            self._types[key] = vt
        return out

    async def _main(self) -> None:
        import logging

        from cnctwin.iotools.opcua_client import _connect

        for name in ("asyncua", "asyncua.client"):
            logging.getLogger(name).setLevel(logging.CRITICAL)
        try:
            client = await _connect(self.url, self.options)
            try:
                nodes = await self._check(client)
            except BaseException:
                await client.disconnect()
                raise
        except BaseException as exc:
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        try:
            while not self._stop.is_set():
                await asyncio.get_running_loop().run_in_executor(None, self._wake.wait, 0.2)
                self._wake.clear()
                latest, self._latest = self._latest, None
                reqs, self._requests = self._requests, []
                for key in reqs:
                    if key in nodes:
                        await self._write(nodes[key], key, True)
                if latest is not None:
                    await self._write(nodes["override_pct"], "override_pct",
                                      latest["override_pct"])
                    if "data_time" in nodes and latest.get("data_time") is not None:
                        await self._write(nodes["data_time"], "data_time",
                                          latest["data_time"])
                    await self._write(nodes["heartbeat"], "heartbeat", latest["heartbeat"])
                    self.written += 1
        finally:
            with contextlib.suppress(Exception):
                await client.disconnect()

    async def _write(self, node: Any, key: str, value: Any) -> None:
        from asyncua import ua

        vt = self._types.get(key, ua.VariantType.Double)
        if vt in (ua.VariantType.Byte, ua.VariantType.SByte, ua.VariantType.Int16,
                  ua.VariantType.UInt16, ua.VariantType.Int32, ua.VariantType.UInt32):
            value = round(value) % (65536 if vt == ua.VariantType.UInt16 else 1 << 31)
        elif vt == ua.VariantType.Boolean:
            value = bool(value)
        elif vt == ua.VariantType.DateTime:
            value = pd.Timestamp(int(value), tz="UTC").to_pydatetime().replace(tzinfo=None)
        else:
            value = float(value)
        try:
            await node.write_value(ua.DataValue(ua.Variant(value, vt)))
        except Exception as exc:  # the PLC's watchdog covers what does not arrive
            if len(self.errors) < 100:
                self.errors.append(f"{time.strftime('%H:%M:%S')} {key}: {exc}")

    # ------------------------------------------------------------------ sink
    def write(self, messages: list[dict[str, Any]], chunk: Chunk | None) -> None:
        """Queue the newest override and any stop/feed-hold request."""
        for m in messages:
            kind = m.get("kind")
            if kind == "override":
                o = m.get("override_pct")
                if o is None or not math.isfinite(float(o)):
                    continue
                o = min(max(float(o), self.min_pct), self.max_pct)
                t = None
                if chunk is not None and chunk.time_ns.size:
                    t = int(chunk.time_ns[-1])
                self._latest = {"override_pct": o, "heartbeat": int(m.get("heartbeat", 0)),
                                "data_time": t}
                self._wake.set()
            elif kind == "alarm" and m.get("detector") == "AdaptiveFeed":
                key = "stop" if m.get("fault") == "breakage" else "feed_hold"
                self._requests.append(key)
                self._wake.set()

    def status(self) -> dict[str, Any]:
        """Values written and write errors."""
        return {"url": self.url, "written": self.written, "errors": len(self.errors)}

    def close(self) -> None:
        """Write what is queued, then disconnect (no 100 % is written: the PLC's watchdog
        falls back when the heartbeat stops)."""
        self._wake.set()
        time.sleep(0.05)
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(10)

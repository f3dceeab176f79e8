"""MTConnect agent (HTTP) and SHDR adapter (TCP) of the edge runtime, and the sink that feeds
them (``cnctwin edge run --mtconnect http://HOST:PORT --shdr tcp://HOST:PORT``).

* :class:`MTConnectAgent`: ``GET /probe``, ``/current``, ``/sample?from=&count=`` (also under
  ``/<device name>/``), ``/assets`` and ``/asset/ID`` (the tools' ``CuttingTool`` assets),
  MTConnect 2.3 XML from :mod:`cnctwin.edge.mtconnect`; errors as MTConnectError documents
  (``OUT_OF_RANGE``, ``INVALID_REQUEST``, ``UNSUPPORTED``, ``ASSET_NOT_FOUND``). A
  non-loopback address needs an access token (``Authorization: Bearer``) and may use TLS;
  without a token it serves only with ``insecure=True``.
* :class:`ShdrAdapter`: the line protocol the reference agent (cppagent) reads from an
  adapter: ``timestamp|key|value|key|value`` per line, conditions as
  ``timestamp|key|level|native_code|native_severity|qualifier|message``; a new connection
  gets every current value first; ``* PING`` is answered ``* PONG <ms>``. SHDR has no
  authentication: a non-loopback address needs ``insecure=True``.
* :class:`MTConnectSink`: the runtime's results and the drive signals (decimated to
  ``sample_hz``) into the buffer and out to the adapter's clients.
"""

from __future__ import annotations

import collections
import contextlib
import hmac
import json
import math
import socket
import socketserver
import ssl
import threading
import time
import urllib.parse
from collections.abc import Mapping
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import numpy as np

from cnctwin.edge.listen import is_loopback
from cnctwin.edge.mtconnect import (
    AssetStore,
    DeviceModel,
    ObservationBuffer,
    OutOfRangeError,
    assets_document,
    cutting_tool,
    error_document,
    iso_timestamp,
    item_key,
    machine_tool_device,
    path_items,
    probe_document,
    streams_document,
)
from cnctwin.edge.pipeline import Chunk
from cnctwin.exceptions import ConfigError
from cnctwin.recording import nc_program_name

__all__ = ["MTConnectAgent", "MTConnectSink", "ShdrAdapter", "parse_listen_url"]


def parse_listen_url(url: str, *, scheme: str, option: str) -> tuple[str, int]:
    """``scheme://HOST:PORT`` -> (host, port); a clear error naming the option otherwise.

    Parameters
    ----------
    url : str
        ``SCHEME://HOST:PORT``.
    scheme : str
        The scheme expected (``http``).
    option : str
        Command-line option named in errors.

    Returns
    -------
    tuple
        (host, port).
    """
    u = urllib.parse.urlsplit(url)
    try:
        port = u.port
    except ValueError:
        port = None
    if u.scheme != scheme or not u.hostname or not port:
        raise ConfigError(f"{option} {url!r}: expected {scheme}://HOST:PORT, e.g. "
                          f"{scheme}://127.0.0.1:{7878 if scheme == 'tcp' else 5000}")
    return u.hostname, port


# ---------------------------------------------------------------------------- agent
class MTConnectAgent:
    """An MTConnect agent over HTTP for one device (read-only).

    Parameters
    ----------
    model : DeviceModel
        The device.
    buffer : ObservationBuffer
        Its observations.
    host, port : str, int
        Address to listen on (port 0: any free port, see :attr:`port`).
    token : str, optional
        Access token: every request then needs ``Authorization: Bearer TOKEN``.
    tls_cert, tls_key : str, optional
        PEM certificate and key: serve HTTPS.
    insecure : bool, default False
        Serve a non-loopback address without a token.
    assets : AssetStore, optional
        The assets served by ``/assets`` and ``/asset/ID`` (default: none yet).

    Raises
    ------
    ConfigError
        A non-loopback address without a token or ``insecure``; the port in use.
    """

    def __init__(self, model: DeviceModel, buffer: ObservationBuffer, *, host: str = "127.0.0.1",
                 port: int = 5000, token: str | None = None, tls_cert: str | None = None,
                 tls_key: str | None = None, insecure: bool = False,
                 assets: AssetStore | None = None) -> None:
        if token is None and not insecure and not is_loopback(host):
            raise ConfigError(f"the MTConnect agent on {host} faces the network: give an "
                              "access token (--mtconnect-token-file) or --mtconnect-insecure")
        self.model, self.buffer, self.token = model, buffer, token
        self.assets = assets if assets is not None else AssetStore()
        agent = self

        class Handler(BaseHTTPRequestHandler):
            server_version = "cnctwin-mtconnect"
            timeout = 10.0  # a client that stops reading or writing holds one thread, briefly

            def log_message(self, *args: Any) -> None:  # quiet
                pass

            def do_GET(self) -> None:
                auth = self.headers.get("Authorization")
                stream = agent.stream_request(self.path, auth)
                if stream is not None:
                    agent.stream(self, *stream)
                    return
                status, body = agent.respond(self.path, auth)
                self.send_response(status)
                self.send_header("Content-Type", "application/xml; charset=utf-8")
                self.send_header("Content-Length", str(len(body)))
                if status == 401:
                    self.send_header("WWW-Authenticate", "Bearer")
                self.end_headers()
                self.wfile.write(body)

        class Server(ThreadingHTTPServer):
            request_queue_size = 128  # a plant's clients connecting at once (default 5)

            def handle_error(self, request: Any, client_address: Any) -> None:
                agent.client_errors += 1  # a client that vanished: counted, no traceback

        self.client_errors = 0
        self._closing = False
        self._cache: dict[Any, tuple[int, bytes]] = {}
        self._cache_lock = threading.Lock()
        try:
            self._server = Server((host, port), Handler)
        except OSError as exc:
            reason = exc.strerror or exc
            raise ConfigError(f"cannot listen on {host}:{port} for MTConnect ({reason}); "
                              "choose another port in --mtconnect") from None
        self._server.daemon_threads = True
        scheme = "http"
        if tls_cert:
            ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
            ctx.load_cert_chain(tls_cert, tls_key)
            self._server.socket = ctx.wrap_socket(self._server.socket, server_side=True)
            scheme = "https"
        self.host = host
        self.port = int(self._server.server_address[1])
        self.url = f"{scheme}://{host}:{self.port}"
        self._thread = threading.Thread(target=self._server.serve_forever, name="mtconnect",
                                        daemon=True)
        self._thread.start()

    def _parse(self, path: str, authorization: str | None
               ) -> tuple[str, dict[str, list[str]]] | tuple[int, bytes]:
        """The request and its query, or an error response."""
        b = self.buffer
        if self.token is not None:
            given = (authorization or "").removeprefix("Bearer ").strip()
            if not hmac.compare_digest(given.encode(), self.token.encode()):
                return 401, error_document("UNAUTHORIZED", "a valid Bearer token is required",
                                           buffer=b)
        u = urllib.parse.urlsplit(path)
        parts = [urllib.parse.unquote(p) for p in u.path.split("/") if p]
        names = (self.model.name, self.model.id, self.model.uuid)
        requests = ("probe", "current", "sample", "assets", "asset")
        if parts and parts[0] in ("asset", "assets") and len(parts) <= 2:
            q = urllib.parse.parse_qs(u.query)
            if len(parts) == 2:
                q["asset_ids"] = parts[1].split(";")
            return parts[0], q
        if parts and parts[0] in names:
            parts = parts[1:]
        elif len(parts) == 2 or (len(parts) == 1 and parts[0] not in requests):
            return 404, error_document("NO_DEVICE", f"no device {parts[0]!r}; this agent "
                                       f"serves {self.model.name!r}", buffer=b)
        req = parts[0] if parts else "probe"
        if len(parts) > 1 or req not in requests or req == "asset":
            return 404, error_document("INVALID_REQUEST", f"unknown request {u.path!r}; use "
                                       "/probe, /current, /sample?from=&count=, /assets or "
                                       "/asset/ID", buffer=b)
        return req, urllib.parse.parse_qs(u.query)

    def _items(self, q: dict[str, list[str]]) -> set[str] | tuple[int, bytes] | None:
        if "path" not in q:
            return None
        try:
            return path_items(self.model, self.buffer, q["path"][0])
        except ConfigError as exc:
            return 400, error_document("INVALID_PATH", str(exc), buffer=self.buffer)

    def respond(self, path: str, authorization: str | None = None) -> tuple[int, bytes]:
        """Status and body for a request path (the HTTP handler's logic, testable alone).

        ``/probe``, ``/current`` and ``/sample`` (also ``/DEVICE/...``; another device name:
        ``NO_DEVICE``); ``path=`` (XPath over the device model: only the items it selects;
        ``INVALID_PATH``), ``from=``, ``count=`` (negative: the last ``-count``), ``to=``.
        ``interval=`` streams (:meth:`stream`).
        """
        b = self.buffer
        parsed = self._parse(path, authorization)
        if isinstance(parsed[0], int):
            return parsed
        req, q = parsed
        assert isinstance(req, str) and isinstance(q, dict)
        # many clients ask the same while nothing new arrived: one document per (request,
        # query, buffer state), the newest 256 kept
        key = (req, tuple(sorted((k, tuple(v)) for k, v in q.items())), b.next_sequence,
               b.first_sequence, self.assets.changes)
        with self._cache_lock:
            hit = self._cache.get(key)
        if hit is not None:
            return hit
        out = self._respond(b, req, q)
        if out[0] == 200:
            with self._cache_lock:
                self._cache[key] = out
                while len(self._cache) > 256:
                    self._cache.pop(next(iter(self._cache)))
        return out

    def _respond(self, b: ObservationBuffer, req: str, q: dict[str, list[str]]
                 ) -> tuple[int, bytes]:
        if req == "probe":
            return 200, probe_document(self.model, b, asset_count=len(self.assets),
                                       asset_buffer_size=self.assets.size)
        if req in ("assets", "asset"):
            return self._assets(b, q)
        items = self._items(q)
        if isinstance(items, tuple):
            return items
        if req == "current":
            if "at" in q:
                return 400, error_document("UNSUPPORTED", "current?at= is not supported",
                                           buffer=b)
            obs, first, nxt = b.current()
            if items is not None:
                obs = [o for o in obs if o.item_id in items]
            return 200, streams_document(self.model, obs, buffer=b, first_sequence=first,
                                         next_sequence=nxt, last_sequence=nxt - 1)
        try:
            start = int(q["from"][0]) if "from" in q else None
            count = int(q["count"][0]) if "count" in q else 100
            to = int(q["to"][0]) if "to" in q else None
        except ValueError:
            return 400, error_document("INVALID_REQUEST", "from, count and to must be integers",
                                       buffer=b)
        try:
            obs, first, nxt, last = b.sample(start, count, to=to, items=items)
        except OutOfRangeError as exc:
            return 400, error_document("OUT_OF_RANGE", str(exc), buffer=b)
        return 200, streams_document(self.model, obs, buffer=b, first_sequence=first,
                                     next_sequence=nxt, last_sequence=last)

    def _assets(self, b: ObservationBuffer, q: dict[str, list[str]]) -> tuple[int, bytes]:
        """``/assets`` (``type=``, ``count=``; no asset is ever removed, so ``removed=``
        changes nothing) and ``/asset/ID;ID``."""
        store = self.assets
        if "asset_ids" in q:
            found = [store.get(i) for i in q["asset_ids"]]
            missing = [i for i, a in zip(q["asset_ids"], found, strict=True) if a is None]
            if missing:
                return 404, error_document("ASSET_NOT_FOUND", f"no asset {missing[0]!r}; "
                                           "/assets lists those held", buffer=b)
            chosen = [a for a in found if a is not None]
        else:
            try:
                count = int(q["count"][0]) if "count" in q else None
            except ValueError:
                return 400, error_document("INVALID_REQUEST", "count must be an integer",
                                           buffer=b)
            if count is not None and count < 1:
                return 400, error_document("INVALID_REQUEST", "count must be at least 1",
                                           buffer=b)
            kind = q.get("type", ["CuttingTool"])[0]
            chosen = store.all(count=count) if kind == "CuttingTool" else []
        return 200, assets_document(self.model, chosen, buffer=b, asset_count=len(store),
                                    asset_buffer_size=store.size)

    def stream_request(self, path: str, authorization: str | None
                       ) -> tuple[str, dict[str, list[str]]] | None:
        """``(request, query)`` when ``path`` asks for a stream (``interval=``), else None."""
        u = urllib.parse.urlsplit(path)
        if "interval" not in urllib.parse.parse_qs(u.query):
            return None
        parsed = self._parse(path, authorization)
        if isinstance(parsed[0], int) or parsed[0] in ("probe", "assets", "asset"):
            return None  # the error (or the probe, the assets) is answered as a document
        return parsed

    def stream(self, handler: Any, req: str, q: dict[str, list[str]]) -> None:
        """``interval=MS`` (and ``heartbeat=MS``, default 10 000): a ``multipart/x-mixed-
        replace`` stream, one document per interval with what is new since the last (sample:
        every observation once, in order; current: the latest values), an empty document
        after ``heartbeat`` without news; until the client leaves or the agent closes."""
        b = self.buffer
        try:
            interval = int(q["interval"][0]) / 1000.0
            heartbeat = int(q.get("heartbeat", ["10000"])[0]) / 1000.0
            count = int(q.get("count", ["100"])[0])
            start = int(q["from"][0]) if "from" in q else None
        except ValueError:
            self._send(handler, 400, error_document(
                "INVALID_REQUEST", "interval, heartbeat, from and count must be integers",
                buffer=b))
            return
        items = self._items(q)
        if isinstance(items, tuple):
            self._send(handler, *items)
            return
        if not (0.0 <= interval <= 3600.0 and 0.01 <= heartbeat <= 3600.0) or count < 1:
            self._send(handler, 400, error_document(
                "INVALID_REQUEST", "interval 0 ... 3 600 000 ms, heartbeat 10 ... 3 600 000 "
                "ms, count >= 1", buffer=b))
            return
        boundary = "cnctwin" + format(id(handler), "x")
        handler.send_response(200)
        handler.send_header("Content-Type", f"multipart/x-mixed-replace;boundary={boundary}")
        handler.send_header("Connection", "close")
        handler.end_headers()
        nxt = b.next_sequence if start is None else start
        last_sent = 0.0
        try:
            while not self._closing:
                if req == "current":
                    obs, first, n2 = b.current()
                    if items is not None:
                        obs = [o for o in obs if o.item_id in items]
                    body = streams_document(self.model, obs, buffer=b, first_sequence=first,
                                            next_sequence=n2, last_sequence=n2 - 1)
                    news = True
                else:
                    try:
                        obs, first, n2, last = b.sample(nxt, count, items=items)
                    except OutOfRangeError as exc:  # fell out of the buffer: say so, end
                        body = error_document("OUT_OF_RANGE", str(exc), buffer=b)
                        self._part(handler, boundary, body)
                        return
                    news = bool(obs)
                    body = streams_document(self.model, obs, buffer=b, first_sequence=first,
                                            next_sequence=n2, last_sequence=last)
                    nxt = n2
                now = time.monotonic()
                if news or now - last_sent >= heartbeat:
                    self._part(handler, boundary, body)
                    last_sent = now
                if not news or req == "current":
                    time.sleep(max(interval, 0.01))
        except OSError:
            return  # the client left

    @staticmethod
    def _part(handler: Any, boundary: str, body: bytes) -> None:
        head = (f"--{boundary}\r\nContent-type: text/xml\r\nContent-length: {len(body)}"
                "\r\n\r\n").encode()
        handler.wfile.write(head + body + b"\r\n")
        handler.wfile.flush()

    @staticmethod
    def _send(handler: Any, status: int, body: bytes) -> None:
        handler.send_response(status)
        handler.send_header("Content-Type", "application/xml; charset=utf-8")
        handler.send_header("Content-Length", str(len(body)))
        handler.end_headers()
        handler.wfile.write(body)

    def close(self) -> None:
        """Stop serving (open streams end)."""
        self._closing = True
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(5)


# ---------------------------------------------------------------------------- SHDR
def _shdr_value(v: Any) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "UNAVAILABLE"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v).replace("|", "/").replace("\n", " ")


class _ShdrClient:
    """One connected agent: a bounded queue of bytes its own thread sends (the pipeline never
    waits on this socket)."""

    def __init__(self, sock: socket.socket, limit_bytes: int) -> None:
        self.sock = sock
        self.limit_bytes = limit_bytes
        self.queue: collections.deque[bytes] = collections.deque()
        self.queued = 0
        self.cond = threading.Condition()
        self.closed = False

    def put(self, data: bytes) -> bool:
        """Queue ``data``; False when the client is too far behind (it is then dropped)."""
        with self.cond:
            if self.closed:
                return False
            if self.queued + len(data) > self.limit_bytes:
                return False
            self.queue.append(data)
            self.queued += len(data)
            self.cond.notify()
        return True

    def close(self) -> None:
        with self.cond:
            self.closed = True
            self.cond.notify_all()
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            self.sock.close()


class ShdrAdapter:
    """An SHDR adapter: a TCP server that agents (cppagent) connect to.

    Every agent has its own bounded queue and sending thread (with a send timeout): a slow or
    stalled agent is dropped and counted (:attr:`dropped_clients`), it never blocks
    :meth:`send`, so the runtime's pipeline never waits on a socket.

    Parameters
    ----------
    model : DeviceModel
        The device (its data item ids are the SHDR keys).
    host, port : str, int
        Address to listen on (port 0: any free port).
    insecure : bool, default False
        Listen on a non-loopback address (SHDR has no authentication).
    queue_bytes : int, default 4_000_000
        Data an agent may be behind before it is dropped [bytes] (about 10 s of the
        500 Hz sampler's lines).
    send_timeout_s : float, default 5
        A send that does not progress for this long drops the agent [s].
    backlog : int, default 128
        Listen backlog (a plant's agents connecting at once).
    """

    def __init__(self, model: DeviceModel, *, host: str = "127.0.0.1", port: int = 7878,
                 insecure: bool = False, queue_bytes: int = 4_000_000,
                 send_timeout_s: float = 5.0, backlog: int = 128) -> None:
        if not insecure and not is_loopback(host):
            raise ConfigError(f"the SHDR adapter on {host} would face the network without "
                              "authentication (SHDR has none): listen on 127.0.0.1 and let "
                              "the agent connect locally, or give --shdr-insecure")
        self.model = model
        self.queue_bytes, self.send_timeout_s = int(queue_bytes), float(send_timeout_s)
        self.coalesce_s = 0.01
        self._clients: list[_ShdrClient] = []
        self._lock = threading.Lock()
        self._current: dict[str, str] = {}
        self.dropped_clients = 0
        adapter = self

        class Handler(socketserver.BaseRequestHandler):
            def handle(self) -> None:
                sock: socket.socket = self.request
                sock.settimeout(adapter.send_timeout_s)
                client = _ShdrClient(sock, adapter.queue_bytes)
                with adapter._lock:
                    snapshot = "".join(f"{line}\n" for line in adapter._current.values())
                    if snapshot:
                        client.put(snapshot.encode())
                    adapter._clients.append(client)
                reader = threading.Thread(target=adapter._read, args=(client,),
                                          name="shdr-read", daemon=True)
                reader.start()
                try:
                    adapter._write(client)
                finally:
                    adapter._remove(client, dropped=False)

        class Server(socketserver.ThreadingTCPServer):
            allow_reuse_address = True
            daemon_threads = True
            request_queue_size = backlog

            def handle_error(self, request: Any, client_address: Any) -> None:
                pass  # a client that vanished is not an error of the runtime

        try:
            self._server = Server((host, port), Handler)
        except OSError as exc:
            reason = exc.strerror or exc
            raise ConfigError(f"cannot listen on {host}:{port} for SHDR ({reason}); choose "
                              "another port in --shdr") from None
        self.host, self.port = host, int(self._server.server_address[1])
        self._thread = threading.Thread(target=self._server.serve_forever, name="shdr",
                                        daemon=True)
        self._thread.start()

    def _write(self, client: _ShdrClient) -> None:
        """The client's thread: send what is queued (a send timeout drops it), at most every
        ``coalesce_s`` (one send per few chunks, not one wake-up per line)."""
        while True:
            with client.cond:
                while not client.queue and not client.closed:
                    client.cond.wait(1.0)
                if client.closed:
                    return
            time.sleep(self.coalesce_s)
            with client.cond:
                parts = list(client.queue)
                client.queue.clear()
                client.queued = 0
            try:
                client.sock.sendall(b"".join(parts))
            except OSError:  # timed out (a stalled agent) or gone
                self._remove(client, dropped=True)
                return

    def _read(self, client: _ShdrClient) -> None:
        """Answer the agent's heartbeats (``* PING`` -> ``* PONG 10000``) until it leaves."""
        buf = b""
        while not client.closed:
            try:
                data = client.sock.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                break
            if not data:
                break
            buf += data
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                if line.strip().startswith(b"* PING"):
                    client.put(b"* PONG 10000\n")
        client.close()

    def _remove(self, client: _ShdrClient, *, dropped: bool) -> None:
        with self._lock:
            if client in self._clients:
                self._clients.remove(client)
                if dropped:
                    self.dropped_clients += 1
        client.close()

    @property
    def n_clients(self) -> int:
        """Connected agents."""
        with self._lock:
            return len(self._clients)

    def send(self, timestamp: str, items: list[tuple[str, Any]]) -> None:
        """Queue one time's values (``[(key, value), ...]``) for every connected agent (never
        waits on a socket: an agent too far behind is dropped and counted)."""
        if not items:
            return
        samples = [(k, v) for k, v in items if not isinstance(v, tuple)]
        lines = []
        if samples:
            lines.append(timestamp + "".join(f"|{k}|{_shdr_value(v)}" for k, v in samples))
        for k, v in items:
            if isinstance(v, tuple):  # condition: (level, native_code, message)
                level, code, text = v
                lines.append(f"{timestamp}|{k}|{level}|{code or ''}|||{_shdr_value(text or '')}")
        data = "".join(f"{line}\n" for line in lines).encode()
        slow = []
        with self._lock:
            for k, v in items:
                self._current[k] = (f"{timestamp}|{k}|{_shdr_value(v)}"
                                    if not isinstance(v, tuple) else lines[-1])
            for c in self._clients:
                if not c.put(data):
                    slow.append(c)
        for c in slow:
            self._remove(c, dropped=True)

    def close(self) -> None:
        """Stop serving and drop the clients."""
        self._server.shutdown()
        self._server.server_close()
        with self._lock:
            clients, self._clients = list(self._clients), []
        for c in clients:
            c.close()
        self._thread.join(5)


# ---------------------------------------------------------------------------- sink
class MTConnectSink:
    """Runtime sink: drive signals and cnctwin results into an MTConnect buffer, served by an
    agent and/or sent to an SHDR adapter's agents.

    Parameters
    ----------
    machine : str
        Machine name (the device).
    agent : tuple of (host, port), optional
        Serve the agent here.
    shdr : tuple of (host, port), optional
        Serve the SHDR adapter here.
    buffer_size : int, default 131072
        The agent's circular buffer (``--mtconnect-buffer``).
    sample_hz : float, default 10
        Rate of the drive-signal samples (a value every ``1/sample_hz`` s of the recording's
        clock: the last cycle of each window) [Hz].
    axes : sequence of str
        Linear axes of the device model.
    token, tls_cert, tls_key, insecure, shdr_insecure
        Security of the agent and the adapter (:class:`MTConnectAgent`, :class:`ShdrAdapter`).
    tools : mapping, optional
        T number -> the tool table's entry: one ``CuttingTool`` asset per tool, updated from
        the ``tool_life`` results (an ``AssetChanged`` observation each time) and marked
        ``BROKEN`` by a breakage alarm of the tool.
    alarm_hold_s : float, default 1.0
        An alarm's condition (``Fault``) returns to ``Normal`` this long after the last
        alarm on the recording's clock [s] (as the OPC UA alarm's hold).
    """

    name = "mtconnect"
    needs = None  # the axes' samples: every column

    def __init__(self, machine: str, *, agent: tuple[str, int] | None = None,
                 shdr: tuple[str, int] | None = None, buffer_size: int = 131_072,
                 sample_hz: float = 10.0, axes: tuple[str, ...] = ("X1", "Y1", "Z1"),
                 spindle: str = "SP1", token: str | None = None, tls_cert: str | None = None,
                 tls_key: str | None = None, insecure: bool = False,
                 shdr_insecure: bool = False,
                 tools: Mapping[int, Mapping[str, Any]] | None = None,
                 alarm_hold_s: float = 1.0) -> None:
        if not (math.isfinite(sample_hz) and 0.01 <= sample_hz <= 500):
            raise ConfigError(f"the MTConnect sample rate must be 0.01 ... 500 Hz, not "
                              f"{sample_hz!r}")
        self.model = machine_tool_device(machine, axes=axes, spindle=spindle)
        self.buffer = ObservationBuffer(buffer_size)
        self.axes, self.spindle, self.sample_hz = axes, spindle, sample_hz
        self._sp = item_key(spindle)
        self.tools = {int(k): dict(v) for k, v in (tools or {}).items()}
        self.assets = AssetStore()
        now = time.time_ns()
        for n, spec in sorted(self.tools.items()):
            self.assets.put(cutting_tool(self.model.id, n, spec, timestamp_ns=now))
        self.alarm_hold_s = alarm_hold_s
        self._cond_until: int | None = None  # the alarm condition clears after this cycle
        self._life: dict[int, dict[str, Any]] = {}
        self._broken: set[int] = set()
        self._tool: int | None = None  # the tool of the last hole
        self.agent = (MTConnectAgent(self.model, self.buffer, host=agent[0], port=agent[1],
                                     token=token, tls_cert=tls_cert, tls_key=tls_key,
                                     insecure=insecure, assets=self.assets) if agent else None)
        try:
            self.adapter = (ShdrAdapter(self.model, host=shdr[0], port=shdr[1],
                                        insecure=shdr_insecure) if shdr else None)
        except ConfigError:
            if self.agent is not None:
                self.agent.close()
            raise
        self._next_sample_cycle: int | None = None
        self._last_event: dict[str, Any] = {}
        self._holes = 0
        self.observations = 0
        self._await: dict[int, int] = {}  # sampled cycle -> its time, torque not yet known
        # every data item starts UNAVAILABLE (as an MTConnect agent does): /current then
        # lists each one, with a value or UNAVAILABLE, never leaves one out
        first = {"avail": "AVAILABLE", "system": ("NORMAL", None, None),
                 f"{self._sp}_cond": ("NORMAL", None, None)}
        self._put(None, [(d.id, first.get(d.id, ("UNAVAILABLE", None, None)
                                          if d.category == "CONDITION" else None))
                         for d in self.model.data_items])

    def _put(self, t_ns: int | None, items: list[tuple[str, Any]]) -> None:
        t = time.time_ns() if t_ns is None else int(t_ns)
        for key, v in items:
            if isinstance(v, tuple):
                self.buffer.add(key, t, v[0], native_code=v[1], message=v[2])
            else:
                self.buffer.add(key, t, v)
        self.observations += len(items)
        if self.adapter is not None:
            self.adapter.send(iso_timestamp(t), items)

    def _event(self, key: str, value: Any, out: list[tuple[str, Any]]) -> None:
        if self._last_event.get(key) != value:
            self._last_event[key] = value
            out.append((key, value))

    def write(self, messages: list[dict[str, Any]], chunk: Chunk | None) -> None:
        """Put a chunk's decimated signals and the messages into the buffer."""
        by_time: dict[int, list[tuple[str, Any]]] = {}
        torque: dict[int, tuple[float, float]] = {}
        for msg in messages:
            if msg["kind"] == "torque":
                c0 = int(msg["first_cycle"])
                tq = msg["torque_nm"]
                sp = msg["speed_rpm"]
                for i in range(int(msg["n"])):
                    torque[c0 + i] = (float(tq[i]) if tq[i] is not None else math.nan,
                                      float(sp[i]) if sp[i] is not None else math.nan)
        for c in [c for c in self._await if c in torque]:  # a sample held for its torque
            t = self._await.pop(c)
            by_time.setdefault(t, []).extend([(f"{self._sp}_cut_torque", torque[c][0]),
                                              (f"{self._sp}_speed", torque[c][1])])
        if len(self._await) > 4:  # a gap or the end: that torque never comes
            for c in sorted(self._await)[:-4]:
                del self._await[c]
        if chunk is not None and len(chunk):
            self._samples(chunk, torque, by_time)
            self._events(chunk, by_time)
        for msg in messages:
            t_ns = self._msg_time(msg, chunk)
            items = by_time.setdefault(t_ns, [])
            if msg["kind"] == "tool_life" and int(msg["tool"]) in self.tools:
                n = int(msg["tool"])
                self._life[n] = msg
                items.append(("asset_chg", self._asset(n, t_ns)))
            elif msg["kind"] == "alarm" and "break" in str(msg.get("fault", "")):
                # the alarm's tool (adaptive feed), else the tool of the hole it judged
                tool = msg.get("tool") if msg.get("tool") is not None else self._tool
                n = -1 if tool is None else int(tool)
                if n in self.tools and n not in self._broken:
                    self._broken.add(n)
                    items.append(("asset_chg", self._asset(n, t_ns)))
            if msg["kind"] == "hole":
                row = msg["row"]
                if row.get("tool") is not None:
                    self._tool = int(row["tool"])
                self._holes += 1
                items += [("holes", self._holes),
                          (f"{self._sp}_hole_torque", row.get("torque_mean_nm")),
                          ("hole_record", json.dumps(
                              {k: row.get(k) for k in ("hole", "depth_mm", "torque_mean_nm",
                                                       "torque_first_nm", "energy_j",
                                                       "x_mm", "y_mm", "tool")},
                              default=str))]
            elif msg["kind"] == "alarm":
                level = "WARNING" if msg.get("severity") == "warning" else "FAULT"
                if chunk is not None and len(chunk):
                    self._cond_until = int(msg["cycle"]) + round(self.alarm_hold_s
                                                                 / chunk.cycle_time_s)
                items.append((f"{self._sp}_cond", (level, str(msg.get("detector", "cnctwin")),
                                                   str(msg.get("message", "anomaly")))))
            elif msg["kind"] == "wear" and "wear" in msg:
                items.append(("wear", f"{float(msg['wear']):.4g}"))
            elif msg["kind"] in ("overload", "status") and msg.get("message"):
                items.append(("system", ("WARNING", msg["kind"], str(msg["message"]))))
        if (self._cond_until is not None and chunk is not None and len(chunk)
                and int(chunk.cycles[-1]) > self._cond_until):
            # the hold is over: Normal clears the alarm conditions (Part 2, Condition)
            t = self._msg_time({"cycle": self._cond_until}, chunk)
            by_time.setdefault(max(t, int(chunk.time_ns[0])), []).append(
                (f"{self._sp}_cond", ("NORMAL", None, None)))
            self._cond_until = None
        for t_ns in sorted(by_time):
            self._put(t_ns, by_time[t_ns])

    def _asset(self, n: int, t_ns: int) -> str:
        """Update tool ``n``'s asset from its latest tool life; its asset id."""
        asset = cutting_tool(self.model.id, n, self.tools[n], self._life.get(n),
                             timestamp_ns=t_ns, broken=n in self._broken)
        self.assets.put(asset)
        return asset.asset_id

    def _msg_time(self, msg: dict[str, Any], chunk: Chunk | None) -> int:
        if chunk is not None and len(chunk):
            return int(chunk.time_ns[0]) + round((int(msg["cycle"]) - chunk.first_cycle)
                                                 * chunk.cycle_time_s * 1e9)
        return time.time_ns()

    def _samples(self, chunk: Chunk, torque: dict[int, tuple[float, float]],
                 by_time: dict[int, list[tuple[str, Any]]]) -> None:
        step = max(1, round(1.0 / (self.sample_hz * chunk.cycle_time_s)))
        if self._next_sample_cycle is None:
            self._next_sample_cycle = chunk.first_cycle + step - 1
        idx = np.arange(self._next_sample_cycle - chunk.first_cycle, len(chunk), step)
        idx = idx[idx >= 0]
        if idx.size:
            self._next_sample_cycle = int(chunk.cycles[idx[-1]]) + step
        sig = chunk.signals
        sp = self._sp
        for i in idx:
            items: list[tuple[str, Any]] = []
            for ax in self.axes:
                k = item_key(ax)
                pos = sig.get(f"ENC_POS|{ax}", sig.get(f"CTRL_POS|{ax}"))
                if pos is not None:
                    items.append((f"{k}_pos", float(pos[i])))
                if f"LOAD|{ax}" in sig:
                    items.append((f"{k}_load", float(sig[f"LOAD|{ax}"][i])))
            if f"LOAD|{self.spindle}" in sig:
                items.append((f"{sp}_load", float(sig[f"LOAD|{self.spindle}"][i])))
            if f"POWER|{self.spindle}" in sig:
                items.append((f"{sp}_power", float(sig[f"POWER|{self.spindle}"][i])))
            c = int(chunk.cycles[i])
            if c in torque:
                items += [(f"{sp}_cut_torque", torque[c][0]), (f"{sp}_speed", torque[c][1])]
            else:  # the chunk's last cycle: its torque comes with the next chunk
                self._await[c] = int(chunk.time_ns[i])
            by_time.setdefault(int(chunk.time_ns[i]), []).extend(items)

    def _events(self, chunk: Chunk, by_time: dict[int, list[tuple[str, Any]]]) -> None:
        ev = chunk.events
        if ev is None or ev.empty:
            return
        for _, row in ev.iterrows():
            items: list[tuple[str, Any]] = []
            name = nc_program_name(row.get("path")) if row.get("kind") == "call" else None
            if name is not None:  # the main program, not a cycle or subprogram it calls
                self._event("program", name, items)
            tool = row.get("active_tool")
            if tool is not None and not (isinstance(tool, float) and math.isnan(tool)):
                with contextlib.suppress(TypeError, ValueError):
                    self._event("tool", int(tool), items)
            if items:
                i = int(np.clip(int(row["cycle"]) - chunk.first_cycle, 0, len(chunk) - 1))
                by_time.setdefault(int(chunk.time_ns[i]), []).extend(items)

    def status(self) -> dict[str, Any]:
        """Counters for ``status.json``."""
        return {"observations": self.observations,
                "next_sequence": self.buffer.next_sequence,
                "first_sequence": self.buffer.first_sequence,
                "agent": self.agent.url if self.agent else None,
                "shdr_clients": self.adapter.n_clients if self.adapter else 0,
                "shdr_dropped_clients": self.adapter.dropped_clients if self.adapter else 0}

    def close(self) -> None:
        """Mark the device unavailable and stop serving."""
        self._put(None, [("avail", "UNAVAILABLE")])
        if self.agent is not None:
            self.agent.close()
        if self.adapter is not None:
            self.adapter.close()

"""MQTT streaming: Industrial Edge Databus and SINUMERIK Data Recorder (needs ``paho-mqtt`` 2.x).

* :class:`MqttRecorder` / :func:`subscribe_databus`: subscribe to a Databus connector's metadata
  topic first (retained; e.g. ``ie/m/j/simatic/v1/s7c1/dp``), then to the data topics the
  metadata announces (or the given ones), feed a :class:`~cnctwin.iotools.databus.DatabusDecoder`
  and hand out :class:`~cnctwin.recording.Recording` objects per window or on request. A new
  metadata message (reconfiguration) replaces the id map and adds newly announced topics.
* :func:`subscribe_data_recorder`: SINUMERIK Data Recorder MQTT streaming, where every message
  is one complete Capture4Analysis JSON document (or a zip of it); each message becomes one
  recording through :func:`cnctwin.iotools.capture4analysis.parse_capture4analysis`, in memory.

The paho network loop runs in its own thread and only puts ``(topic, payload)`` into a bounded
queue; decoding happens in the caller's thread. Messages lost because the queue was full are
counted in the next recording's ``meta.issues``. Every wait is bounded by a timeout.
"""

from __future__ import annotations

import contextlib
import os
import queue
import select
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from types import TracebackType
from typing import Any

from cnctwin.exceptions import ConfigError, FormatError
from cnctwin.iotools._mqtt_read import receiving_client
from cnctwin.iotools.databus import DatabusColumns, DatabusDecoder, merge_columns
from cnctwin.recording import Recording

__all__ = [
    "MqttHub",
    "MqttHubs",
    "MqttRecorder",
    "MqttSecurity",
    "parse_data_recorder_message",
    "subscribe_data_recorder",
    "subscribe_databus",
]


def _paho() -> Any:
    try:
        import paho.mqtt.client as mqtt
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("MQTT streaming needs paho-mqtt 2.x: pip install 'cnctwin[mqtt]'"
                          ) from exc
    return mqtt


@dataclass(frozen=True)
class MqttSecurity:
    """Transport security of an MQTT connection: TLS and a user.

    Attributes
    ----------
    ca_file : Path or None
        CA certificate (PEM) the broker's certificate must be signed by; enables TLS.
    cert_file, key_file : Path or None
        Client certificate and key (PEM), where the broker asks for them.
    username, password : str or None
        Broker credentials (the password from a file or the environment, never the command
        line: :meth:`from_options`).
    """

    ca_file: Path | None = None
    cert_file: Path | None = None
    key_file: Path | None = None
    username: str | None = None
    password: str | None = None

    @property
    def tls(self) -> bool:
        """TLS is on (a CA or a client certificate is given)."""
        return self.ca_file is not None or self.cert_file is not None

    @classmethod
    def from_options(cls, *, ca_file: str | PathLike[str] | None = None,
                     cert_file: str | PathLike[str] | None = None,
                     key_file: str | PathLike[str] | None = None,
                     username: str | None = None,
                     password_file: str | PathLike[str] | None = None,
                     password_env: str = "CNCTWIN_MQTT_PASSWORD") -> MqttSecurity:
        """From command-line options: the password from ``password_file`` or the environment.

        Raises
        ------
        ConfigError
            A file that does not exist or cannot be read (named), a key without a certificate.
        """
        for opt, f in (("--tls-ca", ca_file), ("--tls-cert", cert_file),
                       ("--tls-key", key_file), ("--password-file", password_file)):
            if f is not None and not Path(f).is_file():
                raise ConfigError(f"{opt} {f}: no such file")
        if (cert_file is None) != (key_file is None):
            raise ConfigError("--tls-cert and --tls-key go together (the client certificate "
                              "and its key)")
        password = None
        if password_file is not None:
            password = Path(password_file).read_text(encoding="utf-8").strip()
        elif os.environ.get(password_env):
            password = os.environ[password_env]
        if password is not None and username is None:
            raise ConfigError("a password without --mqtt-user: give the user name too")
        return cls(Path(ca_file) if ca_file else None, Path(cert_file) if cert_file else None,
                   Path(key_file) if key_file else None, username, password)

    def apply(self, client: Any) -> None:
        """Configure a paho client (TLS and the user) before it connects."""
        if self.tls:
            try:
                client.tls_set(ca_certs=str(self.ca_file) if self.ca_file else None,
                               certfile=str(self.cert_file) if self.cert_file else None,
                               keyfile=str(self.key_file) if self.key_file else None)
            except (OSError, ValueError) as exc:  # ssl.SSLError is an OSError
                raise ConfigError(f"TLS files ({self.ca_file}, {self.cert_file}): {exc}"
                                  ) from None
        if self.username is not None:
            client.username_pw_set(self.username, self.password)


def connect_error(exc: BaseException, host: str, port: int) -> str:
    """A readable reason for a failed (TLS) connection."""
    import ssl

    if isinstance(exc, ssl.SSLCertVerificationError):
        return (f"TLS: the certificate of {host}:{port} is not trusted ({exc.verify_message}); "
                "give the CA that signed it with --tls-ca")
    if isinstance(exc, ssl.SSLError):
        return f"TLS handshake with {host}:{port} failed ({exc.reason or exc}); is it a TLS port?"
    return f"cannot connect to MQTT broker {host}:{port}: {exc}"


def refusal(rc: Any, host: str, port: int) -> str:
    """A readable reason for a refused CONNACK (bad user or password, not authorised)."""
    return (f"broker {host}:{port} refused the connection: {rc}; check --mqtt-user and the "
            "password (--password-file or CNCTWIN_MQTT_PASSWORD)")


Received = tuple[str, bytes, int, tuple[int, int] | None]
"""A message as the network thread hands it over: topic, payload, arrival time [ns since the
epoch], and ``(mid, qos)`` to acknowledge (None: QoS 0, or paho acknowledged it already)."""


def _received(msg: Any, manual_ack: bool) -> Received:
    return (msg.topic, bytes(msg.payload), time.time_ns(),
            (msg.mid, msg.qos) if manual_ack and msg.qos else None)


def _offer(q: queue.Queue[Received], item: Received) -> bool:
    """Put without waiting; False when the queue is full (the caller counts the drop: with
    manual acknowledgement the broker sends the message again after a reconnect)."""
    try:
        q.put_nowait(item)
    except queue.Full:
        return False
    return True


RECONNECT_MIN_S = 1.0
RECONNECT_MAX_S = 120.0
"""paho's default reconnect delays (``reconnect_delay_set``), kept when the owner's thread
drives a connection instead of paho's network thread."""


class _Client:
    """A paho client whose callbacks feed a bounded queue."""

    def __init__(self, host: str, port: int, *, client_id: str, username: str | None,
                 password: str | None, keepalive_s: int, max_queue: int,
                 security: MqttSecurity | None = None, session_expiry_s: int = 0,
                 manual_ack: bool = False, receive_maximum: int = 0) -> None:
        mqtt = _paho()
        if session_expiry_s > 0 and not client_id:
            raise ConfigError("a persistent MQTT session needs a stable client_id")
        self.host, self.port, self.keepalive_s = host, port, keepalive_s
        self.session_expiry_s = int(session_expiry_s)
        # MQTT 5 Receive Maximum: unacknowledged QoS 1 messages the broker may send (without
        # it mosquitto allows max_inflight_messages, 20 by default)
        self.receive_maximum = int(receive_maximum)
        self.v5 = self.session_expiry_s > 0 or self.receive_maximum > 0
        self.session_present = False
        self.topics: dict[str, int] = {}  # subscriptions, renewed after a session loss
        self.resubscribes = 0
        self.queue: queue.Queue[Received] = queue.Queue(maxsize=max_queue)
        self.manual_ack = manual_ack
        self.dropped = 0
        self.connected = threading.Event()
        self.connect_rc: Any = None
        self.subacks: set[int] = set()
        self._sub_lock = threading.Lock()
        self._acks: list[tuple[Any, int, int]] = []  # held (socket, packet id, qos): ack()
        # MQTT 5 for a persistent session: the broker keeps the subscriptions and queues QoS 1
        # messages for this client id while it is away (up to the expiry interval)
        # a Databus message is ~400 kB: read with one copy, not paho's ten (_mqtt_read)
        self.client = receiving_client(mqtt)(
            callback_api_version=mqtt.CallbackAPIVersion.VERSION2, client_id=client_id,
            protocol=mqtt.MQTTv5 if self.v5 else mqtt.MQTTv311,
            manual_ack=manual_ack)
        if username is not None:
            self.client.username_pw_set(username, password)
        if security is not None:
            security.apply(self.client)
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        self.client.on_subscribe = self._on_subscribe

    def _on_connect(self, client: Any, userdata: Any, flags: Any, rc: Any,
                    properties: Any = None) -> None:
        self.connect_rc = rc
        self.session_present = bool(getattr(flags, "session_present", False))
        if self.connected.is_set() and not self.session_present \
                and not getattr(rc, "is_failure", False):
            # a reconnect (paho's own) to a broker that has no session for us (restarted
            # without persistence, or the session expired): subscribe again, else the data
            # would stop without a word
            self.resubscribes += 1
            for topic, qos in list(self.topics.items()):
                client.subscribe(topic, qos=qos)
        self.connected.set()

    def _on_subscribe(self, client: Any, userdata: Any, mid: int, rcs: Any,
                      properties: Any = None) -> None:
        with self._sub_lock:
            self.subacks.add(mid)

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        if not _offer(self.queue, _received(msg, self.manual_ack)):
            self.dropped += 1

    ACK_HOLD_S = 0.05
    """A driven client holds acknowledgements up to this long and sends what gathered in
    one write (:meth:`io`): a plant worker's machines acknowledge each message once their
    checkpoint covers it, one 4-byte PUBACK each, and on loopback every send also runs the
    broker's TCP receive path (3.5 % of a live plant's CPU, BENCHMARKS.md, session 26).
    Later is always safe: an unacknowledged message is only delivered again."""

    def ack(self, acks: list[tuple[int, int]]) -> None:
        """Acknowledge messages (``manual_ack``): the broker forgets them (a driven client
        sends them with its next :meth:`io` after :attr:`ACK_HOLD_S`, or when it stops)."""
        if not self.driven:
            for mid, qos in acks:
                self.client.ack(mid, qos)
            return
        if acks:
            if not self._acks:
                self._acks_since = time.monotonic()
            # the connection they belong to: a packet id means nothing on the next one
            sock = self.client.socket()
            self._acks += [(sock, mid, qos) for mid, qos in acks]

    def _send_acks(self, *, now: float | None = None) -> None:
        """The held acknowledgements of this connection, in one write, when due."""
        if not self._acks or (now is not None and now - self._acks_since < self.ACK_HOLD_S
                              and len(self._acks) < 256):
            return
        acks, self._acks = self._acks, []
        c = self.client
        sock = c.socket()
        with c.holding_writes():
            for s, mid, qos in acks:
                if s is sock and sock is not None:
                    c.ack(mid, qos)
        if sock is not None:
            c.loop_write()

    def start(self, timeout_s: float) -> None:
        try:
            if self.v5:
                from paho.mqtt.packettypes import PacketTypes
                from paho.mqtt.properties import Properties

                props = Properties(PacketTypes.CONNECT)
                props.SessionExpiryInterval = self.session_expiry_s
                if self.receive_maximum:
                    props.ReceiveMaximum = min(self.receive_maximum, 65535)
                self.client.connect(self.host, self.port, keepalive=self.keepalive_s,
                                    clean_start=self.session_expiry_s == 0, properties=props)
            else:
                self.client.connect(self.host, self.port, keepalive=self.keepalive_s)
        except OSError as exc:
            raise ConnectionError(connect_error(exc, self.host, self.port)) from exc
        self.client.loop_start()
        if not self.connected.wait(timeout_s):
            self.stop()
            raise TimeoutError(f"no CONNACK from {self.host}:{self.port} within {timeout_s} s")
        if getattr(self.connect_rc, "is_failure", False):
            self.stop()
            raise ConnectionError(refusal(self.connect_rc, self.host, self.port))

    def subscribe(self, topic: str, qos: int) -> int:
        self.topics[topic] = qos
        _, mid = self.client.subscribe(topic, qos=qos)
        return int(mid)

    def acked(self, mid: int) -> bool:
        with self._sub_lock:
            return mid in self.subacks

    def unsubscribe(self, topics: list[str]) -> None:
        for t in topics:
            self.topics.pop(t, None)
        if topics:
            with contextlib.suppress(Exception):  # a lost connection: nothing to undo
                self.client.unsubscribe(topics)

    def stop(self) -> None:
        with contextlib.suppress(Exception):
            self._send_acks()
        with contextlib.suppress(Exception):
            self.client.disconnect()
        with contextlib.suppress(Exception):
            self.client.loop_stop()

    # ------------------------------------------------ driven from its owner's thread
    driven = False
    _acks_since = 0.0
    _retry_at = 0.0
    _retry_s = RECONNECT_MIN_S

    def drive(self) -> None:
        """Stop the network thread: from now on the owner's thread calls :meth:`io` (paho's
        external-loop calls on the same connection and session)."""
        if not self.driven:
            self.client.loop_stop()  # the thread ends after its select (<= 1 s)
            self.driven = True

    def buffered(self) -> bool:
        """Decrypted bytes wait inside a TLS socket (a ``select`` on it does not see them)."""
        pending = getattr(self.client.socket(), "pending", None)
        return pending is not None and pending() > 0

    def readable(self) -> bool:
        """Bytes wait: on the socket, or decrypted already inside a TLS socket."""
        sock = self.client.socket()
        if sock is None:
            return False
        return self.buffered() or bool(select.select([sock], [], [], 0.0)[0])

    def io(self, *, max_packets: int = 10_000) -> None:
        """Read what arrived (messages go to ``on_message``), write what waits, keep the
        connection alive; reconnect a lost one with paho's back-off (1 s doubling to 120 s)
        without blocking on it."""
        c = self.client
        now = time.monotonic()
        if c.socket() is None:
            if now < self._retry_at:
                return
            try:
                c.reconnect()
            except OSError:
                self._retry_at = now + self._retry_s
                self._retry_s = min(2.0 * self._retry_s, RECONNECT_MAX_S)
                return
            self._retry_s = RECONNECT_MIN_S
        rc = 0
        for _ in range(max_packets):  # paho reads one packet per call with nothing in flight
            rc = c.loop_read()
            if rc != 0 or not self.readable():
                break
        if rc == 0:
            self._send_acks(now=now)
        if rc == 0 and c.want_write():
            rc = c.loop_write()
        if rc == 0:
            rc = c.loop_misc()
        if c.socket() is None:  # lost (paho closed it): the next attempt after the delay
            self._retry_at = now + self._retry_s


class _HubPort:
    """One recorder's view of a :class:`MqttHub`: what :class:`MqttRecorder` uses of its own
    client (``queue``, ``subscribe``, ``acked``, ``ack``, ``start``, ``stop``), fed by the hub's
    routing instead of a connection of its own."""

    def __init__(self, hub: MqttHub, max_queue: int) -> None:
        self.hub = hub
        self.queue: queue.Queue[Received] = queue.Queue(maxsize=max_queue)
        self.dropped = 0
        self.manual_ack = True

    def put(self, item: Received) -> None:
        if not _offer(self.queue, item):
            self.dropped += 1

    @property
    def session_present(self) -> bool:
        return bool(self.hub.client.session_present)

    @property
    def session_expiry_s(self) -> int:
        return self.hub.client.session_expiry_s

    def start(self, timeout_s: float) -> None:
        self.hub.start(timeout_s)

    def subscribe(self, topic: str, qos: int) -> int:
        return self.hub.subscribe(topic, qos, self)

    def acked(self, mid: int) -> bool:
        return self.hub.client.acked(mid)

    def ack(self, acks: list[tuple[int, int]]) -> None:
        self.hub.client.ack(acks)

    def stop(self) -> None:
        self.hub.detach(self)


class MqttHub:
    """One MQTT connection for the Databus sources of many machines (a plant worker's).

    Each :class:`MqttRecorder` given ``hub=`` subscribes through it; the hub's network thread
    routes every message by its topic into that recorder's queue (a dictionary lookup; no
    decoding there) and notes the recorder in :attr:`touched`, so one thread can serve all
    machines: wait on :attr:`notify`, then poll the recorders that have messages; or, after
    :meth:`drive`, that thread does the socket work itself (:meth:`io`) and no network
    thread runs. QoS 1 messages are acknowledged by the recorders (manual acknowledgement,
    as with a connection of their own), so exactly-once across crashes holds per machine;
    with a ``client_id`` and ``session_expiry_s`` the broker keeps one persistent session
    for all of them.

    Messages for a topic no recorder has claimed yet (a resumed session delivers its queue
    before the machines have subscribed, or before their metadata told them the data topics)
    are held, in order, and handed over when a recorder subscribes to the topic; at most
    ``max_pending_bytes`` of them (more are left unacknowledged, so the broker delivers them
    again on the next connection, and counted in :attr:`unrouted_dropped`). A recorder that
    stops while others go on unsubscribes its topics (the broker then keeps nothing more for
    it; a recorder with a connection of its own leaves that to its session's expiry).

    Parameters
    ----------
    host, port : str, int
        Broker.
    client_id : str, optional
        Stable client id (the key of the persistent session).
    username, password : str, optional
        Broker credentials.
    security : MqttSecurity, optional
        TLS and user.
    session_expiry_s : int, default 0
        MQTT 5 session expiry [s] (0: a clean session).
    max_pending_bytes : int, default 256 MiB
        Unclaimed messages held [bytes of payload].
    notify : threading.Event, optional
        Set whenever a routed message arrives (several hubs may share one).
    receive_maximum : int, default 1000
        Unacknowledged QoS 1 messages the broker may send (MQTT 5 Receive Maximum, at most
        65535): the machines together hold up to their checkpoints' worth (10 messages each
        by default), which one connection must be allowed; the broker's own per-client
        limit (mosquitto ``max_inflight_messages``, 20) applies only without it.

    Notes
    -----
    Acknowledgements go out per machine when its checkpoint covers the messages, so across
    machines they are not in the order the messages came in (MQTT 5 asks a receiver to
    acknowledge QoS 1 messages in order, [MQTT-4.6.0-2]); brokers match a PUBACK by its packet
    id (mosquitto does; tested in tests/edge/test_plant_hub.py).
    """

    def __init__(self, host: str, port: int = 1883, *, client_id: str = "",
                 username: str | None = None, password: str | None = None,
                 security: MqttSecurity | None = None, session_expiry_s: int = 0,
                 max_pending_bytes: int = 256 << 20, notify: threading.Event | None = None,
                 receive_maximum: int = 1000) -> None:
        self.client = _Client(host, port, client_id=client_id, username=username,
                              password=password, keepalive_s=30, max_queue=1,
                              security=security, session_expiry_s=session_expiry_s,
                              manual_ack=True, receive_maximum=receive_maximum)
        self.client.client.on_message = self._on_message
        self.client_id = client_id
        self.notify = notify if notify is not None else threading.Event()
        self.max_pending_bytes = max_pending_bytes
        self._pending_bytes = 0
        self.unrouted_dropped = 0
        self._routes: dict[str, _HubPort] = {}
        self._wild: dict[str, _HubPort] = {}  # filter prefix (before '#') -> port
        self._pending: list[Received] = []
        self._touched: set[_HubPort] = set()
        self._ports: set[_HubPort] = set()
        self._lock = threading.Lock()
        self._start_lock = threading.Lock()
        self._started = False
        self.closing = False  # every recorder is stopping: keep the session's subscriptions

    def port(self, max_queue: int = 100_000) -> _HubPort:
        """A recorder's view of the hub (:class:`MqttRecorder` calls it)."""
        p = _HubPort(self, max_queue)
        with self._lock:
            self._ports.add(p)
        return p

    def start(self, timeout_s: float = 10.0) -> None:
        """Connect (once; every recorder's start calls it)."""
        with self._start_lock:
            if not self._started:
                self.client.start(timeout_s)
                self._started = True

    def _route(self, topic: str) -> _HubPort | None:
        p = self._routes.get(topic)
        if p is None and self._wild:
            for prefix, wp in self._wild.items():
                if topic.startswith(prefix):
                    return wp
        return p

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        item = _received(msg, True)
        with self._lock:
            p = self._route(msg.topic)
            if p is None:
                if self._pending_bytes + len(item[1]) <= self.max_pending_bytes:
                    self._pending.append(item)
                    self._pending_bytes += len(item[1])
                else:
                    self.unrouted_dropped += 1
                return
            p.put(item)
            self._touched.add(p)
        self.notify.set()

    def subscribe(self, topic: str, qos: int, port: _HubPort) -> int:
        """Route ``topic`` (an exact topic or a filter ending in ``#``) to ``port``, hand it
        the held messages of that topic, and subscribe. Returns the SUBSCRIBE's message id.

        Raises
        ------
        ConfigError
            Another recorder of this connection has the topic (two machines of a plant
            configured with one connector's topics).
        """
        with self._lock:
            table, key = (self._wild, topic[:-1]) if topic.endswith("#") else \
                (self._routes, topic)
            other = table.get(key)
            if other is not None and other is not port:
                raise ConfigError(f"MQTT topic {topic!r} belongs to two machines on the "
                                  "same broker: give each machine its own connector topics")
            table[key] = port
            keep = []
            for item in self._pending:
                if self._route(item[0]) is port:
                    port.put(item)
                    self._touched.add(port)
                    self._pending_bytes -= len(item[1])
                else:
                    keep.append(item)
            moved = len(keep) != len(self._pending)
            self._pending = keep
        if moved:
            self.notify.set()
        return self.client.subscribe(topic, qos)

    @property
    def driven(self) -> bool:
        """Driven from its owner's thread (:meth:`drive`), no network thread."""
        return self.client.driven

    def drive(self) -> None:
        """Hand the connection's socket work to the caller's thread: stop the network thread;
        from now on the caller calls :meth:`io` (and may wait on :meth:`socket`). A plant
        worker does it once its machines are built (their start waits for the metadata,
        which the thread delivers): one thread then serves the connection and the
        machines, with no hand-over of the interpreter lock per message."""
        with self._start_lock:
            if self._started:
                self.client.drive()

    def socket(self) -> Any:
        """The connection's socket (None while reconnecting)."""
        return self.client.client.socket()

    def buffered(self) -> bool:
        """Decrypted bytes wait inside its TLS socket: read them before waiting on it."""
        return self.client.buffered()

    def io(self) -> None:
        """Socket work of a driven hub: routes what arrived (see :meth:`drive`)."""
        if self._started and self.client.driven:
            self.client.io()

    def take_touched(self) -> set[_HubPort]:
        """The ports that received messages since the last call (and clear :attr:`notify`)."""
        with self._lock:
            self.notify.clear()
            got, self._touched = self._touched, set()
        return got

    def detach(self, port: _HubPort) -> None:
        """A recorder stops: its topics are no longer routed; while other recorders go on
        they are unsubscribed (else their messages would fill the broker's in-flight window
        unacknowledged); the connection closes with the last recorder (its session keeps
        every subscription)."""
        with self._lock:
            gone = [t for t, p in self._routes.items() if p is port] + \
                [t + "#" for t, p in self._wild.items() if p is port]
            self._routes = {t: p for t, p in self._routes.items() if p is not port}
            self._wild = {t: p for t, p in self._wild.items() if p is not port}
            self._ports.discard(port)
            self._touched.discard(port)
            last = not self._ports
        if last:
            self.stop()
        elif self._started and not self.closing:  # the others go on: nothing more for it
            self.client.unsubscribe(gone)

    def stop(self) -> None:
        """Disconnect (the persistent session stays with the broker)."""
        with self._start_lock:
            if self._started:
                self.client.stop()
                self._started = False


class MqttHubs:
    """The hubs of one plant worker: one per broker, user and session setting, made on first
    use (thread-safe: the machines are built in parallel).

    Parameters
    ----------
    client_id : str
        Client id of the worker's persistent sessions (the second hub gets ``-2``, ...).
    machines : int, default 1
        Machines of the worker: each may hold 10 messages unacknowledged until its
        checkpoint, so a hub allows 20 per machine in flight (at least 100).
    """

    def __init__(self, client_id: str, *, machines: int = 1) -> None:
        self.client_id = client_id
        self.machines = machines
        self._hubs: dict[tuple[Any, ...], MqttHub] = {}
        self._lock = threading.Lock()

    def get(self, host: str, port: int, *, username: str | None = None,
            password: str | None = None, security: MqttSecurity | None = None,
            session_expiry_s: int = 0) -> MqttHub:
        """The hub of this broker connection (made now if it is the first)."""
        key = (host, int(port), username, password, security, int(session_expiry_s))
        with self._lock:
            hub = self._hubs.get(key)
            if hub is None:
                k = len(self._hubs) + 1
                cid = self.client_id if k == 1 else f"{self.client_id}-{k}"
                hub = self._hubs[key] = MqttHub(
                    host, port, client_id=cid, username=username, password=password,
                    security=security, session_expiry_s=session_expiry_s,
                    receive_maximum=max(100, 20 * self.machines))
            return hub

    def stop(self) -> None:
        """Disconnect every hub."""
        with self._lock:
            hubs = list(self._hubs.values())
        for h in hubs:
            h.stop()


class MqttRecorder:
    """Record Industrial Edge Databus values from an MQTT broker.

    Parameters
    ----------
    host : str
        Broker host (on an Industrial Edge device: ``ie-databus``).
    port : int, default 1883
        Broker port.
    metadata_topic : str
        Metadata topic of the connector (``ie/m/j/simatic/v1/<instance>/dp``).
    data_topics : list of str, optional
        Data topics; default all topics the metadata announces.
    name_map : dict, optional
        Datapoint name -> recording column (``{"Axis_X_Load": "LOAD|X1"}``).
    cycle_time_s : float, default 0.002
        Cycle base of the recordings [s].
    username, password : str, optional
        Broker credentials (Databus users are set up in the Databus configurator).
    client_id : str, optional
        MQTT client id; default a random one.
    qos : int, default 1
        Subscription QoS.
    salvage : bool, default False
        Keep values with unknown ids (see :class:`~cnctwin.iotools.databus.DatabusDecoder`).
    max_queue : int, default 100000
        Messages buffered between the network thread and the decoder.
    session_expiry_s : int, default 0
        With a ``client_id``: an MQTT 5 persistent session (clean start off, this session
        expiry interval [s]); the broker keeps the subscriptions and queues the QoS 1 messages
        that arrive while the recorder is away, and delivers them on the next start. 0: a clean
        session (MQTT 3.1.1), nothing is kept. Data that a resumed session delivers before the
        (retained) metadata is held, up to ``max_queue`` messages, and decoded once the
        metadata is known.
    columnar : bool, default False
        Decode well-formed bulk messages of numbers straight into arrays
        (:meth:`DatabusDecoder.decode_columns`, collected by :meth:`take_columns`) instead of
        one object per value; every other message takes the general path. The live edge
        source uses it.
    manual_ack : bool, default False
        QoS 1 messages are acknowledged to the broker only by :meth:`ack` (the live edge
        source does it after their results are written), not when they arrive; with a
        persistent session a crash in between makes the broker deliver them again.
    hub : MqttHub, optional
        Share this connection with other recorders (a plant worker's machines): ``host``,
        ``port``, the user, ``client_id`` and the session are the hub's; acknowledgement is
        manual.

    Examples
    --------
    With a broker on the machine (the tests start one)::

        with MqttRecorder("127.0.0.1", 1883,
                          metadata_topic="ie/m/j/simatic/v1/s7c1/dp") as rec:
            rec.wait_ready(timeout_s=10)
            recording = rec.collect(duration_s=5)
    """

    def __init__(
        self,
        host: str,
        port: int = 1883,
        *,
        metadata_topic: str,
        data_topics: list[str] | None = None,
        name_map: dict[str, str] | None = None,
        cycle_time_s: float = 0.002,
        username: str | None = None,
        password: str | None = None,
        client_id: str = "",
        qos: int = 1,
        salvage: bool = False,
        max_queue: int = 100_000,
        security: MqttSecurity | None = None,
        session_expiry_s: int = 0,
        columnar: bool = False,
        manual_ack: bool = False,
        hub: MqttHub | None = None,
    ) -> None:
        self.metadata_topic = metadata_topic
        self.fixed_topics = list(data_topics) if data_topics else None
        self.qos = qos
        self.decoder = DatabusDecoder(name_map=name_map, cycle_time_s=cycle_time_s,
                                      salvage=salvage)
        self._client: _Client | _HubPort
        if hub is not None:  # the hub's connection (its host, user, session)
            self._client = hub.port(max_queue)
        else:
            self._client = _Client(host, port, client_id=client_id, username=username,
                                   password=password, keepalive_s=30, max_queue=max_queue,
                                   security=security, session_expiry_s=session_expiry_s,
                                   manual_ack=manual_ack)
        self._max_pending = max_queue
        self._pending: list[Received] = []
        self._unacked: list[tuple[int, int]] = []
        self.columnar = columnar
        self.batches: list[DatabusColumns] = []
        self.first_arrival_ns = 0
        self._pending_dropped = 0
        self._subscribed: dict[str, int] = {}
        self._dropped_reported = 0
        self._errors: list[str] = []
        self.messages = 0

    # ------------------------------------------------------------------ lifecycle
    def start(self, *, timeout_s: float = 10.0) -> MqttRecorder:
        """Connect and subscribe to the metadata topic."""
        self._client.start(timeout_s)
        # QoS 0: the metadata is retained (a new subscription gets it again), and a QoS 1
        # subscription would queue it behind the data messages a resumed session holds
        # unacknowledged (the broker sends only so many: mosquitto 20), which wait for it
        self._client.subscribe(self.metadata_topic, 0 if self._client.manual_ack else self.qos)
        return self

    def stop(self) -> None:
        """Disconnect and stop the network thread."""
        self._client.stop()

    @property
    def dropped(self) -> int:
        """Messages dropped: the receive queue was full, or data waited too long for metadata."""
        return int(self._client.dropped) + self._pending_dropped

    @property
    def session_present(self) -> bool:
        """The broker resumed a persistent session (queued messages follow)."""
        return bool(self._client.session_present)

    def __enter__(self) -> MqttRecorder:
        return self.start()

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    # ------------------------------------------------------------------ processing
    def _subscribe_data(self) -> None:
        topics = self.fixed_topics or self.decoder.data_topics
        for t in topics:
            if t not in self._subscribed:
                self._subscribed[t] = self._client.subscribe(t, self.qos)

    def poll(self, timeout_s: float = 0.1) -> int:
        """Decode the messages that arrived; wait up to ``timeout_s`` for the first one.

        Returns
        -------
        int
            Number of messages processed.
        """
        n = 0
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            try:
                topic, payload, arrived, ack = self._client.queue.get(
                    timeout=max(remaining, 0.0)) if n == 0 and remaining > 0 \
                    else self._client.queue.get_nowait()
            except queue.Empty:
                return n
            n += 1
            self.messages += 1
            if topic == self.metadata_topic or (
                    self.metadata_topic.endswith("#")
                    and topic.startswith(self.metadata_topic[:-1])):
                self.decoder.update_metadata(payload, topic=topic)
                self._subscribe_data()
                if ack is not None:
                    self._client.ack([ack])
                pending, self._pending = self._pending, []
                for t, p, a, k in pending:
                    self._decode(t, p, a, k)
            elif self.decoder.metadata is None:
                # a resumed session delivers the queued data before the retained metadata
                if len(self._pending) < self._max_pending:
                    self._pending.append((topic, payload, arrived, ack))
                else:
                    self._pending_dropped += 1
            else:
                self._decode(topic, payload, arrived, ack)

    def _decode(self, topic: str, payload: bytes, arrived: int,
                ack: tuple[int, int] | None = None) -> None:
        if ack is not None:
            self._unacked.append(ack)
        if not self.first_arrival_ns:
            self.first_arrival_ns = arrived
        if self.columnar:
            batch = self.decoder.decode_columns(payload, topic=topic)
            if batch is not None:
                self.batches.append(batch)
                return
        try:
            self.decoder.decode(payload, topic=topic)
        except FormatError as exc:
            # a bad message must not stop the stream: keep the error as an issue
            self.decoder.issues.append(f"message skipped: {exc}")

    def take_acks(self) -> list[tuple[int, int]]:
        """The acknowledgements of the messages decoded so far (``manual_ack``); send them
        with :meth:`ack` once what was made of those messages is safely written."""
        acks, self._unacked = self._unacked, []
        return acks

    def ack(self, acks: list[tuple[int, int]]) -> None:
        """Acknowledge messages to the broker (``manual_ack``): it will not send them again."""
        if acks:
            self._client.ack(acks)

    def take_columns(self) -> tuple[DatabusColumns | None, int]:
        """The fast-path values decoded since the last call (``columnar=True``) and the
        arrival time of the first message since then [ns since the epoch]; both reset."""
        batches, self.batches = self.batches, []
        first, self.first_arrival_ns = self.first_arrival_ns, 0
        return (merge_columns(batches) if batches else None), first

    def dropped_issue(self) -> str | None:
        """A message about receive-queue drops since the last call (None without any)."""
        dropped = self.dropped - self._dropped_reported
        if not dropped:
            return None
        self._dropped_reported = self.dropped
        return (f"{dropped} MQTT messages dropped: the receive queue was full (decode faster "
                "or raise max_queue)")

    @property
    def ready(self) -> bool:
        """Metadata received and every data subscription acknowledged by the broker."""
        return bool(self._subscribed) and all(self._client.acked(m)
                                              for m in self._subscribed.values())

    def wait_ready(self, *, timeout_s: float = 10.0) -> None:
        """Block until the metadata arrived and the data topics are subscribed.

        Raises
        ------
        TimeoutError
            If no metadata arrives on ``metadata_topic`` within ``timeout_s``.
        """
        deadline = time.monotonic() + timeout_s
        while not self.ready:
            if time.monotonic() > deadline:
                raise TimeoutError(
                    f"no metadata on {self.metadata_topic!r} (or no SUBACK for the data "
                    f"topics) within {timeout_s} s; check the topic and the broker user's ACL")
            self.poll(0.05)

    def _recording(self) -> Recording:
        rec = self.decoder.recording(clear=True)
        msg = self.dropped_issue()
        if msg:
            rec.meta.issues.append(msg)
            rec.meta.partial = True
        return rec

    def collect(
        self,
        *,
        duration_s: float | None = None,
        until: Callable[[DatabusDecoder], bool] | None = None,
        timeout_s: float = 60.0,
    ) -> Recording:
        """Decode messages for ``duration_s`` or until ``until(decoder)`` is true.

        Parameters
        ----------
        duration_s : float, optional
            Collect for this long [s].
        until : callable, optional
            Stop as soon as it returns True (e.g. ``lambda d: len(d.values) >= 100``).
        timeout_s : float, default 60
            Upper bound on the wait [s]; reaching it returns what was collected (with an
            issue) when ``until`` was given.

        Returns
        -------
        Recording
            The values collected (the decoder is cleared).
        """
        start = time.monotonic()
        limit = min(duration_s if duration_s is not None else timeout_s, timeout_s)
        while time.monotonic() - start < limit:
            self.poll(0.05)
            if until is not None and until(self.decoder):
                break
        else:
            if until is not None:
                self.decoder.issues.append(f"collect: condition not met within {limit} s")
        return self._recording()

    def windows(self, window_s: float, *, max_windows: int | None = None,
                timeout_s: float | None = None) -> Iterator[Recording]:
        """Yield one recording per ``window_s`` of arrival time (windows without values are
        skipped).

        Parameters
        ----------
        window_s : float
            Window length on the receiving clock [s].
        max_windows : int, optional
            Stop after this many recordings.
        timeout_s : float, optional
            Stop after this long in total [s].
        """
        t_start = time.monotonic()
        count = 0
        while max_windows is None or count < max_windows:
            w_end = time.monotonic() + window_s
            while time.monotonic() < w_end:
                self.poll(min(0.05, max(w_end - time.monotonic(), 0.0)))
            if self.decoder.values:
                count += 1
                yield self._recording()
            if timeout_s is not None and time.monotonic() - t_start > timeout_s:
                return


def subscribe_databus(
    host: str,
    port: int = 1883,
    *,
    metadata_topic: str,
    data_topics: list[str] | None = None,
    window_s: float = 1.0,
    max_windows: int | None = None,
    timeout_s: float | None = None,
    name_map: dict[str, str] | None = None,
    cycle_time_s: float = 0.002,
    username: str | None = None,
    password: str | None = None,
) -> Iterator[Recording]:
    """Stream Databus values as one recording per window (see :class:`MqttRecorder`).

    Parameters
    ----------
    host, port : str, int
        Broker.
    metadata_topic : str
        Connector metadata topic (subscribed first).
    data_topics : list of str, optional
        Data topics; default those in the metadata.
    window_s : float, default 1.0
        Window length [s].
    max_windows : int, optional
        Stop after this many windows.
    timeout_s : float, optional
        Stop after this long [s].
    name_map : dict, optional
        Datapoint name -> column.
    cycle_time_s : float, default 0.002
        Cycle base [s].
    username, password : str, optional
        Broker credentials.

    Yields
    ------
    Recording
    """
    with MqttRecorder(host, port, metadata_topic=metadata_topic, data_topics=data_topics,
                      name_map=name_map, cycle_time_s=cycle_time_s, username=username,
                      password=password) as rec:
        yield from rec.windows(window_s, max_windows=max_windows, timeout_s=timeout_s)


def parse_data_recorder_message(payload: bytes, *, topic: str = "<mqtt>",
                                salvage: bool = False) -> Recording:
    """One SINUMERIK Data Recorder MQTT message (Capture4Analysis JSON, or a zip) -> Recording.

    The payload is parsed in memory with
    :func:`cnctwin.iotools.capture4analysis.parse_capture4analysis` (no temporary file); errors
    and ``meta.issues`` name the topic, and ``meta.source_files`` is ``[topic]``.

    Parameters
    ----------
    payload : bytes
        Message payload.
    topic : str, default '<mqtt>'
        Topic (named in errors and notes).
    salvage : bool, default False
        Keep what an incomplete message holds (flagged partial).

    Returns
    -------
    Recording
    """
    from cnctwin.iotools.capture4analysis import parse_capture4analysis

    rec = parse_capture4analysis(payload, source=topic, salvage=salvage)
    rec.meta.source_files = [topic]
    return rec


def subscribe_data_recorder(
    host: str,
    port: int = 1883,
    topic: str = "#",
    *,
    max_messages: int | None = None,
    timeout_s: float | None = None,
    salvage: bool = False,
    username: str | None = None,
    password: str | None = None,
    qos: int = 1,
    ready: threading.Event | None = None,
) -> Iterator[Recording]:
    """Stream SINUMERIK Data Recorder messages, one recording per message.

    Parameters
    ----------
    host, port : str, int
        Broker.
    topic : str, default '#'
        Data Recorder topic (global topic + optional job sub-topic, e.g. ``MACHINE_A/#``).
    max_messages : int, optional
        Stop after this many recordings.
    timeout_s : float, optional
        Stop when no message arrived for this long [s].
    salvage : bool, default False
        Passed to the Capture4Analysis reader. A message that still fails is skipped and
        listed in the next recording's ``meta.issues``.
    username, password : str, optional
        Broker credentials.
    qos : int, default 1
        Subscription QoS.
    ready : threading.Event, optional
        Set once the subscription is acknowledged (lets a test publish afterwards).

    Yields
    ------
    Recording
    """
    client = _Client(host, port, client_id="", username=username, password=password,
                     keepalive_s=30, max_queue=1000)
    client.start(10.0 if timeout_s is None else timeout_s)
    try:
        mid = client.subscribe(topic, qos)
        count = 0
        pending: list[str] = []
        last = time.monotonic()
        while max_messages is None or count < max_messages:
            if ready is not None and not ready.is_set() and client.acked(mid):
                ready.set()
            try:
                t, payload, _, _ = client.queue.get(timeout=0.05)
            except queue.Empty:
                if timeout_s is not None and time.monotonic() - last > timeout_s:
                    return
                continue
            last = time.monotonic()
            try:
                rec = parse_data_recorder_message(payload, topic=t, salvage=salvage)
            except FormatError as exc:
                pending.append(f"a Data Recorder message on {t} was skipped: {exc}")
                continue
            rec.meta.issues[:0] = pending
            pending = []
            if client.dropped:
                rec.meta.issues.append(f"{client.dropped} MQTT messages dropped (queue full)")
                client.dropped = 0
            count += 1
            yield rec
    finally:
        client.stop()

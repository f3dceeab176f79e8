"""A paho client that reads large messages with one copy (the receive side of the MQTT sources).

paho 2.x reads a packet's body with ``recv(remaining)`` calls, each allocating a buffer the
size of what is still missing, appends them to a ``bytearray`` and then unpacks a PUBLISH
with three ``struct.unpack`` copies of the whole body: for a 400 kB Databus message (one
second of 11 datapoints at 500 Hz) about ten buffers and copies of its size. Here the body
goes with ``recv_into`` into one buffer that lives as long as the client, and a PUBLISH of
QoS 0 or 1 is read from a view of it: the payload is copied once, into the ``bytes`` the
``on_message`` callback gets. CPU per 400 kB message on a 2-vCPU VM: 0.90-0.97 against
0.64-0.65 ms in a receiver alone (``benchmarks/bench_mqtt_receive.py``; 2.2-2.7 against
0.63 ms in a fresh process, whose allocator still maps every large buffer anew), 0.92
against 0.72 ms in a plant worker (BENCHMARKS.md, session 25). An MQTT 3.1.1 PUBACK
(what the result sinks read) is read without the ``ReasonCode`` and ``Properties``
objects paho makes for each.

Only the reading of a packet and the unpacking of those two kinds are replaced; every
packet is still handled by paho (``_packet_handle``: acknowledgements, the keepalive, QoS 2
flows, ``manual_ack``), and the callbacks get what paho gives them (the same
:class:`paho.mqtt.client.MQTTMessage` fields, MQTT 5 properties included). The
packet-reading methods of paho 2.x are not public API: the project pins
``paho-mqtt>=2.0,<3`` and ``tests/iotools/test_mqtt_read.py`` feeds the same byte streams
to paho's own client and to this one and compares what comes out.
"""

from __future__ import annotations

import contextlib
import copy
import ssl
import struct
from collections.abc import Iterator
from functools import cache
from typing import Any

_PUBLISH = 0x30
_PUBACK = 0x40
_DISCONNECT = 0xE0


def _quiet(packet: dict[str, Any]) -> bool:
    """Nothing happens in paho once this queued packet is written (see ``_packet_write``)."""
    cmd = packet["command"] & 0xF0
    return cmd != _DISCONNECT and not (cmd == _PUBLISH and packet["qos"] == 0)


def _fresh_packet() -> dict[str, Any]:
    """paho's empty incoming-packet state."""
    return {"command": 0, "have_remaining": 0, "remaining_count": [], "remaining_mult": 1,
            "remaining_length": 0, "packet": bytearray(b""), "to_process": 0, "pos": 0}


@cache
def receiving_client(mqtt: Any) -> type:
    """The subclass of ``mqtt.Client`` (``paho.mqtt.client``) that reads with one copy.

    Parameters
    ----------
    mqtt : module
        ``paho.mqtt.client``.

    Returns
    -------
    type
        A subclass of ``mqtt.Client``, constructed as it is.
    """
    from paho.mqtt.exception import MalformedPacket, MQTTException
    from paho.mqtt.packettypes import PacketTypes
    from paho.mqtt.properties import Properties
    from paho.mqtt.reasoncodes import ReasonCode

    err = mqtt.MQTTErrorCode
    malformed = MalformedPacket
    # what paho's own decoding turns into MalformedPacket (paho.mqtt._packet.DECODE_ERRORS)
    decode_errors = (struct.error, IndexError, KeyError, ValueError, MQTTException)

    class OneCopyClient(mqtt.Client):
        """``paho.mqtt.client.Client`` that reads a packet's body into one reused buffer."""

        _in_packet: dict[str, Any]  # paho's state of the packet being read
        _body_buf: bytearray | None = None
        _body_pos = 0
        _no_props: Any = None  # an empty MQTT 5 Properties of PUBLISH, copied per message

        def _recv_into(self, view: memoryview) -> int:
            sock = self._sock
            if sock is None:
                raise ConnectionError("self._sock is None")
            try:
                return int(sock.recv_into(view))
            except ssl.SSLWantReadError as exc:
                raise BlockingIOError() from exc
            except ssl.SSLWantWriteError as exc:
                self._call_socket_register_write()
                raise BlockingIOError() from exc

        def _read_header(self) -> Any:
            """The command byte and the remaining length (paho's byte-wise read); None when
            both are known, else the return code."""
            p = self._in_packet
            try:
                if p["command"] == 0:
                    c = self._sock_recv(1)
                    if len(c) == 0:
                        return err.MQTT_ERR_CONN_LOST
                    p["command"] = c[0]
                if p["have_remaining"] == 0:
                    while True:
                        b = self._sock_recv(1)
                        if len(b) == 0:
                            return err.MQTT_ERR_CONN_LOST
                        v = b[0]
                        p["remaining_count"].append(v)
                        if len(p["remaining_count"]) > 4:  # at most 4 bytes (MQTT 2.1.4)
                            return err.MQTT_ERR_PROTOCOL
                        p["remaining_length"] += (v & 127) * p["remaining_mult"]
                        p["remaining_mult"] *= 128
                        if (v & 128) == 0:
                            break
                    p["have_remaining"] = 1
                    p["to_process"] = p["remaining_length"]
            except BlockingIOError:
                return err.MQTT_ERR_AGAIN
            except OSError:
                return err.MQTT_ERR_CONN_LOST
            return None

        def _packet_read(self) -> Any:
            rc = self._read_header()
            if rc is not None:
                return rc
            p = self._in_packet
            n = int(p["remaining_length"])
            buf = self._body_buf
            if buf is None or len(buf) < n:
                # a new buffer (not a resize: a view of the old one may still be held)
                buf = self._body_buf = bytearray(max(n, 1 << 16))
            with memoryview(buf) as whole:
                view = whole[:n]
                try:
                    while self._body_pos < n:
                        try:
                            k = self._recv_into(view[self._body_pos:])
                        except BlockingIOError:
                            return err.MQTT_ERR_AGAIN
                        except OSError:
                            return err.MQTT_ERR_CONN_LOST
                        if k == 0:
                            return err.MQTT_ERR_CONN_LOST
                        self._body_pos += k
                        p["to_process"] = n - self._body_pos
                        with self._msgtime_mutex:
                            self._last_bytes_received = mqtt.time_func()
                    self._body_pos = 0
                    # a PUBLISH is read from the view (_handle_publish); the small packets
                    # as paho keeps them
                    p["packet"] = view if (p["command"] & 0xF0) == _PUBLISH else bytes(view)
                    p["pos"] = 0
                    try:
                        rc = self._packet_handle()
                    except malformed:
                        rc = err.MQTT_ERR_PROTOCOL
                    self._in_packet = _fresh_packet()
                finally:
                    view.release()
            with self._msgtime_mutex:
                self._last_bytes_received = mqtt.time_func()
            return rc

        def _handle_publish(self) -> Any:
            header = int(self._in_packet["command"])
            qos = (header & 0x06) >> 1
            packet = self._in_packet["packet"]
            if qos > 1 or not isinstance(packet, memoryview):
                if isinstance(packet, memoryview):
                    self._in_packet["packet"] = bytes(packet)
                return super()._handle_publish()  # QoS 2: paho's flow
            try:
                (slen,) = struct.unpack_from("!H", packet, 0)
                if 2 + slen > len(packet):
                    raise malformed("topic longer than the packet")
                topic = bytes(packet[2:2 + slen])
                if self._protocol != mqtt.MQTTv5 and slen == 0:
                    raise malformed("topic can't be empty in MQTTv3")
                pos = 2 + slen
                mid = 0
                if qos > 0:
                    (mid,) = struct.unpack_from("!H", packet, pos)
                    pos += 2
                props = None
                if self._protocol == mqtt.MQTTv5:
                    size, mult, i = 0, 1, pos  # property length: a variable byte integer
                    while True:
                        b = packet[i]
                        i += 1
                        size += (b & 127) * mult
                        mult *= 128
                        if not b & 128:
                            break
                        if i - pos >= 4:
                            raise malformed("property length longer than 4 bytes")
                    if i + size > len(packet):
                        raise malformed("properties longer than the packet")
                    if size:
                        props = Properties(PacketTypes.PUBLISH)
                        props.unpack(bytes(packet[pos:i + size]))
                    else:  # none (a Databus message): a copy of an empty one, not a new one
                        if self._no_props is None:
                            self._no_props = Properties(PacketTypes.PUBLISH)
                        props = copy.copy(self._no_props)
                    pos = i + size
                payload = bytes(packet[pos:])
            except malformed:
                raise
            except decode_errors as exc:
                raise malformed(str(exc)) from exc
            message = mqtt.MQTTMessage(mid=mid, topic=topic)
            message.dup = bool(header & 0x08)
            message.qos = qos
            message.retain = bool(header & 0x01)
            message.properties = props
            message.payload = payload
            message.timestamp = mqtt.time_func()
            self._handle_on_message(message)
            if qos == 1 and not self._manual_ack:
                return self._send_puback(mid)
            return err.MQTT_ERR_SUCCESS

        _puback: tuple[Any, Any] | None = None

        # ------------------------------------------------------------ writing
        _holding = False

        @contextlib.contextmanager
        def holding_writes(self) -> Iterator[None]:
            """Packets made inside (acknowledgements, publishes) are queued, not written;
            the next :meth:`loop_write` sends them together, in one system call where they
            fit the socket's buffer (see :meth:`_packet_write`)."""
            self._holding = True
            try:
                yield
            finally:
                self._holding = False

        def _packet_queue(self, command: int, packet: Any, mid: int, qos: int,
                          info: Any = None) -> Any:
            if not self._holding:
                return super()._packet_queue(command, packet, mid, qos, info)
            self._out_packet.append({"command": command, "mid": mid, "qos": qos, "pos": 0,
                                     "to_process": len(packet), "packet": packet,
                                     "info": info})
            return err.MQTT_ERR_SUCCESS

        def _packet_write(self) -> Any:
            # consecutive packets not begun and without anything to do once written (all
            # but a QoS 0 PUBLISH, whose on_publish paho calls then, and a DISCONNECT) go
            # out as one: on loopback each send runs the broker's TCP receive path too
            q = self._out_packet
            if len(q) > 1 and q[0]["pos"] == 0:
                run = []
                while q and q[0]["pos"] == 0 and _quiet(q[0]):
                    run.append(q.popleft())
                if len(run) > 1:
                    blob = b"".join(bytes(p["packet"]) for p in run)
                    q.appendleft({"command": _PUBACK, "mid": 0, "qos": 1, "pos": 0,
                                  "to_process": len(blob), "packet": blob, "info": None})
                else:
                    q.extendleft(run)
            return super()._packet_write()

        def _handle_pubackcomp(self, cmd: str) -> Any:
            packet = self._in_packet["packet"]
            if cmd != "PUBACK" or self._protocol == mqtt.MQTTv5 or len(packet) != 2:
                return super()._handle_pubackcomp(cmd)
            # MQTT 3.1.1: a PUBACK is the packet id alone; paho makes a ReasonCode and a
            # Properties object for each (~0.1 ms, for every result message a sink sends):
            # these are made once per client, the success and no properties they always are
            if self._puback is None:
                self._puback = (ReasonCode(PacketTypes.PUBACK), Properties(PacketTypes.PUBACK))
            (mid,) = struct.unpack("!H", packet)
            with self._out_message_mutex:
                if mid in self._out_messages:
                    return self._do_on_publish(mid, *self._puback)
            return err.MQTT_ERR_SUCCESS

    return OneCopyClient

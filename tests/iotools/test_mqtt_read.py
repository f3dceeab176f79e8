"""The one-copy MQTT reader (cnctwin.iotools._mqtt_read) against paho's own client.

The same byte streams (PUBLISH of QoS 0/1/2 in MQTT 3.1.1 and 5 with properties, a 400 kB
Databus-sized payload, small control packets, malformed packets), cut into random pieces
as TCP may deliver them, go to a stock ``paho.mqtt.client.Client`` and to the reader's
client; the messages their ``on_message`` gets, the acknowledgements they write back and the
return codes must be the same (paho 2.x is the reference: software we did not write).
"""

from __future__ import annotations

import contextlib
import random
import socket
import struct
from typing import Any

import pytest

mqtt = pytest.importorskip("paho.mqtt.client")

from paho.mqtt.packettypes import PacketTypes  # noqa: E402
from paho.mqtt.properties import Properties  # noqa: E402

from cnctwin.iotools._mqtt_read import receiving_client  # noqa: E402


def _varint(n: int) -> bytes:
    out = b""
    while True:
        b, n = n % 128, n // 128
        out += bytes([b | (128 if n else 0)])
        if not n:
            return out


def _publish(topic: bytes, payload: bytes, *, qos: int = 0, mid: int = 0, retain: bool = False,
             dup: bool = False, props: Properties | None = None, v5: bool = False) -> bytes:
    body = struct.pack("!H", len(topic)) + topic
    if qos:
        body += struct.pack("!H", mid)
    if v5:
        body += props.pack() if props is not None else b"\x00"
    body += payload
    head = 0x30 | (qos << 1) | (0x08 if dup else 0) | (0x01 if retain else 0)
    return bytes([head]) + _varint(len(body)) + body


def _feed(client_cls: type, stream: bytes, *, v5: bool, manual_ack: bool, seed: int
          ) -> tuple[list[tuple[Any, ...]], bytes, list[int]]:
    """``stream`` into a client of ``client_cls`` in random pieces: the messages, the bytes
    it wrote back, the return codes of its reads that were not 'again'."""
    a, b = socket.socketpair()
    b.setblocking(False)
    a.setblocking(False)
    c = client_cls(callback_api_version=mqtt.CallbackAPIVersion.VERSION2, client_id="t",
                   protocol=mqtt.MQTTv5 if v5 else mqtt.MQTTv311, manual_ack=manual_ack)
    got: list[tuple[Any, ...]] = []

    def on_message(client: Any, userdata: Any, msg: Any) -> None:
        props = msg.properties.json() if msg.properties is not None else None
        got.append((msg.topic, bytes(msg.payload), msg.qos, msg.mid, msg.retain, msg.dup,
                    props))

    c.on_message = on_message
    c._sock = b
    rng = random.Random(seed)
    codes: list[int] = []
    back = b""
    pos = 0
    try:
        while pos < len(stream):
            k = rng.choice([1, 2, 3, 7, 100, 4096, 65536, 300_000])
            with contextlib.suppress(BlockingIOError):  # the socket's buffer is finite
                pos += a.send(stream[pos:pos + k])
            while True:
                rc = c._packet_read()
                if rc == mqtt.MQTTErrorCode.MQTT_ERR_AGAIN:
                    break
                if rc != mqtt.MQTTErrorCode.MQTT_ERR_SUCCESS:
                    codes.append(int(rc))
                    return got, back, codes
                with contextlib.suppress(BlockingIOError):
                    back += a.recv(1 << 20)
    finally:
        c._sock = None
        a.close()
        b.close()
    return got, back, codes


def _both(stream: bytes, *, v5: bool, manual_ack: bool = False) -> None:
    for seed in range(4):
        ref = _feed(mqtt.Client, stream, v5=v5, manual_ack=manual_ack, seed=seed)
        ours = _feed(receiving_client(mqtt), stream, v5=v5, manual_ack=manual_ack, seed=seed)
        assert ours == ref


def _mixed(v5: bool) -> bytes:
    props = None
    if v5:
        props = Properties(PacketTypes.PUBLISH)
        props.UserProperty = [("machine", "mill-007"), ("unit", "A")]
        props.MessageExpiryInterval = 30
        props.ContentType = "application/json"
    big = random.Random(1).randbytes(400_000)
    return b"".join([
        _publish(b"ie/d/j/simatic/v1/s7c1/dp/r/default/bulk", b'{"seq":1,"vals":[]}', v5=v5),
        _publish(b"a/b", big, qos=1, mid=17, v5=v5, props=props),
        b"\xd0\x00",  # PINGRESP
        _publish(b"a/c", b"", qos=1, mid=18, retain=True, dup=True, v5=v5),
        _publish(b"a/q2", b"exactly once", qos=2, mid=19, v5=v5, props=props),
        _publish(b"a/d", b"x" * 200, qos=0, retain=True, v5=v5, props=props),
    ])


@pytest.mark.parametrize("v5", [False, True])
@pytest.mark.parametrize("manual_ack", [False, True])
def test_same_messages_and_acknowledgements_as_paho(v5: bool, manual_ack: bool) -> None:
    _both(_mixed(v5), v5=v5, manual_ack=manual_ack)


@pytest.mark.parametrize("v5", [False, True])
def test_malformed_publish_is_a_protocol_error_as_in_paho(v5: bool) -> None:
    good = _publish(b"a/b", b"payload", qos=1, mid=3, v5=v5)
    # the topic length runs past the end of the packet
    body = struct.pack("!H", 500) + b"a/b"
    bad = bytes([0x32]) + _varint(len(body)) + body
    _both(good + bad, v5=v5)
    # an empty topic: an error in MQTT 3.1.1 (paho), allowed in MQTT 5 (a topic alias)
    _both(good + _publish(b"", b"no topic", qos=1, mid=4, v5=v5), v5=v5)
    if v5:  # a property length past the end of the packet
        body = struct.pack("!H", 3) + b"a/b" + struct.pack("!H", 5) + b"\x7f\x01"
        _both(good + bytes([0x32]) + _varint(len(body)) + body, v5=True)


def test_reader_reuses_one_buffer_and_copies_the_payload() -> None:
    """The body buffer lives with the client; a message handed out stays intact when the
    next one overwrites the buffer."""
    first = _publish(b"t", b"A" * 100_000, qos=1, mid=1)
    second = _publish(b"t", b"B" * 100_000, qos=1, mid=2)
    a, b = socket.socketpair()
    b.setblocking(False)
    c = receiving_client(mqtt)(callback_api_version=mqtt.CallbackAPIVersion.VERSION2,
                               client_id="t", manual_ack=True)
    got: list[bytes] = []
    c.on_message = lambda client, userdata, msg: got.append(msg.payload)
    c._sock = b
    try:
        a.sendall(first)
        while c._packet_read() == mqtt.MQTTErrorCode.MQTT_ERR_SUCCESS:
            pass
        buf = c._body_buf
        a.sendall(second)
        while c._packet_read() == mqtt.MQTTErrorCode.MQTT_ERR_SUCCESS:
            pass
        assert c._body_buf is buf
        assert got == [b"A" * 100_000, b"B" * 100_000]
        assert all(type(p) is bytes for p in got)
    finally:
        c._sock = None
        a.close()
        b.close()


def _acks(client_cls: type, stream: bytes, *, v5: bool) -> list[tuple[Any, ...]]:
    """Three QoS 1 messages published by a client of ``client_cls``, then ``stream`` (its
    acknowledgements) read: what its ``on_publish`` got."""
    a, b = socket.socketpair()
    b.setblocking(False)
    c = client_cls(callback_api_version=mqtt.CallbackAPIVersion.VERSION2, client_id="t",
                   protocol=mqtt.MQTTv5 if v5 else mqtt.MQTTv311)
    got: list[tuple[Any, ...]] = []
    c.on_publish = lambda client, userdata, mid, rc, props: got.append(
        (mid, rc.value, str(rc), props.json()))
    c._sock = b
    try:
        c._state = mqtt._ConnectionState.MQTT_CS_CONNECTED
        mids = [c.publish("t/x", b"result", qos=1).mid for _ in range(3)]
        assert mids == [1, 2, 3]
        a.sendall(stream)
        while c._packet_read() == mqtt.MQTTErrorCode.MQTT_ERR_SUCCESS:
            pass
    finally:
        c._sock = None
        a.close()
        b.close()
    return got


@pytest.mark.parametrize("v5", [False, True])
def test_publish_acknowledgements_as_in_paho(v5: bool) -> None:
    """PUBACKs (MQTT 3.1.1: the packet id; MQTT 5 also with a reason code and properties)
    reach on_publish as paho gives them, an unknown id not at all."""
    acks = b"".join(b"\x40\x02" + struct.pack("!H", m) for m in (2, 99, 1))
    if v5:
        props = Properties(PacketTypes.PUBACK)
        props.ReasonString = "quota"
        body = struct.pack("!H", 3) + b"\x97" + props.pack()
        acks += bytes([0x40]) + _varint(len(body)) + body
    else:
        acks += b"\x40\x02\x00\x03"
    ref = _acks(mqtt.Client, acks, v5=v5)
    assert [g[0] for g in ref] == [2, 1, 3]
    assert _acks(receiving_client(mqtt), acks, v5=v5) == ref


def test_held_packets_go_out_together_byte_for_byte() -> None:
    """Packets made while :meth:`holding_writes` (PUBACKs of QoS 1 messages, a QoS 1 PUBLISH)
    leave in one ``send``, the same bytes in the same order as paho writes them one by one;
    a QoS 0 PUBLISH among them is written on its own, so paho still calls its on_publish."""
    def run(cls: type, hold: bool) -> tuple[bytes, int, list[int]]:
        a, b = socket.socketpair()
        a.setblocking(False)
        c = cls(callback_api_version=mqtt.CallbackAPIVersion.VERSION2, client_id="t",
                manual_ack=True)
        c._sock = a
        c._state = mqtt._ConnectionState.MQTT_CS_CONNECTED
        published: list[int] = []
        c.on_publish = lambda client, userdata, mid, *rest: published.append(mid)
        sends = [0]
        raw = c._sock_send

        def counting(buf: Any) -> int:
            sends[0] += 1
            return int(raw(buf))

        c._sock_send = counting
        ctx = c.holding_writes() if hold else contextlib.nullcontext()
        with ctx:
            for mid in (3, 4, 5):
                c.ack(mid, 1)
            c.publish("r/m/torque", b"x" * 30_000, qos=1)
            c.publish("r/m/status", b"{}", qos=0)
            c.ack(6, 1)
        c.loop_write()
        out = b""
        b.setblocking(False)
        with contextlib.suppress(BlockingIOError):
            while chunk := b.recv(1 << 20):
                out += chunk
        c._sock = None
        a.close()
        b.close()
        return out, sends[0], published

    ref, ref_sends, ref_pub = run(mqtt.Client, hold=False)
    ours, our_sends, our_pub = run(receiving_client(mqtt), hold=True)
    assert ours == ref and len(ref) > 30_000
    assert ref_sends == 6
    assert our_sends == 3  # the first four at once, the QoS 0 PUBLISH, the last PUBACK
    assert our_pub == ref_pub == [2]  # the QoS 0 message's on_publish (mid 2)

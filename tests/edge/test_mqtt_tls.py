"""Secured MQTT (issue 14, point 3): TLS with the broker's CA, a user and a password that never
appears on the command line; a real mosquitto with TLS and a password file, certificates made
by the test. Right credentials: the results arrive; a wrong password or a wrong CA: one clear
message and exit 2, no traceback."""

from __future__ import annotations

import datetime as dt
import ipaddress
import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from cnctwin.cli import main
from tests._services import free_port, require_mosquitto, require_tool

pytestmark = [pytest.mark.mqtt, pytest.mark.xdist_group("mqtt_tls")]
USER, PASSWORD = "cnctwin-edge", "pa55-w0rd-for-the-test"


def _cert(tmp: Path, name: str, *, ca: tuple[Any, Any] | None = None) -> tuple[Any, Any]:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    now = dt.datetime.now(dt.UTC)
    b = (x509.CertificateBuilder().subject_name(subject)
         .issuer_name(ca[0].subject if ca else subject).public_key(key.public_key())
         .serial_number(x509.random_serial_number())
         .not_valid_before(now - dt.timedelta(minutes=5))
         .not_valid_after(now + dt.timedelta(days=1)))
    if ca is None:
        b = b.add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
    else:
        b = b.add_extension(x509.SubjectAlternativeName(
            [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
            critical=False)
    cert = b.sign(ca[1] if ca else key, hashes.SHA256())
    (tmp / f"{name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (tmp / f"{name}.key").write_bytes(key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption()))
    return cert, key


@pytest.fixture(scope="module")
def model_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from cnctwin.edge import save_spindle_model
    from cnctwin.spindle import SpindleModel

    return save_spindle_model(SpindleModel.from_parameters("thesis_spinner_840dsl"),
                              tmp_path_factory.mktemp("model") / "spindle.json")


@pytest.fixture(scope="module")
def tls_broker(tmp_path_factory: pytest.TempPathFactory) -> Any:
    exe = require_mosquitto()
    passwd = require_tool("mosquitto_passwd", install="apt-get install mosquitto")
    d = tmp_path_factory.mktemp("tls")
    ca = _cert(d, "ca")
    _cert(d, "server", ca=ca)
    _cert(d, "other-ca")  # a CA that did not sign the broker's certificate
    subprocess.run([passwd, "-b", "-c", str(d / "passwords"), USER, PASSWORD], check=True,
                   capture_output=True)
    port = free_port()
    # run as root, mosquitto drops to its own user, which cannot read pytest's private
    # temporary directory: keep it root for this private test broker
    user = "user root\n" if os.geteuid() == 0 else ""
    (d / "mosquitto.conf").write_text(
        f"{user}listener {port} 127.0.0.1\ncafile {d / 'ca.pem'}\n"
        f"certfile {d / 'server.pem'}\nkeyfile {d / 'server.key'}\n"
        f"password_file {d / 'passwords'}\nallow_anonymous false\n", encoding="utf-8")
    proc = subprocess.Popen([exe, "-c", str(d / "mosquitto.conf")],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(100):
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                    break
            except OSError:
                time.sleep(0.05)
        else:
            pytest.fail("mosquitto with TLS did not listen within 5 s")
        (d / "password").write_text(PASSWORD + "\n", encoding="utf-8")
        (d / "wrong").write_text("not-the-password\n", encoding="utf-8")
        yield d, port
    finally:
        proc.terminate()
        proc.wait(timeout=5)


def _subscriber(d: Path, port: int, got: list[dict[str, Any]], ready: threading.Event) -> Any:
    import paho.mqtt.client as mqtt

    c = mqtt.Client(callback_api_version=mqtt.CallbackAPIVersion.VERSION2)
    c.tls_set(ca_certs=str(d / "ca.pem"))
    c.username_pw_set(USER, PASSWORD)

    def on_connect(client: Any, *a: Any) -> None:
        client.subscribe("cnctwin/#", qos=1)

    c.on_connect = on_connect
    c.on_subscribe = lambda *a: ready.set()
    c.on_message = lambda cl, u, m: got.append(json.loads(m.payload))
    c.connect("127.0.0.1", port)
    c.loop_start()
    return c


def test_results_arrive_over_tls_with_a_password_from_a_file(
        tls_broker: Any, c4a_file: Path, model_file: Path, tmp_path: Path) -> None:
    d, port = tls_broker
    got: list[dict[str, Any]] = []
    ready = threading.Event()
    sub = _subscriber(d, port, got, ready)
    try:
        assert ready.wait(10)
        code = main(["edge", "run", "--source", str(c4a_file), "--model", str(model_file),
                     "--out", str(tmp_path / "state"), "--quiet", "--no-anomaly",
                     "--publish", f"mqtt://127.0.0.1:{port}/cnctwin",
                     "--tls-ca", str(d / "ca.pem"), "--mqtt-user", USER,
                     "--password-file", str(d / "password")])
        assert code == 0
        deadline = time.monotonic() + 10
        while not any(m.get("kind") == "torque" for m in got) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert any(m.get("kind") == "torque" for m in got)
    finally:
        sub.loop_stop()
        sub.disconnect()


@pytest.mark.parametrize(("extra", "needle"), [
    (["--password-file", "wrong"], "not authorized"),
    (["--password-file", "password", "--tls-ca-other"], "certificate"),
])
def test_wrong_password_or_ca_is_one_clear_message(
        tls_broker: Any, c4a_file: Path, model_file: Path, tmp_path: Path,
        extra: list[str], needle: str) -> None:
    d, port = tls_broker
    args = ["--tls-ca", str(d / ("other-ca.pem" if "--tls-ca-other" in extra else "ca.pem")),
            "--mqtt-user", USER, "--password-file", str(d / extra[1])]
    r = subprocess.run(
        [sys.executable, "-m", "cnctwin", "edge", "run", "--source", str(c4a_file), "--model",
         str(model_file), "--out", str(tmp_path / "s"), "--quiet", "--no-anomaly",
         "--publish", f"mqtt://127.0.0.1:{port}/cnctwin", *args],
        capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 2, r.stderr
    assert needle in r.stderr.lower() and "Traceback" not in r.stderr
    assert r.stderr.strip().count("\n") == 0


def test_the_password_from_the_environment(tls_broker: Any, c4a_file: Path, model_file: Path,
                                           tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    d, port = tls_broker
    monkeypatch.setenv("CNCTWIN_MQTT_PASSWORD", PASSWORD)
    assert main(["edge", "run", "--source", str(c4a_file), "--model", str(model_file),
                 "--out", str(tmp_path / "state"), "--quiet", "--no-anomaly",
                 "--publish", f"mqtt://127.0.0.1:{port}/cnctwin",
                 "--tls-ca", str(d / "ca.pem"), "--mqtt-user", USER]) == 0

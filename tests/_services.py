"""Real services for the tests: free loopback ports, required executables (a skip that says
what to install, a failure under ``CI=true``: CI must run every test) and a private mosquitto
broker that a test can stop and restart on the same port."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import time
from pathlib import Path

import pytest


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def require_tool(name: str, *, install: str, dirs: tuple[str, ...] = ("/usr/bin",)) -> str:
    """Path of an executable (on PATH or in ``dirs``); a skip saying how to install it, a
    failure under ``CI=true``."""
    path = shutil.which(name) or next(
        (str(Path(d) / name) for d in dirs if (Path(d) / name).exists()), None)
    if path is None:
        msg = f"{name} is required for this test: {install}"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    return path


def require_mosquitto() -> str:
    """The mosquitto binary (Debian puts it in /usr/sbin, often not on PATH)."""
    return require_tool("mosquitto", install="apt-get install mosquitto "
                        "(scripts/ensure-services.sh does it as root)", dirs=("/usr/sbin",))


class Broker:
    """A mosquitto process on a fixed free loopback port; stop() and start() again."""

    def __init__(self, exe: str, *, persistence_dir: Path | None = None) -> None:
        self.exe = exe
        self.port = free_port()
        self.proc: subprocess.Popen[bytes] | None = None
        self.persistence_dir = persistence_dir

    def _args(self) -> list[str]:
        if self.persistence_dir is None:
            return [self.exe, "-p", str(self.port)]
        # sessions, subscriptions and queued messages kept across a restart of the broker
        # (written on shutdown), as a plant's broker is configured
        self.persistence_dir.mkdir(parents=True, exist_ok=True)
        conf = self.persistence_dir / "mosquitto.conf"
        import getpass

        # `user`: run as root, mosquitto would switch to the user 'mosquitto', which cannot
        # write into the test's directory
        conf.write_text(f"listener {self.port} 127.0.0.1\nallow_anonymous true\n"
                        f"persistence true\npersistence_location {self.persistence_dir}/\n"
                        f"user {getpass.getuser()}\n")
        return [self.exe, "-c", str(conf)]

    def start(self) -> None:
        self.proc = subprocess.Popen(self._args(),
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for _ in range(100):  # up to 5 s
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.2):
                    return
            except OSError:
                time.sleep(0.05)
        pytest.fail(f"mosquitto did not listen on 127.0.0.1:{self.port} within 5 s")

    def stop(self) -> None:
        if self.proc is None:
            return
        self.proc.terminate()
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=5)
        self.proc = None

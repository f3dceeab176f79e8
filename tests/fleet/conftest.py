"""Fixtures of the fleet tests: a synthetic fleet (simulated once per session), real Dask
clusters started from the command line, and the command-line runner.

The fleet: ``cnctwin simulate fleet --machines 12 --days 2 --cycles-per-day 1 --seed 11``
(24 recordings, 5 hidden faults on day 2), as a user runs it (12, not 20, machines keep the
suite under 15 minutes in CI; every job still spans both workers many times over).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests._services import free_port

BIN = Path(sys.executable).parent
FLEET_ARGS = ["--machines", "12", "--days", "2", "--cycles-per-day", "1", "--seed", "11"]


def cnctwin(*args: str, check: bool = True, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run the ``cnctwin`` command line."""
    res = subprocess.run([str(BIN / "cnctwin"), *args], capture_output=True, text=True,
                         timeout=timeout)
    if check and res.returncode != 0:
        raise AssertionError(f"cnctwin {' '.join(args)} exited {res.returncode}:\n"
                             f"{res.stdout}\n{res.stderr}")
    return res


def dask_exe() -> str:
    exe = BIN / "dask"
    if not exe.exists():
        msg = f"{exe} missing: `make test` installs distributed with the project"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    return str(exe)


class DaskCluster:
    """``dask scheduler`` and N ``dask worker`` processes on a free port, as an operator
    starts them (workers without a nanny, so killing one kills its tasks for good)."""

    def __init__(self, n_workers: int = 2) -> None:
        self.exe = dask_exe()
        self.port = free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.n_workers = n_workers
        self.scheduler: subprocess.Popen[bytes] | None = None
        self.workers: list[subprocess.Popen[bytes]] = []

    def start(self) -> DaskCluster:
        self.scheduler = subprocess.Popen(
            [self.exe, "scheduler", "--host", "127.0.0.1", "--port", str(self.port),
             "--dashboard-address", ":0"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for i in range(self.n_workers):
            self.workers.append(subprocess.Popen(
                [self.exe, "worker", self.address, "--nthreads", "1", "--no-nanny",
                 "--name", f"w{i}", "--dashboard-address", ":0"],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                # as docs/fleet.md tells an operator: no statistical profiler in the workers
                env={**os.environ, "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False"}))
        from distributed import Client

        deadline = time.monotonic() + 60
        while True:
            try:
                with Client(self.address, timeout="5s") as c:
                    c.wait_for_workers(self.n_workers, timeout=60)
                return self
            except (OSError, TimeoutError):
                if time.monotonic() > deadline:
                    self.stop()
                    raise
                time.sleep(0.5)

    def kill_worker(self, i: int) -> None:
        self.workers[i].send_signal(signal.SIGKILL)
        self.workers[i].wait(10)

    def stop(self) -> None:
        # workers first (SIGKILL: a graceful worker close waits for the scheduler), then the
        # scheduler
        for p in self.workers:
            if p.poll() is None:
                p.kill()
            p.wait(10)
        if self.scheduler is not None and self.scheduler.poll() is None:
            self.scheduler.terminate()
            try:
                self.scheduler.wait(10)
            except subprocess.TimeoutExpired:
                self.scheduler.kill()


@pytest.fixture(scope="session")
def fleet_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The synthetic fleet written by ``cnctwin simulate fleet`` (12 machines x 2 days)."""
    out = tmp_path_factory.mktemp("fleet") / "fleet"
    cnctwin("simulate", "fleet", *FLEET_ARGS, "--workers", "2", "--out", str(out))
    return out


@pytest.fixture(scope="session")
def truth(fleet_dir: Path) -> list[dict[str, Any]]:
    """The injected faults (``truth.json``)."""
    return list(json.loads((fleet_dir / "truth.json").read_text())["faults"])


@pytest.fixture(scope="session")
def dask_cluster() -> Iterator[DaskCluster]:
    """A real scheduler and two workers, started from the command line."""
    cluster = DaskCluster(2).start()
    try:
        yield cluster
    finally:
        cluster.stop()


@pytest.fixture(scope="session")
def fleet_store(fleet_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The fleet ingested into an embedded store (on the embedded cluster)."""
    store = tmp_path_factory.mktemp("fleet-store") / "store"
    cnctwin("fleet", "ingest", str(fleet_dir), "--store", str(store), "--workers", "2")
    return store


@pytest.fixture(scope="session")
def reference_health(fleet_store: Path) -> Any:
    """Health rows of the whole fleet from the single-process batch path."""
    from cnctwin.fleet import health_partition, partitions, run_job

    return run_job(health_partition, partitions(str(fleet_store)), client=None,
                   store_url=str(fleet_store))

"""Many machines in one edge process group: ``cnctwin edge run --config plant.toml`` (issue 14,
point 4).

Each machine of a plant must get exactly what it gets from its own ``edge run``: the same
torque values and holes (compared value by value with a single-machine run of the same file),
its own state directory and message numbers; a machine that fails (a missing file) is named
and the others go on; a bad plant file is refused before anything starts, naming the file,
the machine and the key. Worker processes are real (``spawn``).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cnctwin.cli import main
from cnctwin.edge import save_spindle_model
from cnctwin.spindle import SpindleModel


def _torque(path: Path) -> tuple[np.ndarray, np.ndarray]:
    cyc, tau = [], []
    for line in path.read_text(encoding="utf-8").splitlines():
        m = json.loads(line)
        if m["kind"] == "torque":
            cyc.append(np.arange(m["first_cycle"], m["first_cycle"] + m["n"]))
            tau.append(np.asarray(m["torque_nm"], dtype=float))
    return np.concatenate(cyc), np.concatenate(tau)


def _holes(path: Path) -> list[dict[str, Any]]:
    return [json.loads(x)["row"] for x in path.read_text(encoding="utf-8").splitlines()
            if '"kind":"hole"' in x]


def _plant(tmp_path: Path, rec: Path, body: str) -> Path:
    m1 = save_spindle_model(SpindleModel(1.01, 8.3e-5, 0.34, j_kgm2=0.0045),
                            tmp_path / "m1.json")
    save_spindle_model(SpindleModel(0.95, 9.0e-5, 0.30, j_kgm2=0.0045), tmp_path / "m2.json")
    assert m1.parent == tmp_path
    p = tmp_path / "plant.toml"
    p.write_text(body.replace("REC", str(rec)), encoding="utf-8")
    return p


PLANT = """
workers = 2
out = "state"

[defaults]
learn-s = 3

[[machine]]
name = "mill-1"
source = "REC"
model = "m1.json"

[[machine]]
name = "mill-2"
source = "REC"
model = "m2.json"
no_anomaly = true

[[machine]]
name = "mill-3"
source = "missing.json"
model = "m1.json"
"""


def test_plant_runs_each_machine_as_its_own_run(tmp_path: Path, wear_run: dict[str, Any],
                                                capsys: pytest.CaptureFixture[str]) -> None:
    plant = _plant(tmp_path, wear_run["path"], PLANT)
    code = main(["edge", "run", "--config", str(plant), "--quiet"])
    out, err = capsys.readouterr()
    # mill-3's file is missing: named, exit 1, and the other two still ran to the end
    assert code == 1
    assert "machine mill-3:" in err and "missing.json" in err
    summary = json.loads(out.strip().splitlines()[-1])
    assert list(summary) == ["mill-1", "mill-2", "mill-3"]
    assert "error" in summary["mill-3"]
    for name, model in (("mill-1", "m1.json"), ("mill-2", "m2.json")):
        assert summary[name]["holes"] == 3 and summary[name]["gaps"] == 0
        alone = tmp_path / f"alone-{name}"
        argv = ["edge", "run", "--source", str(wear_run["path"]), "--model",
                str(tmp_path / model), "--out", str(alone), "--quiet", "--learn-s", "3"]
        if name == "mill-2":
            argv.append("--no-anomaly")
        assert main(argv) == 0
        capsys.readouterr()
        state = tmp_path / "state" / name
        cyc_p, tau_p = _torque(state / "results.jsonl")
        cyc_a, tau_a = _torque(alone / "results.jsonl")
        np.testing.assert_array_equal(cyc_p, cyc_a)
        np.testing.assert_array_equal(tau_p, tau_a)  # bit for bit: same code, same input
        assert _holes(state / "results.jsonl") == _holes(alone / "results.jsonl")
        assert json.loads((state / "status.json").read_text())["state"] == "finished"
    # two models, two machines: different torque, each from its own model
    assert not np.array_equal(_torque(tmp_path / "state/mill-1/results.jsonl")[1],
                              _torque(tmp_path / "state/mill-2/results.jsonl")[1])
    assert main(["edge", "status", "--config", str(plant)]) == 0
    table = capsys.readouterr().out
    assert table.count("finished") == 2 and "mill-3" in table
    assert main(["edge", "status", "--config", str(plant), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["mill-1"]["holes"] == 3 and doc["mill-3"] is None


@pytest.mark.parametrize(("body", "expect"), [
    ("[[machine]]\nname = 'a'\nsource = 'x.json'\nout = 's'\nbogus = 1\n",
     "[[machine]] 'a': unknown option 'bogus'"),
    ("out = 's'\n[[machine]]\nname = 'a'\nsource = 'x.json'\n[[machine]]\nname = 'a'\n"
     "source = 'y.json'\n", "two machines are named 'a'"),
    ("[[machine]]\nname = 'a'\nsource = 'x.json'\nout = 's'\n[[machine]]\nname = 'b'\n"
     "source = 'x.json'\nout = 's'\n", "share the state directory"),
    ("out = 's'\n", "no machines"),
    ("out = 's'\n[[machine]]\nsource = 'x.json'\n", "needs name"),
    ("out = 's'\n[[machine]]\nname = 'a'\n", "has no source"),
    ("out = 's'\n[[machine]]\nname = 'a'\nsource = 'x.json'\nno-holes = 'yes'\n",
     "no-holes = 'yes': give true or false"),
    ("out = 's'\n[[machine]]\nname = 'a'\nsource = 'x.json'\nlearn-s = 'soon'\n",
     "machine 'a': argument --learn-s: invalid float value"),
    ("out = 's'\n[[machine]]\nname = 'a'\nsource = 'x.json'\ndetector = 'magic'\n",
     "invalid choice: 'magic'"),
    ("workers = 0\nout = 's'\n", "workers = 0"),
    ("out = 's'\n[machine\n", "not valid TOML"),
    ("outdir = 's'\n", "unknown top-level key(s) ['outdir']"),
])
def test_bad_plant_file_is_refused_before_start(tmp_path: Path, body: str, expect: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "plant.toml"
    p.write_text(body, encoding="utf-8")
    assert main(["edge", "run", "--config", str(p), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert expect in err and str(p) in err, err
    assert "Traceback" not in err
    assert not (tmp_path / "s").exists()  # nothing started


def test_config_and_single_machine_options_do_not_mix(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["edge", "run", "--config", str(tmp_path / "p.toml"), "--source", "x"]) == 2
    assert "--source there" in capsys.readouterr().err
    assert main(["edge", "run", "--out", str(tmp_path / "o")]) == 2
    assert "give --source" in capsys.readouterr().err
    assert main(["edge", "run", "--config", str(tmp_path / "p.toml")]) == 2
    assert "no such plant file" in capsys.readouterr().err


def test_a_killed_worker_is_restarted_and_sigterm_stops_the_plant(
        tmp_path: Path, wear_run: dict[str, Any]) -> None:
    """kill -9 of a worker process: the supervisor starts it again (its machines resume from
    their state directories, seq continues); SIGTERM to the supervisor stops every machine
    cleanly (state 'finished', exit 0)."""
    body = PLANT.split("[[machine]]\nname = \"mill-3\"")[0].replace(
        "learn-s = 3", "learn-s = 3\nspeed = 1.0")  # real time: still running when killed
    plant = _plant(tmp_path, wear_run["path"], body)
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "cnctwin", "edge", "run", "--config",
                             str(plant), "--quiet"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=env, cwd=tmp_path)
    try:
        status = tmp_path / "state/mill-1/status.json"
        deadline = time.monotonic() + 90
        while not (status.exists() and json.loads(status.read_text())["cycles"] > 500):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "mill-1 did not start"
            time.sleep(0.2)
        workers = subprocess.run(["pgrep", "-P", str(proc.pid), "-f", "spawn_main"],
                                 capture_output=True, text=True).stdout.split()
        assert len(workers) == 2, workers
        seq_before = json.loads((tmp_path / "state/mill-1/seq.json").read_text())["next_seq"]
        os.kill(int(workers[0]), signal.SIGKILL)
        deadline = time.monotonic() + 60
        while True:
            again = subprocess.run(["pgrep", "-P", str(proc.pid), "-f", "spawn_main"],
                                   capture_output=True, text=True).stdout.split()
            if len(again) == 2 and workers[0] not in again:
                break
            assert time.monotonic() < deadline, f"no restart: {again}"
            time.sleep(0.2)
        # at once, while the new worker may still be starting: the supervisor sends it SIGTERM
        # only once it can drain (it reports ready), so it is never killed half-started
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err.decode()
    summary = json.loads(out.decode().strip().splitlines()[-1])
    assert set(summary) == {"mill-1", "mill-2"}
    for name in summary:
        st = json.loads((tmp_path / "state" / name / "status.json").read_text())
        assert st["state"] == "finished"
        seqs = [json.loads(x)["seq"] for x in
                (tmp_path / "state" / name / "results.jsonl").read_text().splitlines()
                if x.strip().endswith("}")]
        assert len(seqs) == len(set(seqs))  # never a repeated number, also across the kill
    seq_after = json.loads((tmp_path / "state/mill-1/seq.json").read_text())["next_seq"]
    assert seq_after > seq_before


def test_a_machine_that_fails_in_the_shared_thread_ends_alone() -> None:
    """Live machines on one connection run in one thread (``run_machines``' pump loop): a
    machine whose pipeline raises is reported with its error and ended; the others are
    served to their end (stand-in runtimes: the loop only needs ``begin``/``process``/
    ``idle``/``end`` and a source with a hub)."""
    import threading
    from types import SimpleNamespace

    from cnctwin.edge.plant import run_machines

    class Hub:
        notify: Any = None
        driven = False

        def take_touched(self) -> set[Any]:
            return set()

        def drive(self) -> None:  # the machines are built: the loop does the socket work
            self.driven = True

        def io(self) -> None:
            assert self.driven

        def socket(self) -> Any:
            return None

        def buffered(self) -> bool:
            return False

    hub = Hub()

    class Runtime:
        def __init__(self, fail: bool) -> None:
            self.source = SimpleNamespace(hub=hub, window_s=0.5, batch_s=0.0,
                                          recorder=SimpleNamespace(_client=object()))
            self.fail = fail
            self.stopping = False
            self.cycles = 0

        def begin(self) -> Any:
            def chunks() -> Any:
                for _ in range(3):
                    yield [0] * 10  # a chunk of 10 cycles
                    yield []  # nothing more for now: an idle chunk
            return chunks()

        def process(self, chunk: list[int]) -> None:
            if self.fail and self.cycles >= 10:
                raise RuntimeError("boom")
            self.cycles += len(chunk)

        def idle(self) -> None:
            pass

        def end(self) -> dict[str, Any]:
            return {"cycles": self.cycles}

        def stop(self) -> None:
            self.stopping = True

        def run(self) -> dict[str, Any]:
            raise AssertionError("a machine on a hub is not run in its own thread")

    reports: list[tuple[str, str, Any]] = []
    run_machines([(n, lambda f=(n == "bad"): Runtime(f)) for n in ("a", "bad", "b")],
                 report=lambda *r: reports.append(r), stop=threading.Event(), tick_s=0.01)
    ends = {r[0]: (r[1], r[2]) for r in reports if r[1] != "started"}
    assert ends == {"a": ("done", {"cycles": 30}), "b": ("done", {"cycles": 30}),
                    "bad": ("error", "internal error: RuntimeError: boom")}


def test_replays_at_full_speed_share_one_thread(tmp_path: Path, wear_recording: Any,
                                               spindle_model: SpindleModel) -> None:
    """Issue 28, the replay plant: machines replaying a file as fast as they can are driven
    from ``run_machines``' own thread, a chunk of each in turn (a thread each spent as much CPU
    on handing the interpreter lock around, futex calls, as on the pipelines: BENCHMARKS.md
    "Replay plant"); a paced replay (``speed``) keeps its thread. Each machine's torque is
    the one its own run gives."""
    import threading

    from cnctwin.edge import EdgeRuntime, JsonLinesSink, ReplaySource, TorqueProcessor
    from cnctwin.edge.plant import run_machines

    ran_alone: list[str] = []

    class Tracked(EdgeRuntime):
        def run(self, **kw: Any) -> dict[str, Any]:
            ran_alone.append(self.name)
            return super().run(**kw)

    def build(name: str, speed: float | None) -> Any:
        def make() -> EdgeRuntime:
            rt = Tracked(ReplaySource(wear_recording, chunk_cycles=250, speed=speed),
                         [TorqueProcessor(spindle_model)],
                         [JsonLinesSink(tmp_path / f"{name}.jsonl")])
            rt.name = name
            return rt
        return make

    names = [f"r{k}" for k in range(6)]
    reports: list[tuple[str, str, Any]] = []
    run_machines([(n, build(n, None)) for n in names] + [("paced", build("paced", 50.0))],
                 report=lambda *r: reports.append(r), stop=threading.Event())
    # run() is a machine's own thread: only the paced one (the others were handed over)
    assert ran_alone == ["paced"]
    ends = {r[0]: r[1] for r in reports if r[1] != "started"}
    assert ends == dict.fromkeys([*names, "paced"], "done")
    alone = tmp_path / "alone.jsonl"
    EdgeRuntime(ReplaySource(wear_recording, chunk_cycles=250),
                [TorqueProcessor(spindle_model)], [JsonLinesSink(alone)]).run()
    ref = _torque(alone)
    for n in [*names, "paced"]:
        got = _torque(tmp_path / f"{n}.jsonl")
        np.testing.assert_array_equal(got[0], ref[0])
        np.testing.assert_array_equal(got[1], ref[1])


def _env_worker(plant_path: str, names: list[str], report_queue: Any, key: str) -> None:
    """A stand-in worker (top level: spawn imports it): reports its BLAS thread setting."""
    report_queue.put(("", "ready", os.getpid()))
    for n in names:
        report_queue.put((n, "done", {"blas": os.environ.get("OPENBLAS_NUM_THREADS"),
                                      "key": key}))


def test_workers_start_with_one_blas_thread(tmp_path: Path, wear_run: dict[str, Any],
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """One worker per core: each starts with OPENBLAS_NUM_THREADS=1 (its BLAS threads would
    only compete for the cores), unless the user set it; the supervisor's own environment
    is left as it was; each worker gets its slot's stable session key."""
    from cnctwin.cli.edge import read_plant_file
    from cnctwin.edge.plant import PlantRunner

    plant = read_plant_file(_plant(tmp_path, wear_run["path"], PLANT))
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    res = PlantRunner(plant, _env_worker, workers=2).run()
    assert {v["blas"] for _, v in res.values()} == {"1"}
    assert len({v["key"] for _, v in res.values()}) == 2  # a key per worker slot
    assert "OPENBLAS_NUM_THREADS" not in os.environ
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")  # the user's choice wins
    res = PlantRunner(plant, _env_worker, workers=2).run()
    assert {v["blas"] for _, v in res.values()} == {"3"}


@pytest.mark.skipif(sys.platform == "win32", reason="no open-file limit to raise on Windows")
def test_a_worker_raises_its_open_file_limit_to_what_its_machines_need() -> None:
    """Linux's usual soft limit of 1024 open files would stop a worker at ~100 machines (9
    files each: the outbox's two segments, results, MQTT socket and wake-up pair,
    the checkpoint's two slots, the status file);
    the worker raises the soft limit to the need, and where the hard limit is lower it says
    what to do. Run in a child process, whose limits are its own."""
    code = """
import resource, sys
from cnctwin.edge.plant import FILES_PER_MACHINE, raise_open_file_limit
soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
resource.setrlimit(resource.RLIMIT_NOFILE, (300, 2000))
assert raise_open_file_limit(20) == ""  # 244 files: within 300, nothing changes
assert resource.getrlimit(resource.RLIMIT_NOFILE) == (300, 2000)
assert raise_open_file_limit(150) == ""
assert resource.getrlimit(resource.RLIMIT_NOFILE) == (150 * FILES_PER_MACHINE + 64, 2000)
msg = raise_open_file_limit(400)  # 3664 files, but at most 2000
assert resource.getrlimit(resource.RLIMIT_NOFILE) == (2000, 2000)
need = 400 * FILES_PER_MACHINE + 64
assert f"{need} open files" in msg and "2000" in msg and "LimitNOFILE" in msg, msg
print("ok")
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr

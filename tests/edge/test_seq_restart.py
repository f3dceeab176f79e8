"""``seq`` is monotonic for a machine across runs and crashes (issue 14, point 1, in part):
a consumer that drops repeats by ``(machine, seq)`` never drops a new result after a restart.
The runtime runs as a real process and is killed with SIGKILL mid-run."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

from cnctwin.edge import save_spindle_model
from cnctwin.spindle import SpindleModel


def _seqs(path: Path) -> list[int]:
    out = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            out.append(int(json.loads(line)["seq"]))
        except json.JSONDecodeError:  # the line a SIGKILL cut short
            continue
    return out


def test_seq_never_repeats_across_a_kill_and_restarts(c4a_file: Path, tmp_path: Path) -> None:
    model = save_spindle_model(SpindleModel.from_parameters("thesis_spinner_840dsl"),
                               tmp_path / "spindle.json")
    out = tmp_path / "state"
    cmd = [sys.executable, "-m", "cnctwin", "edge", "run", "--source", str(c4a_file),
           "--model", str(model), "--out", str(out), "--quiet", "--machine", "m1"]
    # run 1 at real-time pace, killed after 3 s (no clean end, no final seq written)
    proc = subprocess.Popen([*cmd, "--speed", "1"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while not (out / "results.jsonl").exists() or len(_seqs(out / "results.jsonl")) < 20:
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.1)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    first = _seqs(out / "results.jsonl")
    # runs 2 and 3 to the end
    for _ in range(2):
        subprocess.run(cmd, check=True, capture_output=True, timeout=120)
    seqs = _seqs(out / "results.jsonl")
    assert len(seqs) > len(first)
    assert len(seqs) == len(set(seqs)), "a seq was given to two messages"
    assert seqs == sorted(seqs)  # monotonic over the three runs
    assert min(seqs[len(first):]) > max(first)

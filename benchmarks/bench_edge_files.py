"""The edge's per-machine file work, this code beside a baseline in one run.

* ``status.json`` every second per machine: :class:`cnctwin.edge.status_file.StatusFile`
  (a spare inode rewritten in place and renamed over the name) against the temporary file
  renamed over the old one (what the runtime did before; on ext4 that rename allocates and
  starts writing the new file's blocks at once, ``auto_da_alloc``);
* the MQTT outbox as a live plant's MQTT sink uses it: per machine-second one write with the
  chunk's two result messages (torque ~22 kB, status ~1.3 kB: the sizes of
  ``bench_edge_live.py``) and the previous chunk's acknowledged ids
  (``put_many(items, remove=...)``), with this code's outbox
  (:class:`cnctwin.edge.forward_log.ForwardLog`, an append-only log since session 27) and
  with the SQLite ``ForwardQueue`` of ``--baseline-rev`` (``git archive``, loaded from its
  file); ``--sleep-ms`` sleeps between the operations as a plant worker does between a
  machine's chunks (its caches go cold; the sleep's own CPU is measured and subtracted).

Run: ``.venv/bin/python benchmarks/bench_edge_files.py [--baseline-rev fd42202] [--n 3000]
[--sleep-ms 0]``.
CPU time per operation (``time.process_time``), best of 3 rounds; the files in a temporary
directory on the file system of ``--dir`` (default: the system's temporary directory).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from _common import cpu_model, export_rev


def _best_us(fn: Callable[[], None], n: int, sleep_s: float = 0.0) -> float:
    best = float("inf")
    for _ in range(3):
        c0 = time.process_time()
        for _ in range(n):
            if sleep_s:
                time.sleep(sleep_s)
            fn()
        best = min(best, (time.process_time() - c0) / n)
    return best * 1e6


def _status(d: Path, n: int) -> tuple[float, float]:
    from cnctwin.edge.status_file import StatusFile

    data = b'{"cycles": 1234567, "latency_ms": {"p50": 2.0}}' * 40  # ~2 kB, a status's size
    f = StatusFile(d / "a" / "status.json")
    f.path.parent.mkdir()
    old = d / "b" / "status.json"
    old.parent.mkdir()

    def temp_and_rename() -> None:
        tmp = old.with_name("status.json.tmp")
        tmp.write_bytes(data)
        os.replace(tmp, old)

    return _best_us(lambda: f.write(data), n), _best_us(temp_and_rename, n)


def _queue_class(src: Path | None) -> Any:
    if src is None:
        from cnctwin.edge.forward_log import ForwardLog

        return ForwardLog
    spec = importlib.util.spec_from_file_location("baseline_forward",
                                                  src / "cnctwin" / "edge" / "forward.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.ForwardQueue


def _outbox(cls: Any, path: Path, n: int, sleep_s: float) -> float:
    q = cls(path)
    items = [("cnctwin/m/torque", b"x" * 22_000), ("cnctwin/m/status", b"y" * 1300)]
    acked: list[int] = []

    def chunk() -> None:
        nonlocal acked
        acked = q.put_many(items, remove=acked or None)

    us = _best_us(chunk, n, sleep_s)
    q.close()
    return us


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--baseline-rev", default="fd42202", metavar="COMMIT",
                    help="the SQLite outbox of this commit beside this code's")
    ap.add_argument("--sleep-ms", type=float, default=0.0,
                    help="sleep between outbox operations (a plant worker's cold caches)")
    ap.add_argument("--n", type=int, default=3000, help="operations per round")
    ap.add_argument("--dir", type=Path, default=None, help="where the files are written")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        d = Path(tmp)
        status_new, status_old = _status(d, args.n)
        old_src = export_rev(args.baseline_rev, Path(tempfile.mkdtemp(dir=d)))
        sleep_s = args.sleep_ms / 1e3
        idle = _best_us(lambda: None, args.n, sleep_s) if sleep_s else 0.0  # the sleep's CPU
        outbox_new = _outbox(_queue_class(None), d / "outbox", args.n, sleep_s) - idle
        outbox_old = _outbox(_queue_class(old_src), d / "old.sqlite", args.n, sleep_s) - idle
    print(f"machine: {cpu_model()}, {os.cpu_count()} vCPU; python {platform.python_version()};"
          f" {args.n} operations per round, best of 3, CPU time")
    print()
    print("| operation | this code [us] | baseline [us] | baseline |")
    print("|---|---|---|---|")
    print(f"| status.json rewritten (~2 kB) | {status_new:.1f} | {status_old:.1f} | "
          "temporary file renamed over it |")
    print(f"| outbox: a chunk's 2 messages (23 kB) appended, the previous chunk's removed"
          f"{f', {args.sleep_ms:g} ms sleep between' if sleep_s else ''} | {outbox_new:.1f} | "
          f"{outbox_old:.1f} | SQLite ForwardQueue of {args.baseline_rev} |")


if __name__ == "__main__":
    main()

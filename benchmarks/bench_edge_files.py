"""The edge's per-machine file work, this code beside a baseline in one run.

* ``status.json`` every second per machine: :class:`cnctwin.edge.status_file.StatusFile`
  (a spare inode rewritten in place and renamed over the name) against the temporary file
  renamed over the old one (what the runtime did before; on ext4 that rename allocates and
  starts writing the new file's blocks at once, ``auto_da_alloc``);
* the MQTT outbox: one chunk's two result messages appended and removed again
  (``ForwardQueue.put_many`` then ``remove``), with this code's ``ForwardQueue`` and with the
  one of ``--baseline-rev`` (``git archive``, loaded from its file).

Run: ``.venv/bin/python benchmarks/bench_edge_files.py [--baseline-rev f2d0a76] [--n 3000]``.
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


def _best_us(fn: Callable[[], None], n: int) -> float:
    best = float("inf")
    for _ in range(3):
        c0 = time.process_time()
        for _ in range(n):
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
        from cnctwin.edge.forward import ForwardQueue

        return ForwardQueue
    spec = importlib.util.spec_from_file_location("baseline_forward",
                                                  src / "cnctwin" / "edge" / "forward.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.ForwardQueue


def _outbox(cls: Any, path: Path, n: int) -> float:
    q = cls(path)
    items = [("cnctwin/m/torque", b"x" * 3000), ("cnctwin/m/anomaly", b"y" * 400)]

    def chunk() -> None:
        q.remove(q.put_many(items))

    us = _best_us(chunk, n)
    q.close()
    return us


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--baseline-rev", default="f2d0a76", metavar="COMMIT",
                    help="the outbox of this commit beside this code's")
    ap.add_argument("--n", type=int, default=3000, help="operations per round")
    ap.add_argument("--dir", type=Path, default=None, help="where the files are written")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        d = Path(tmp)
        status_new, status_old = _status(d, args.n)
        old_src = export_rev(args.baseline_rev, Path(tempfile.mkdtemp(dir=d)))
        outbox_new = _outbox(_queue_class(None), d / "new.sqlite", args.n)
        outbox_old = _outbox(_queue_class(old_src), d / "old.sqlite", args.n)
    print(f"machine: {cpu_model()}, {os.cpu_count()} vCPU; python {platform.python_version()};"
          f" {args.n} operations per round, best of 3, CPU time")
    print()
    print("| operation | this code [us] | baseline [us] | baseline |")
    print("|---|---|---|---|")
    print(f"| status.json rewritten (~2 kB) | {status_new:.1f} | {status_old:.1f} | "
          "temporary file renamed over it |")
    print(f"| outbox: a chunk's 2 messages appended and removed | {outbox_new:.1f} | "
          f"{outbox_old:.1f} | ForwardQueue of {args.baseline_rev} |")


if __name__ == "__main__":
    main()

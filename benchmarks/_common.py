"""Helpers shared by the benchmark scripts: one core, best-of timing, the machine's name, an
older source tree, a section of BENCHMARKS.md. Scripts import it as ``from _common import
...`` (run from this folder's parent; Python puts the script's folder on ``sys.path``)."""

from __future__ import annotations

import os
import re
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


def pin_one_core() -> str:
    """Pin this process to the lowest CPU it may use; says how (for the report)."""
    if hasattr(os, "sched_setaffinity"):
        cpu = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})
        return f"sched_setaffinity cpu {cpu}"
    return "not pinned"


def best_wall_cpu(fn: Callable[[], Any], repeat: int) -> tuple[float, float]:
    """Best (wall s, CPU s of this process) of ``repeat`` calls of ``fn``."""
    best_w, best_c = float("inf"), float("inf")
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        fn()
        best_w = min(best_w, time.perf_counter() - w0)
        best_c = min(best_c, time.process_time() - c0)
    return best_w, best_c


def cpu_model() -> str:
    """``lscpu``'s model name, or 'unknown'."""
    try:
        txt = subprocess.run(["lscpu"], capture_output=True, text=True, check=False).stdout
    except OSError:
        return "unknown"
    for line in txt.splitlines():
        if line.startswith("Model name"):
            return line.split(":", 1)[1].strip()
    return "unknown"


def export_rev(rev: str, dest: Path) -> Path:
    """``git archive`` the package source of commit ``rev`` into ``dest`` (read-only on the
    repository); returns the ``src`` directory to put on PYTHONPATH."""
    archive = subprocess.run(["git", "-C", str(REPO), "archive", rev, "src"],
                             capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest / "src"


def replace_section(path: Path, title: str, section: str) -> None:
    """Put ``section`` (starting with the ``## title`` line) in place of that section of the
    Markdown file ``path`` (up to the next ``## ``), or append it."""
    text = path.read_text(encoding="utf-8") if path.exists() else "# Benchmarks\n\n"
    pattern = re.compile(re.escape(title) + r"\n.*?(?=\n## |\Z)", re.S)
    body = section.rstrip("\n") + "\n"
    text = pattern.sub(lambda _m: body, text) if pattern.search(text) else (
        text.rstrip("\n") + "\n\n" + body)
    path.write_text(text, encoding="utf-8")

"""``cnctwin demo``: its arguments (the run itself is :func:`cnctwin.cli.demo.run_demo`,
imported when the command runs, so that ``cnctwin --help`` stays fast)."""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``demo`` to the ``cnctwin`` command line.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers; the module adds its commands to them.
    """
    p = sub.add_parser(
        "demo",
        help="simulate the thesis campaign, calibrate, estimate and write the HTML report",
        description="Simulate the air-cut sweep, warm-up and drilling validation, calibrate "
        "the spindle twin (thesis and improved method), print the validation beside thesis "
        "Table 4.1 and write a self-contained HTML report.",
    )
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--quick", action="store_true", help="fewer speeds, shorter runs (< 1 min)")
    p.set_defaults(func=_cmd_demo)


def _cmd_demo(args: argparse.Namespace) -> int:
    from cnctwin.cli.demo import run_demo  # numpy, pandas, matplotlib: only for the demo

    run_demo(args.out, seed=args.seed, quick=args.quick)
    return 0

"""The ``cnctwin`` command line: one subcommand per library verb.

Each module in this package registers its subcommands through ``register(subparsers)``; the
commands themselves stay thin and call the library.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

from cnctwin.exceptions import CnctwinError

__all__ = ["main"]

# Modules that contribute subcommands, in help order. Each has ``register(subparsers)``.
_COMMAND_MODULES: tuple[str, ...] = (
    "cnctwin.cli.io", "cnctwin.cli.opcua", "cnctwin.cli.store", "cnctwin.cli.sim",
    "cnctwin.cli.servo", "cnctwin.cli.calibrate", "cnctwin.cli.optimize", "cnctwin.cli.twin",
    "cnctwin.cli.usecases",
    "cnctwin.cli.demo_command", "cnctwin.cli.edge", "cnctwin.cli.fleet", "cnctwin.cli.web")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every registered subcommand."""
    parser = argparse.ArgumentParser(
        prog="cnctwin",
        description="Edge digital twin for CNC machine tools (SINUMERIK 840D sl class).",
    )
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def _version() -> str:
    from cnctwin import __version__

    return f"cnctwin {__version__}"


_VALUE_OPTIONS = ("--stock",)
"""Options whose value may start with a minus sign (a coordinate list, ``-20,0,-30,...``)."""


def _join_negative_values(argv: Sequence[str]) -> list[str]:
    """``--stock -20,0,...`` -> ``--stock=-20,0,...`` (argparse takes ``-20,..`` for an option)."""
    out: list[str] = []
    it = iter(argv)
    for a in it:
        if a in _VALUE_OPTIONS:
            nxt = next(it, None)
            out.append(a if nxt is None else f"{a}={nxt}")
        else:
            out.append(a)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (2 for bad input, 1 for other failures).

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.

    Returns
    -------
    int
        Exit code: 0 done, 1 failed (also: a service such as the Dask scheduler cannot be
        reached, a job finished only in part), 2 bad input (file, option or value named on
        stderr).
    """
    parser = build_parser()
    args = parser.parse_args(_join_negative_values(sys.argv[1:] if argv is None else argv))
    if not getattr(args, "command", None):
        parser.print_help()
        return 0
    try:
        code = args.func(args)
    except CnctwinError as exc:
        print(f"cnctwin {args.command}: error: {exc}", file=sys.stderr)
        # a service that cannot be reached (a Dask scheduler) is a failure, not bad input
        return 1 if isinstance(exc, ConnectionError) else 2
    except KeyboardInterrupt:
        print(f"cnctwin {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. piped into head: the reader has gone
        return 0
    except Exception as exc:  # the last line of defence: one readable line
        if os.environ.get("CNCTWIN_DEBUG"):
            raise
        print(f"cnctwin {args.command}: internal error: {type(exc).__name__}: {exc} "
              "(a bug: please report it with the command; CNCTWIN_DEBUG=1 shows the "
              "traceback)", file=sys.stderr)
        return 1
    return int(code or 0)

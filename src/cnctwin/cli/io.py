"""Recording subcommands: ``info``, ``convert``, ``ingest``, ``query`` (filled in by issue #2)."""

from __future__ import annotations

import argparse

__all__ = ["register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the recording subcommands to ``sub``."""

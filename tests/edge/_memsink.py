"""An in-memory result sink for the edge tests (the runtime's Sink protocol)."""

from __future__ import annotations

from typing import Any


class MemorySink:
    """Keeps every message the runtime writes, in order."""

    name = "memory"
    needs: tuple[str, ...] = ()  # results only (cnctwin.edge.pipeline.needed_columns)

    def __init__(self) -> None:
        self.messages: list[dict[str, Any]] = []

    def write(self, messages: list[dict[str, Any]], chunk: Any) -> None:
        self.messages.extend(messages)

    def kind(self, kind: str) -> list[dict[str, Any]]:
        """The messages of one kind (``'torque'``, ``'hole'``, ``'alarm'``, ...)."""
        return [m for m in self.messages if m["kind"] == kind]

    def status(self) -> dict[str, Any]:
        return {"n": len(self.messages)}

    def close(self) -> None:
        pass

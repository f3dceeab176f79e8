"""The cnctwin exception tree.

Every error cnctwin raises on purpose derives from :class:`CnctwinError`, so a caller can catch
one class. Members also subclass the matching built-in, so ``except ValueError`` keeps working::

    CnctwinError (Exception)
    ├── FormatError (ValueError)            bad or unreadable input; names file and position
    │   └── TruncatedFileError               the input ends early (truncated JSON, broken zip)
    ├── SignalNotFoundError (KeyError)       a signal, axis or channel is not in the recording
    ├── ConfigError (ValueError)             bad parameter, option or machine description
    │   └── GCodeError                       a part program line that cannot be run; names the line
    ├── IdentificationError (RuntimeError)   the data cannot support an estimate (and says why)
    └── StoreError (RuntimeError)            storage backend failures (DuckDB, PostgreSQL)

Warnings for numerical hazards derive from :class:`CnctwinWarning` (a ``UserWarning``).
"""

from __future__ import annotations

__all__ = [
    "ClusterError",
    "CnctwinError",
    "CnctwinWarning",
    "ConfigError",
    "FormatError",
    "GCodeError",
    "IdentificationError",
    "NotScoredError",
    "SignalNotFoundError",
    "StoreError",
    "TruncatedFileError",
]


class CnctwinError(Exception):
    """Base class of every error raised by cnctwin."""


class CnctwinWarning(UserWarning):
    """Base class of cnctwin warnings (numerical hazards, repaired input)."""


class FormatError(CnctwinError, ValueError):
    """Input that cannot be read as the format it claims to be.

    Parameters
    ----------
    message : str
        What is wrong and, where possible, what to do next.
    path : str, optional
        The file (or stream/topic) the input came from.
    position : str, optional
        Where in the input: ``"line 12"``, ``"byte 4096"``, ``"Payload[3].HFData[7]"``.
    field : str, optional
        The field, column or key concerned.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | None = None,
        position: str | None = None,
        field: str | None = None,
    ) -> None:
        self.path = path
        self.position = position
        self.field = field
        self.message = message
        where = ", ".join(
            part
            for part in (
                str(path) if path else "",
                position or "",
                f"field {field!r}" if field else "",
            )
            if part
        )
        super().__init__(f"{where}: {message}" if where else message)

    def __reduce__(self) -> tuple[object, ...]:  # keep pickling (multiprocessing) working
        args = (type(self), self.message, self.path, self.position, self.field)
        return (_rebuild_format_error, args)


def _rebuild_format_error(
    cls: type[FormatError], message: str, path: str | None, position: str | None, field: str | None
) -> FormatError:
    return cls(message, path=path, position=position, field=field)


class TruncatedFileError(FormatError):
    """The input ends before the format says it should (truncated JSON, broken zip)."""


class SignalNotFoundError(CnctwinError, KeyError):
    """A signal, axis or external channel is not present; the message lists what is."""

    def __str__(self) -> str:  # KeyError quotes its argument; keep the message readable
        return str(self.args[0]) if self.args else ""


class ConfigError(CnctwinError, ValueError):
    """A parameter, option or machine description value is invalid; the message lists valid ones."""


class GCodeError(ConfigError):
    """A part-program line that cannot be interpreted.

    Parameters
    ----------
    message : str
        The reason.
    line : int
        1-based line number in the program.
    text : str, optional
        The offending line.
    """

    def __init__(self, message: str, *, line: int, text: str | None = None) -> None:
        self.line = line
        self.text = text
        self.message = message
        suffix = f": {text.strip()!r}" if text else ""
        super().__init__(f"line {line}{suffix}: {message}")

    def __reduce__(self) -> tuple[object, ...]:
        return (_rebuild_gcode_error, (self.message, self.line, self.text))


def _rebuild_gcode_error(message: str, line: int, text: str | None) -> GCodeError:
    return GCodeError(message, line=line, text=text)


class IdentificationError(CnctwinError, RuntimeError):
    """The data cannot support the requested estimate; the message says why and what is needed."""


class NotScoredError(CnctwinError, ValueError):
    """An analysis cannot judge its input (a needed signal missing or not finite); the
    message says which and why, instead of a score of 0 that looks like "no alarm"."""


class StoreError(CnctwinError, RuntimeError):
    """A storage backend failed or was asked for something it does not hold."""


class ClusterError(CnctwinError, ConnectionError):
    """The Dask scheduler of a fleet job cannot be reached or lost its workers."""

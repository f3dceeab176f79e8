"""Kernels compiled by numba on their first call (numba imports in ~0.5 s: not at import).

A per-chunk step of the edge pipelines made of ten or more NumPy calls on a few hundred
samples costs more in the calls than in the arithmetic, and several times more on a busy
plant worker, where every call starts with cold caches: ``SpeedChangeFlags.update`` took
155 us there against 13 us as one compiled loop (BENCHMARKS.md, session 25). Such steps are
written as a plain-Python loop (the reference, readable and testable without numba) and
called through :func:`lazy_njit`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["lazy_njit"]


class _Lazy:
    """``py`` compiled with ``numba.njit(cache=True, nogil=True)`` at the first call."""

    __slots__ = ("_fn", "py")

    def __init__(self, py: Callable[..., Any]) -> None:
        self.py = py
        self._fn: Callable[..., Any] | None = None

    def __call__(self, *args: Any) -> Any:
        fn = self._fn
        if fn is None:
            import numba

            fn = self._fn = numba.njit(cache=True, nogil=True)(self.py)
        return fn(*args)


def lazy_njit(py: Callable[..., Any]) -> Callable[..., Any]:
    """``py`` as a kernel compiled on its first call (numba's on-disk cache kept).

    Parameters
    ----------
    py : callable
        A function numba's ``njit`` compiles (loops over NumPy arrays and scalars); it
        stays reachable as ``.py`` (tests compare both).

    Returns
    -------
    callable
        Same arguments and results as ``py``.
    """
    return _Lazy(py)

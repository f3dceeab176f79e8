"""The web dashboard: a FastAPI app over a cnctwin store and/or recording files.

::

    from cnctwin.web import create_app
    app = create_app(store_url="/data/cnctwin-store", recordings=["run1.json"])

Run it with ``cnctwin web --store PATH_OR_URL [--recording PATH ...]`` (uvicorn). Pages: the
fleet overview with signal-quality accounting, a recording view with server-side min/max
decimation of the signals, per-hole tables and trends from :mod:`cnctwin.usecases`, and a live
view of an edge run (Server-Sent Events from its ``results.jsonl``). See docs/web.md.

Needs the ``web`` extra (``pip install 'cnctwin[web]'``: FastAPI, uvicorn, plotly for its
bundled ``plotly.min.js``); :mod:`cnctwin.web.decimate` and :mod:`cnctwin.web.quality` need
only numpy.
"""

from __future__ import annotations

from typing import Any

from cnctwin.web.decimate import Envelope, bucket_starts, envelope_decimate
from cnctwin.web.quality import SignalQuality, signal_quality, signal_quality_of

__all__ = [
    "Envelope",
    "SignalQuality",
    "bucket_starts",
    "create_app",
    "envelope_decimate",
    "signal_quality",
    "signal_quality_of",
]


def create_app(**kwargs: Any) -> Any:
    """Build the dashboard app; see :func:`cnctwin.web.app.create_app` (imports FastAPI).

    Parameters
    ----------
    **kwargs
        Options of :func:`cnctwin.web.app.create_app`.

    Returns
    -------
    fastapi.FastAPI
        The application.
    """
    from cnctwin.web.app import create_app as _create

    return _create(**kwargs)

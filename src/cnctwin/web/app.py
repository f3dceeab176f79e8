"""The dashboard application: :func:`create_app` builds a FastAPI app over a store and files.

No global state: everything an app serves hangs off the :class:`Dashboard` made by
:func:`create_app`, so tests and several dashboards in one process do not share anything.

JSON API (every error is ``{"detail": "<what is wrong and what to do>"}``):

=========================================  ===================================================
``GET /api/recordings``                    summaries with signal-quality accounting
``GET /api/machines``                      the fleet: recordings per machine, last activity
``GET /api/recordings/{id}``               one summary plus its signals, units and issues
``GET /api/recordings/{id}/signals/{sig}``  ``?px=&start_s=&end_s=``: min/max envelope
``GET /api/recordings/{id}/holes``         per-hole record (``cnctwin.usecases.holes``)
``GET /api/recordings/{id}/trends``        torque/current trends, wear indicator, temperature,
                                           hole quality
``GET /api/recordings/{id}/anomalies``     ``?detector=``: replay through a detector
``GET /api/machines/{m}/holes``, ``/trends``  the same over all recordings of a machine
``GET /api/live/status``, ``/api/live/stream``  edge-runtime status and its results as SSE
=========================================  ===================================================
"""

from __future__ import annotations

import contextlib
import itertools
import os
import threading
import time
from collections.abc import AsyncIterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pandas as pd
from numpy.typing import NDArray

from cnctwin.exceptions import CnctwinError, ConfigError, SignalNotFoundError, StoreError
from cnctwin.machine import MachineFile
from cnctwin.recording import Recording
from cnctwin.spindle import SpindleModel
from cnctwin.web import analyses, pages
from cnctwin.web.auth import add_token_auth
from cnctwin.web.decimate import envelope_decimate
from cnctwin.web.live import LiveSource, directory_labels
from cnctwin.web.plant import PlantStatusOptions, plant_state
from cnctwin.web.sources import Catalog, Entry

__all__ = ["DERIVED_TORQUE", "Dashboard", "create_app", "plot_payload"]

DERIVED_TORQUE = "twin.cutting_torque_nm"
"""Name of the derived signal: cutting torque of the calibrated spindle twin [Nm]."""

STATIC_DIR = Path(__file__).parent / "static"
MAX_PX = 20_000


def _plotly_js() -> Path:
    """The plotly.js bundle shipped inside the ``plotly`` Python package (served locally)."""
    try:
        import plotly
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ConfigError("the dashboard needs plotly: pip install 'cnctwin[web]'") from exc
    p = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
    if not p.exists():  # pragma: no cover - depends on the plotly build
        raise ConfigError(f"plotly is installed but {p} is missing; reinstall plotly")
    return p


def _swagger_dir() -> Path:
    """Swagger UI's bundle, shipped by the ``fastapi-offline`` package (served locally, no CDN)."""
    try:
        import fastapi_offline
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ConfigError("the dashboard's API page needs fastapi-offline: "
                          "pip install 'cnctwin[web]'") from exc
    return Path(fastapi_offline.__file__).parent / "static"


def plot_payload(time_s: NDArray[np.float64], cycles: NDArray[np.int64],
                 values: NDArray[np.float64], *, px: int, start_s: float | None,
                 end_s: float | None) -> dict[str, Any]:
    """The plot data of one signal in ``[start_s, end_s]``: a min/max envelope per segment.

    The range is split at counter gaps; each gap-free segment gets a share of the ``px``
    buckets proportional to its samples (at least one) and the segments are joined by a
    ``null`` so the plot shows the gap instead of a line across it. A range of up to
    ``2 px`` samples is sent at full resolution (``exact``).

    Parameters
    ----------
    time_s : numpy.ndarray
        Sample times [s from the first cycle].
    cycles : numpy.ndarray
        Cycle counter (gaps split the plot).
    values : numpy.ndarray
        Samples.
    px : int
        Plot width [pixels].
    start_s : float, optional
        Start of the range [s]; default the first sample.
    end_s : float, optional
        End of the range [s]; default the last sample.

    Returns
    -------
    dict
        ``x``, ``y``, ``n_source``, ``n_points``, ``exact``, ``n_gaps``, ``min``, ``max``.
    """
    lo = 0 if start_s is None else int(np.searchsorted(time_s, start_s, side="left"))
    hi = time_s.size if end_s is None else int(np.searchsorted(time_s, end_s, side="right"))
    t, c, v = time_s[lo:hi], cycles[lo:hi], values[lo:hi]
    n = int(t.size)
    # cycles increase strictly: a span of n - 1 means no gap, and the scan can be skipped
    gapless = n < 2 or int(c[-1]) - int(c[0]) == n - 1
    brk = np.empty(0, dtype=np.int64) if gapless else np.flatnonzero(np.diff(c) > 1) + 1
    bounds = [0, *brk.tolist(), n]
    xs: list[NDArray[np.float64]] = []
    ys: list[NDArray[np.float64]] = []
    exact = True
    for a, b in itertools.pairwise(bounds):
        if b <= a:
            continue
        share = max(1, round(px * (b - a) / n))
        env = envelope_decimate(t[a:b], v[a:b], px=share)
        exact &= env.exact
        if xs:  # a null between segments: the gap is not drawn over
            xs.append(np.array([t[a - 1] + 0.5 * (t[a] - t[a - 1])]))
            ys.append(np.array([np.nan]))
        xs.append(env.x)
        ys.append(env.y)
    x = np.concatenate(xs) if xs else np.empty(0)
    y = np.concatenate(ys) if ys else np.empty(0)
    # every bucket's extremes are kept, so the kept points hold the range's min and max
    finite = y[np.isfinite(y)]
    return {"x": x, "y": y, "n_source": n, "n_points": int(x.size), "exact": bool(exact),
            "n_gaps": int(brk.size), "px": px,
            "start_s": float(t[0]) if n else None, "end_s": float(t[-1]) if n else None,
            "min": float(finite.min()) if finite.size else None,
            "max": float(finite.max()) if finite.size else None}


@dataclass
class Dashboard:
    """Everything one dashboard app serves (held in ``app.state.dashboard``)."""

    catalog: Catalog
    model: SpindleModel | None = None
    """A spindle model given for every recording (``model=``), else None."""
    model_source: str = ""
    machine_files: dict[str, MachineFile] = field(default_factory=dict)
    """Machine files by the machine they name (``name``)."""
    lives: dict[str, LiveSource] = field(default_factory=dict)
    title: str = "cnctwin"
    _lock: threading.RLock = field(default_factory=threading.RLock)
    _cache: dict[tuple[str, ...], Any] = field(default_factory=dict)
    _known: tuple[float, set[str]] | None = None

    @property
    def live(self) -> LiveSource | None:
        """The first live source (the live page's default machine), or None."""
        return next(iter(self.lives.values()), None)

    def live_source(self, machine: str | None) -> LiveSource:
        """The live source of ``machine`` (its label), or the first one when None."""
        if not self.lives:
            raise ConfigError("no live source: start the dashboard with --live DIR (the --out "
                              "directory of `cnctwin edge run`) or --plant plant.toml")
        if machine is None:
            return next(iter(self.lives.values()))
        if machine not in self.lives:
            raise ConfigError(f"no live machine {machine!r}; known: {', '.join(self.lives)}")
        return self.lives[machine]

    # ------------------------------------------------------------------ machine files
    def machine_file_for(self, machine: str | None) -> MachineFile | None:
        """The machine file of ``machine``: the one that names it; a single file that names
        no machine of this dashboard is every machine's (a one-machine dashboard whose file
        was named differently); otherwise None (the machine is uncalibrated)."""
        files = self.machine_files
        if machine is not None and machine in files:
            return files[machine]
        if len(files) == 1:
            only = next(iter(files.values()))
            if only.machine.name not in self._known_machines():
                return only
        return None

    def _known_machines(self) -> set[str]:
        """Machine names of the recordings (looked up at most every 5 s)."""
        now = time.monotonic()
        with self._lock:
            if self._known is None or now - self._known[0] > 5.0:
                self._known = (now, {e.machine or "?" for e in self.catalog.entries()
                                     if not e.error})
            return self._known[1]

    def spindle_for(self, machine: str | None) -> tuple[SpindleModel | None, str]:
        """The spindle model for ``machine``'s cutting torque and where it comes from."""
        if self.model is not None:
            return self.model, self.model_source
        mf = self.machine_file_for(machine)
        if mf is not None and mf.is_identified("spindle.kt_nm_per_a"):
            return (SpindleModel.from_machine(mf),
                    f"{mf.path or 'machine file'} (machine file of {mf.machine.name})")
        return None, ""

    def _machine_of(self, ids: Sequence[str]) -> str | None:
        return self.catalog.entry(ids[0]).machine if ids else None

    # ------------------------------------------------------------------ helpers
    def _cached(self, key: tuple[str, ...], make: Any) -> Any:
        with self._lock:
            if key not in self._cache:
                self._cache[key] = make()
                # per-sample results (the torque signal) are as large as a recording: keep as
                # many as the catalog keeps recordings; hole tables and trends are small
                big = [k for k in self._cache if k[0] == "torque"]
                for old in big[: max(0, len(big) - self.catalog.cache_size)]:
                    del self._cache[old]
            return self._cache[key]

    def machines(self) -> list[dict[str, Any]]:
        """The fleet: one row per machine over every recording that opened."""
        rows: dict[str, dict[str, Any]] = {}
        for e in self.catalog.entries():
            if e.error:
                continue
            m = rows.setdefault(e.machine or "?", {
                "machine": e.machine or "?", "n_recordings": 0, "duration_s": 0.0,
                "n_cycles": 0, "n_gaps": 0, "missing_s": 0.0, "partial": 0,
                "first_activity": None, "last_activity": None, "recordings": []})
            if m["n_recordings"] == 0:
                mf = self.machine_file_for(e.machine or "?")
                spindle, _ = self.spindle_for(e.machine or "?")
                m["machine_file"] = str(mf.path or mf.machine.name) if mf is not None else None
                m["calibrated"] = spindle is not None
            m["n_recordings"] += 1
            m["duration_s"] += e.duration_s
            m["n_cycles"] += e.n_cycles
            m["recordings"].append(e.id)
            if e.quality is not None:
                m["n_gaps"] += e.quality.n_gaps
                m["missing_s"] += e.quality.missing_s
                m["partial"] += int(e.quality.partial)
            if e.end_time is not None and (m["last_activity"] is None
                                           or e.end_time > m["last_activity"]):
                m["last_activity"] = e.end_time
            if e.start_time is not None and (m["first_activity"] is None
                                             or e.start_time < m["first_activity"]):
                m["first_activity"] = e.start_time
        return [analyses.jsonable(r) for r in sorted(rows.values(), key=lambda r: r["machine"])]

    def machine_ids(self, machine: str) -> list[str]:
        """Recording ids of one machine (raises naming the machines there are)."""
        ids = [e.id for e in self.catalog.entries() if not e.error and
               (e.machine or "?") == machine]
        if not ids:
            names = sorted({e.machine or "?" for e in self.catalog.entries() if not e.error})
            raise StoreError(f"no machine {machine!r} in this dashboard; machines: "
                             f"{', '.join(names) or 'none'}")
        return ids

    def recordings(self, ids: Sequence[str]) -> list[Recording]:
        """Loaded recordings (cached in the catalog)."""
        return [self.catalog.recording(i) for i in ids]

    def holes(self, ids: Sequence[str]) -> pd.DataFrame:
        """Per-hole record of the recordings ``ids`` (time order), cached."""
        spindle, _ = self.spindle_for(self._machine_of(ids))
        return self._cached(("holes", *ids), lambda: analyses.hole_table(
            self.recordings(ids), model=spindle))

    def holes_payload(self, ids: Sequence[str]) -> dict[str, Any]:
        holes = self.holes(ids)
        spindle, source = self.spindle_for(self._machine_of(ids))
        return {"ids": list(ids), "n_holes": len(holes), "columns": [str(c) for c in holes.columns],
                "rows": analyses.records(holes),
                "spindle_model": str(holes.attrs.get("spindle_model", "")),
                "calibrated": spindle is not None, "model_source": source,
                "thrust_source": str(holes.attrs.get("thrust_source", "")),
                "issues": [str(i) for i in holes.attrs.get("issues", [])]}

    def compare_payload(self, entry_id: str) -> dict[str, Any]:
        """The recording against the machine file's twin (``compare.json`` of the CLI)."""
        machine = self.catalog.entry(entry_id).machine
        found = self.machine_file_for(machine)
        if found is None:
            raise ConfigError(
                f"no machine file for machine {machine!r}: it is uncalibrated here. Start the "
                "dashboard with --machine FILE for it (cnctwin calibrate writes it; its name "
                f"must be {machine!r})" if self.machine_files else
                "no machine file: start the dashboard with --machine FILE (cnctwin calibrate "
                "writes it) to compare recordings with the twin")
        mf = found

        def make() -> dict[str, Any]:
            from cnctwin.compare import compare_recording

            cmp = compare_recording(self.catalog.recording(entry_id), mf)
            doc = cmp.to_dict()
            # the curves of the CLI's compare.html, min/max-decimated to a plot's width
            plots: dict[str, dict[str, Any]] = {}
            for name, a in cmp.axes.items():
                s = a.series
                if "time_s" not in s or not len(s["time_s"]):
                    continue
                t = np.asarray(s["time_s"], dtype=np.float64) - float(s["time_s"][0])
                curves = {"fe_meas_um": s["fe_meas"] * 1e3, "fe_pred_um": s["fe_pred"] * 1e3,
                          "fe_diff_um": (s["fe_meas"] - s["fe_pred"]) * 1e3}
                if "i_meas" in s:
                    curves.update(i_meas_a=s["i_meas"], i_pred_a=s["i_pred"])
                plot: dict[str, Any] = {"spans_s": [
                    [sp["start_s"] - float(s["time_s"][0]), sp["end_s"] - float(s["time_s"][0])]
                    for sp in a.spans]}
                for key, y in curves.items():
                    env = envelope_decimate(t, np.asarray(y, dtype=np.float64), px=1500)
                    plot[key] = {"x": env.x, "y": env.y}
                plots[name] = plot
            return dict(analyses.jsonable({"machine_file": str(mf.path or ""), **doc,
                                           "plots": plots}))

        return dict(self._cached(("compare", entry_id), make))

    def trends_payload(self, ids: Sequence[str]) -> dict[str, Any]:
        holes = self.holes(ids)
        return self._cached(("trends", *ids), lambda: analyses.trends(
            holes, self.recordings(ids)))

    def signal_names(self, entry: Entry) -> list[str]:
        names = list(entry.columns)
        if self.spindle_for(entry.machine)[0] is not None and "CURRENT|SP1" in names:
            names.append(DERIVED_TORQUE)
        return names

    def signal_payload(self, entry_id: str, name: str, *, px: int, start_s: float | None,
                       end_s: float | None) -> dict[str, Any]:
        if not 1 <= px <= MAX_PX:
            raise ConfigError(f"px must be between 1 and {MAX_PX} (the plot width in pixels), "
                              f"not {px}")
        if name == DERIVED_TORQUE:
            machine = self.catalog.entry(entry_id).machine
            spindle, model_source = self.spindle_for(machine)
            if spindle is None:
                raise SignalNotFoundError(
                    f"signal {name!r} needs a calibrated spindle model, and machine "
                    f"{machine!r} has none here: start the dashboard with --machine FILE "
                    "naming it or --model spindle.json (see docs/web.md)")
            rec = self.catalog.recording(entry_id)
            torque, source = self._cached(
                ("torque", entry_id), lambda: analyses.cutting_torque(rec, spindle))
            cycles = rec.cycles
            time_s = rec.time_s
            unit, values = "Nm", torque
            note = f"SpindleModel.cutting_torque ({model_source or 'calibrated model'}; " \
                   f"speed from {source})"
        else:
            sig = self.catalog.signal(entry_id, name)
            cycles, time_s, values, unit, note = (sig.cycles, sig.time_s, sig.values, sig.unit,
                                                  "")
        out = plot_payload(time_s, cycles, values, px=px, start_s=start_s, end_s=end_s)
        out.update({"recording": entry_id, "signal": name, "unit": unit, "note": note,
                    "total_s": float(time_s[-1]) if time_s.size else 0.0})
        return out

    def anomalies_payload(self, ids: Sequence[str], detector: str,
                          learn_s: float | None, px: int) -> dict[str, Any]:
        def make() -> dict[str, Any]:
            res = analyses.anomalies(self.recordings(ids), self.holes(ids), detector=detector,
                                     learn_s=learn_s)
            t = np.asarray(res.pop("score_time_s"), dtype=np.float64)
            s = np.asarray(res.pop("score"), dtype=np.float64)
            env = envelope_decimate(t, s, px=px)
            res.update({"score_x": env.x, "score_y": env.y, "score_exact": env.exact,
                        "n_scored": int(t.size)})
            return res

        key = ("anomalies", detector, str(learn_s), str(px), *ids)
        return self._cached(key, make)


def _json_response_class() -> Any:
    from starlette.responses import Response

    class OrjsonResponse(Response):
        media_type = "application/json"

        def render(self, content: Any) -> bytes:
            return orjson.dumps(content, option=orjson.OPT_SERIALIZE_NUMPY
                                | orjson.OPT_NON_STR_KEYS)

    return OrjsonResponse


def _live_sources(live: Any) -> dict[str, LiveSource]:
    """Label -> live source from one directory, a list of them or a mapping."""
    if live is None:
        return {}
    if isinstance(live, Mapping):
        return {str(k): LiveSource(v) for k, v in live.items()}
    items = [live] if isinstance(live, str | os.PathLike) else list(live)
    return {label: LiveSource(p) for label, p in directory_labels(items).items()}


def create_app(
    *,
    store_url: str | None = None,
    recordings: Sequence[str | os.PathLike[str]] = (),
    model: SpindleModel | str | os.PathLike[str] | None = None,
    machine: MachineFile | str | os.PathLike[str]
    | Sequence[MachineFile | str | os.PathLike[str]] | None = None,
    live: str | os.PathLike[str] | Sequence[str | os.PathLike[str]]
    | Mapping[str, str | os.PathLike[str]] | None = None,
    fleet: str | os.PathLike[str] | None = None,
    title: str = "cnctwin",
    cache_size: int = 4,
    salvage: bool = False,
    token: str | None = None,
) -> Any:
    """Build the dashboard app.

    Parameters
    ----------
    store_url : str, optional
        A cnctwin store: a directory (DuckDB + Parquet) or a ``postgresql://`` URL. It must
        exist (``cnctwin ingest FILE --store URL`` makes one).
    recordings : sequence of path-like
        Recording files (any format ``cnctwin.read_recording`` opens) or directories of them.
    model : SpindleModel or path-like, optional
        Calibrated spindle twin (or its JSON/TOML file, ``cnctwin.edge.save_spindle_model``)
        for the cutting torque; without it the hole torques use the library default
        (thesis parameters, flagged "not calibrated") and no torque signal is offered.
    machine : MachineFile, path-like or a sequence of them, optional
        Machine files (``cnctwin calibrate``), each for the machine it names (its ``name``):
        its calibrated spindle is that machine's torque model where ``model`` is not given,
        and its recordings get a comparison with the twin (``/recordings/ID/compare``,
        ``/api/recordings/ID/compare``). A machine without a file is shown uncalibrated; a
        single file that names no machine of the dashboard is taken for every recording.
    live : path-like, sequence of path-like or mapping, optional
        ``--out`` directory of a ``cnctwin edge run`` (or its ``results.jsonl``) to follow
        on the live page; several (a plant: label -> directory, or a list labelled by the
        directory names) give the plant page ``/plant`` (``GET /api/plant``): a status per
        machine (running, cutting, alarm, stale) with its latest torque, hole and alarm.
    fleet : path-like, optional
        Result directory of the fleet jobs (``cnctwin fleet ... --out DIR``): the fleet page
        ``/fleet`` and ``GET /api/fleet`` rank its machines by alarms, wear, drift and data
        quality.
    title : str, default 'cnctwin'
        Shown in the page header.
    cache_size : int, default 4
        Whole recordings kept in memory.
    salvage : bool, default False
        Read damaged files with ``salvage=True`` (kept, flagged partial).
    token : str, optional
        Access token: every page, asset and API endpoint then answers 401 unless the request
        carries ``Authorization: Bearer TOKEN`` or the cookie the login form (``/login``)
        sets; compared in constant time. ``cnctwin web`` requires it on a non-loopback host.

    Returns
    -------
    fastapi.FastAPI
        ``app.state.dashboard`` holds the :class:`Dashboard`.

    Raises
    ------
    StoreError, ConfigError
        If the store or a path does not exist (the message says what to do).
    """
    try:
        from fastapi import FastAPI, Query, Request
        from fastapi.responses import FileResponse, HTMLResponse, StreamingResponse
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ConfigError("the dashboard needs FastAPI: pip install 'cnctwin[web]'") from exc

    if fleet is not None:
        from cnctwin.fleet.summary import read_fleet_tables

        read_fleet_tables(fleet)  # fails early, naming the directory
    lives = _live_sources(live)
    if store_url is None and not recordings and not lives and fleet is None:
        raise ConfigError("nothing to show: give a store (--store PATH_OR_URL), recording "
                          "files or directories (--recording PATH) and/or an edge run's "
                          "state directory (--live DIR)")
    spindle: SpindleModel | None
    model_source = ""
    files: dict[str, MachineFile] = {}
    if machine is not None:
        from cnctwin.machine import load_machine

        given = [machine] if isinstance(machine, MachineFile | str | os.PathLike) \
            else list(machine)
        for m in given:
            mf = m if isinstance(m, MachineFile) else load_machine(m)
            if mf.machine.name in files:
                raise ConfigError(f"two machine files name machine {mf.machine.name!r}: "
                                  f"{files[mf.machine.name].path} and {mf.path}; give one "
                                  "per machine")
            files[mf.machine.name] = mf
    if model is None or isinstance(model, SpindleModel):
        spindle = model
        model_source = "SpindleModel given" if model is not None else ""
    else:
        from cnctwin.edge.model_file import load_spindle_model

        spindle = load_spindle_model(model)
        model_source = str(model)
    dash = Dashboard(
        catalog=Catalog(store_url=store_url, recordings=recordings, cache_size=cache_size,
                        salvage=salvage),
        model=spindle, model_source=model_source, machine_files=files,
        lives=lives, title=title)
    plotly_js = _plotly_js()
    JsonResponse = _json_response_class()
    @contextlib.asynccontextmanager
    async def lifespan(_: Any) -> AsyncIterator[None]:
        yield
        dash.catalog.close()

    app = FastAPI(title=f"{title} dashboard", default_response_class=JsonResponse,
                  docs_url=None, redoc_url=None, lifespan=lifespan)
    swagger = _swagger_dir()
    app.state.dashboard = dash
    if token is not None:
        add_token_auth(app, token, title)

    @app.exception_handler(CnctwinError)
    async def _cnctwin_error(request: Request, exc: CnctwinError) -> Any:
        status = 404 if isinstance(exc, SignalNotFoundError | StoreError) else 422
        text = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
        return JsonResponse({"detail": str(text)}, status_code=status)

    # ------------------------------------------------------------------ static
    @app.get("/static/plotly.min.js", include_in_schema=False)
    def _plotly() -> Any:
        return FileResponse(plotly_js, media_type="application/javascript",
                            headers={"Cache-Control": "max-age=86400"})

    @app.get("/api/docs", include_in_schema=False)
    def _api_docs() -> Any:
        from fastapi.openapi.docs import get_swagger_ui_html

        # FastAPI's default page loads Swagger UI from a CDN; every asset here is local
        return get_swagger_ui_html(openapi_url="/openapi.json", title=f"{title} API",
                                   swagger_js_url="/static/swagger/swagger-ui-bundle.js",
                                   swagger_css_url="/static/swagger/swagger-ui.css",
                                   swagger_favicon_url="/static/swagger/favicon.png")

    @app.get("/static/swagger/{name}", include_in_schema=False)
    def _swagger(name: str) -> Any:
        files = {"swagger-ui-bundle.js": "application/javascript",
                 "swagger-ui.css": "text/css", "favicon.png": "image/png"}
        if name not in files:
            raise StoreError(f"no static file swagger/{name!r}")
        return FileResponse(swagger / name, media_type=files[name],
                            headers={"Cache-Control": "max-age=86400"})

    static_files = {p.name for p in STATIC_DIR.iterdir() if p.is_file()}

    @app.get("/static/{name}", include_in_schema=False)
    def _static(name: str) -> Any:
        if name not in static_files:  # (a name too long for the file system is a 404 too)
            raise StoreError(f"no static file {name[:80]!r}")
        p = STATIC_DIR / name
        media = {".js": "application/javascript", ".css": "text/css"}.get(p.suffix)
        return FileResponse(p, media_type=media)

    # ------------------------------------------------------------------ pages
    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def _overview() -> Any:
        return HTMLResponse(pages.overview_page(dash.title, dash.machines(),
                                                dash.catalog.entries(), live=dash.live is not None,
                                                store_url=dash.catalog.store_url,
                                                plant=plant_state(dash.lives)))

    @app.get("/plant", response_class=HTMLResponse, include_in_schema=False)
    def _plant_page() -> Any:
        return HTMLResponse(pages.plant_page(dash.title, plant_state(dash.lives)))

    @app.get("/plant/tiles", response_class=HTMLResponse, include_in_schema=False)
    def _plant_tiles() -> Any:
        return HTMLResponse(pages.plant_tiles(plant_state(dash.lives)))

    @app.get("/api/plant")
    def api_plant(stale_s: float = 10.0, alarm_hold_s: float = 60.0) -> Any:
        """Status per machine (running, cutting, alarm, stale, finished, waiting) with its
        latest torque, hole and alarm, from each edge runtime's state directory."""
        opt = PlantStatusOptions(stale_s=stale_s, alarm_hold_s=alarm_hold_s)
        return JsonResponse(plant_state(dash.lives, options=opt))

    @app.get("/recordings/{entry_id}", response_class=HTMLResponse, include_in_schema=False)
    def _recording_page(entry_id: str) -> Any:
        e = dash.catalog.entry(entry_id)
        return HTMLResponse(pages.recording_page(
            dash.title, e, dash.signal_names(e),
            calibrated=dash.spindle_for(e.machine)[0] is not None,
            twin=dash.machine_file_for(e.machine) is not None))

    @app.get("/machines/{machine}", response_class=HTMLResponse, include_in_schema=False)
    def _machine_page(machine: str) -> Any:
        ids = dash.machine_ids(machine)
        return HTMLResponse(pages.machine_page(dash.title, machine,
                                               [dash.catalog.entry(i) for i in ids],
                                               calibrated=dash.spindle_for(machine)[0]
                                               is not None))

    @app.get("/recordings/{entry_id}/compare", response_class=HTMLResponse,
             include_in_schema=False)
    def _compare_page(entry_id: str) -> Any:
        e = dash.catalog.entry(entry_id)
        return HTMLResponse(pages.compare_page(dash.title, e, dash.compare_payload(entry_id)))

    def _fleet_rows(sort: str) -> tuple[list[dict[str, Any]], list[str]]:
        from cnctwin.fleet.summary import fleet_summary, read_fleet_tables

        if fleet is None:
            return [], []
        tables = read_fleet_tables(fleet)  # read per request: a rerun job shows at once
        table = fleet_summary(tables, sort=sort)
        rows = [{str(k): (None if isinstance(v, float) and v != v else v)
                 for k, v in r.items()} for r in table.to_dict("records")]
        return rows, sorted(tables)

    @app.get("/fleet", response_class=HTMLResponse, include_in_schema=False)
    def _fleet_page(sort: str = "alarms") -> Any:
        rows, tables = _fleet_rows(sort)
        return HTMLResponse(pages.fleet_page(dash.title, rows, sort=sort, tables=tables,
                                             source=str(fleet) if fleet is not None else None))

    @app.get("/api/fleet")
    def api_fleet(sort: str = "alarms") -> Any:
        """Machines of the fleet results ranked (``sort``: alarms, wear, drift, quality)."""
        rows, tables = _fleet_rows(sort)
        return JsonResponse({"source": str(fleet) if fleet is not None else None,
                             "tables": tables, "sort": sort, "machines": rows})

    @app.get("/live", response_class=HTMLResponse, include_in_schema=False)
    def _live_page(machine: str | None = None) -> Any:
        if not dash.lives:
            return HTMLResponse(pages.live_page(dash.title, None))
        src = dash.live_source(machine)
        label = next(k for k, v in dash.lives.items() if v is src)
        return HTMLResponse(pages.live_page(dash.title, str(src.results), machine=label,
                                            machines=list(dash.lives)))

    # ------------------------------------------------------------------ API
    @app.get("/api/recordings")
    def api_recordings() -> Any:
        return JsonResponse([e.to_dict() for e in dash.catalog.entries()])

    @app.get("/api/machines")
    def api_machines() -> Any:
        return JsonResponse(dash.machines())

    @app.get("/api/recordings/{entry_id}")
    def api_recording(entry_id: str) -> Any:
        e = dash.catalog.entry(entry_id)
        d = e.to_dict()
        d["signals"] = dash.signal_names(e)
        calibrated = dash.spindle_for(e.machine)[0] is not None
        d["units"] = {**e.units, **({DERIVED_TORQUE: "Nm"} if calibrated else {})}
        d["calibrated"] = calibrated
        return JsonResponse(analyses.jsonable(d))

    @app.get("/api/recordings/{entry_id}/signals/{name}")
    def api_signal(entry_id: str, name: str, px: int = Query(1500),
                   start_s: float | None = None, end_s: float | None = None) -> Any:
        return JsonResponse(dash.signal_payload(entry_id, name, px=px, start_s=start_s,
                                                end_s=end_s))

    @app.get("/api/recordings/{entry_id}/holes")
    def api_holes(entry_id: str) -> Any:
        dash.catalog.entry(entry_id)
        return JsonResponse(dash.holes_payload([entry_id]))

    @app.get("/api/recordings/{entry_id}/trends")
    def api_trends(entry_id: str) -> Any:
        dash.catalog.entry(entry_id)
        return JsonResponse(dash.trends_payload([entry_id]))

    @app.get("/api/recordings/{entry_id}/compare")
    def api_compare(entry_id: str) -> Any:
        dash.catalog.entry(entry_id)
        return JsonResponse(dash.compare_payload(entry_id))

    @app.get("/api/recordings/{entry_id}/anomalies")
    def api_anomalies(entry_id: str, detector: str = "physics",
                      learn_s: float | None = None, px: int = 1500) -> Any:
        dash.catalog.entry(entry_id)
        return JsonResponse(dash.anomalies_payload([entry_id], detector, learn_s, px))

    @app.get("/api/machines/{machine}/holes")
    def api_machine_holes(machine: str) -> Any:
        return JsonResponse(dash.holes_payload(dash.machine_ids(machine)))

    @app.get("/api/machines/{machine}/trends")
    def api_machine_trends(machine: str) -> Any:
        return JsonResponse(dash.trends_payload(dash.machine_ids(machine)))

    @app.get("/api/live/status")
    def api_live_status(machine: str | None = None) -> Any:
        return JsonResponse(dash.live_source(machine).status())

    @app.get("/api/live/stream")
    async def api_live_stream(from_start: bool = False, limit: int | None = None,
                              kinds: str | None = None, machine: str | None = None,
                              until_finished: bool = False) -> Any:
        live = dash.live_source(machine)
        wanted = {k.strip() for k in kinds.split(",")} if kinds else None
        gen = live.events(from_start=from_start, limit=limit, kinds=wanted,
                          until_finished=until_finished)
        return StreamingResponse(gen, media_type="text/event-stream",
                                 headers={"Cache-Control": "no-cache",
                                          "X-Accel-Buffering": "no"})

    @app.get("/healthz", include_in_schema=False)
    def _health() -> Any:
        return JsonResponse({"ok": True, "recordings": len(dash.catalog.entries())})

    return app

"""``cnctwin web``: serve the dashboard (FastAPI app of :mod:`cnctwin.web`, uvicorn).

``cnctwin web --store PATH_OR_URL [--recording PATH ...] [--model spindle.json] [--live DIR]
[--host 127.0.0.1 --port 8050]``
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cnctwin.exceptions import ConfigError

__all__ = ["register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``web`` to the ``cnctwin`` command line."""
    p = sub.add_parser(
        "web", help="serve the dashboard in a browser (fleet, signals, holes, live edge run)",
        description="Serve the web dashboard on HOST:PORT over a cnctwin store and/or recording "
        "files. Every asset (plotly.js included) is served locally: no internet needed.")
    p.add_argument("--store", metavar="PATH_OR_URL",
                   help="cnctwin store: directory (DuckDB+Parquet) or postgresql:// URL")
    p.add_argument("--recording", action="append", type=Path, default=[], metavar="PATH",
                   help="recording file or directory of recordings (repeatable)")
    p.add_argument("--model", type=Path, metavar="FILE",
                   help="calibrated spindle model (JSON/TOML, cnctwin.edge.save_spindle_model) "
                   "for the cutting torque")
    p.add_argument("--machine", type=Path, metavar="FILE",
                   help="machine file (cnctwin calibrate): its calibrated spindle for the "
                   "cutting torque and the twin comparison of every recording")
    p.add_argument("--live", type=Path, metavar="DIR",
                   help="--out directory of `cnctwin edge run` to follow on the live page")
    p.add_argument("--salvage", action="store_true",
                   help="read damaged recordings with salvage=True (kept, flagged partial)")
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (127.0.0.1)")
    p.add_argument("--port", type=int, default=8050, help="port (8050)")
    p.set_defaults(func=_cmd_web)


def _cmd_web(args: argparse.Namespace) -> int:
    if args.store is None and not args.recording and args.live is None:
        raise ConfigError("give --store PATH_OR_URL and/or --recording PATH (a file or a "
                          "directory of recordings) and/or --live DIR (`cnctwin edge run "
                          "--out DIR`); `cnctwin ingest FILE --store PATH` fills a store")
    if args.store is not None and "://" not in args.store and not Path(args.store).exists():
        raise ConfigError(f"store path {args.store} does not exist; create it with `cnctwin "
                          f"ingest FILE... --store {args.store}` or check the path")
    if args.model is not None and not args.model.exists():
        raise ConfigError(f"model file {args.model} does not exist; write one with "
                          "cnctwin.edge.save_spindle_model (docs/edge.md)")
    try:
        import uvicorn
    except ImportError:
        raise ConfigError("cnctwin web needs the web extra: pip install 'cnctwin[web]'") from None
    from cnctwin.web.app import create_app

    machine = None
    if args.machine is not None:
        from cnctwin.machine import load_machine

        machine = load_machine(args.machine)
    app = create_app(store_url=args.store, recordings=args.recording, model=args.model,
                     machine=machine, live=args.live, salvage=args.salvage)
    print(f"cnctwin web: serving on http://{args.host}:{args.port}/ (Ctrl-C stops)", flush=True)
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning")
    return 0

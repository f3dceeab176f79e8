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
    """Add ``web`` to the ``cnctwin`` command line.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers; the module adds its commands to them.
    """
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
    p.add_argument("--machine", type=Path, action="append", default=[], metavar="FILE",
                   help="machine file (cnctwin calibrate) for the machine it names: its "
                   "calibrated spindle for the cutting torque and the twin comparison of that "
                   "machine's recordings (repeatable: one per machine of a fleet store; a "
                   "machine without one is shown uncalibrated)")
    p.add_argument("--live", type=Path, action="append", default=[], metavar="DIR",
                   help="--out directory of `cnctwin edge run` to follow (repeatable: the "
                   "plant page /plant shows a status tile per machine)")
    p.add_argument("--plant", type=Path, metavar="FILE",
                   help="plant file of `cnctwin edge run --config`: follow every machine's "
                   "state directory (plant page /plant, live page per machine)")
    p.add_argument("--fleet", type=Path, metavar="DIR",
                   help="result directory of `cnctwin fleet ... --out DIR`: the fleet page "
                   "(/fleet) ranks its machines by alarms, wear, drift and data quality")
    p.add_argument("--salvage", action="store_true",
                   help="read damaged recordings with salvage=True (kept, flagged partial)")
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (127.0.0.1)")
    p.add_argument("--port", type=int, default=8050, help="port (8050)")
    p.add_argument("--token-file", type=Path, metavar="FILE",
                   help="file holding the access token (or CNCTWIN_WEB_TOKEN); required on a "
                   "non-loopback --host: every page and API endpoint then needs it "
                   "(Authorization: Bearer TOKEN, or the /login form)")
    p.add_argument("--insecure", action="store_true",
                   help="serve a non-loopback --host without a token (not recommended)")
    p.set_defaults(func=_cmd_web)


def _cmd_web(args: argparse.Namespace) -> int:
    from cnctwin.web.live import directory_labels

    lives = directory_labels(args.live)
    if args.plant is not None:
        from cnctwin.cli.edge import read_plant_file

        for m in read_plant_file(args.plant).machines:
            lives[m.name] = m.out
            m.out.mkdir(parents=True, exist_ok=True)  # the runtime may start after the page
    if args.store is None and not args.recording and not lives and args.fleet is None:
        raise ConfigError("give --store PATH_OR_URL and/or --recording PATH (a file or a "
                          "directory of recordings) and/or --live DIR (`cnctwin edge run "
                          "--out DIR`) or --plant plant.toml; `cnctwin ingest FILE --store "
                          "PATH` fills a store")
    if args.store is not None and "://" not in args.store and not Path(args.store).exists():
        raise ConfigError(f"store path {args.store} does not exist; create it with `cnctwin "
                          f"ingest FILE... --store {args.store}` or check the path")
    if args.model is not None and not args.model.exists():
        raise ConfigError(f"model file {args.model} does not exist; write one with "
                          "cnctwin.edge.save_spindle_model (docs/edge.md)")
    token = _token(args)
    from cnctwin.edge.listen import check_bindable, is_loopback

    if token is None and not is_loopback(args.host) and not args.insecure:
        raise ConfigError(f"--host {args.host} faces the network: give an access token "
                          "(--token-file FILE or CNCTWIN_WEB_TOKEN), or --insecure to serve "
                          "it to anyone")
    if not 1 <= args.port <= 65535:
        raise ConfigError(f"--port {args.port} is not a TCP port; give 1 ... 65535 (default 8050)")
    check_bindable(args.host, args.port, service="the dashboard", option="--port")
    try:
        import uvicorn
    except ImportError:
        raise ConfigError("cnctwin web needs the web extra: pip install 'cnctwin[web]'") from None
    from cnctwin.web.app import create_app

    machine = None
    if args.machine:
        from cnctwin.machine import load_machine

        machine = [load_machine(f) for f in args.machine]
    app = create_app(store_url=args.store, recordings=args.recording, model=args.model,
                     machine=machine, live=lives or None, fleet=args.fleet, salvage=args.salvage,
                     token=token)
    print(f"cnctwin web: serving on http://{args.host}:{args.port}/ (Ctrl-C stops)", flush=True)
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning")
    return 0


def _token(args: argparse.Namespace) -> str | None:
    """The access token from --token-file or CNCTWIN_WEB_TOKEN (never the command line)."""
    import os

    if args.token_file is not None:
        try:
            text = args.token_file.read_text(encoding="utf-8").strip()
        except OSError as exc:
            raise ConfigError(f"--token-file {args.token_file}: {exc.strerror or exc}") from None
        if not text:
            raise ConfigError(f"--token-file {args.token_file} is empty")
        return text
    env = os.environ.get("CNCTWIN_WEB_TOKEN", "").strip()
    return env or None

"""Edge subcommands: ``edge run`` (the streaming runtime) and ``edge status``.

Examples::

    cnctwin edge run --source run1.json --model spindle.json --out state/ --speed 10
    cnctwin edge run --source mqtt://ie-databus:1883/ie/m/j/simatic/v1/nck1/dp \\
        --name-map map.json --model spindle.json --out /var/lib/cnctwin \\
        --publish mqtt://broker:1883/cnctwin
    cnctwin edge status /var/lib/cnctwin
    cnctwin edge run --config plant.toml          # many machines (docs/edge.md)
    cnctwin edge status --config plant.toml
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cnctwin.exceptions import ConfigError

__all__ = ["register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``edge run`` and ``edge status`` to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers; the module adds its commands to them.
    """
    p = sub.add_parser("edge", help="streaming runtime: live Databus/MQTT or a replayed "
                       "recording in, cutting torque, holes and alarms out",
                       description="The edge runtime (docs/edge.md).")
    esub = p.add_subparsers(dest="edge_command", metavar="ACTION")
    r = esub.add_parser("run", help="run the runtime next to a machine or on a file",
                        description="Source -> torque, holes, anomalies -> JSON lines in OUT, "
                        "optional MQTT publish (store-and-forward) and store.")
    r.add_argument("--config", type=Path, metavar="PLANT.toml",
                   help="run every machine of this plant file in one process group (one "
                   "worker process per core; docs/edge.md \"Many machines\"); the other "
                   "options then come from the file")
    r.add_argument("--workers", type=int, metavar="N",
                   help="with --config: worker processes (default the file's, else the cores)")
    _add_run_options(r)
    r.add_argument("--quiet", action="store_true", help="no live summary")
    r.set_defaults(func=_run)
    s = esub.add_parser("status", help="show the status a runtime wrote into its state dir")
    s.add_argument("dir", type=Path, metavar="DIR", nargs="?",
                   help="the --out directory of `edge run`")
    s.add_argument("--config", type=Path, metavar="PLANT.toml",
                   help="every machine of this plant file, one row each")
    s.add_argument("--json", action="store_true", help="print the raw status.json")
    s.set_defaults(func=_status)
    u = esub.add_parser("opcua-user", help="add or replace a user of the OPC UA server",
                        description="Append NAME with a salted PBKDF2 hash of the password to "
                        "the users file of --opcua-users. The password is read from "
                        "CNCTWIN_OPCUA_PASSWORD or standard input, never the command line.")
    u.add_argument("name", metavar="NAME", help="user name")
    u.add_argument("--users", type=Path, required=True, metavar="FILE", help="users file")
    u.set_defaults(func=_opcua_user)

    def _help(args: argparse.Namespace) -> int:
        p.print_help()
        return 0

    p.set_defaults(func=_help)


def _add_run_options(r: argparse.ArgumentParser) -> None:
    """The options of one machine's runtime (the command line and a plant file's tables)."""
    r.add_argument("--source", metavar="URL|FILE",
                   help="mqtt://host:port/<databus metadata topic> or a recording file")
    r.add_argument("--model", type=Path, metavar="FILE",
                   help="calibrated spindle model (.json/.toml, cnctwin.edge.save_spindle_model); "
                   "not needed with --machine FILE.toml")
    r.add_argument("--out", type=Path, metavar="DIR",
                   help="state directory: results.jsonl, status.json, outbox/")
    r.add_argument("--publish", metavar="URL",
                   help="mqtt://host:port/<topic prefix> for results (default prefix cnctwin)")
    r.add_argument("--store", metavar="URL", help="also append results to this store")
    r.add_argument("--rotate-mb", type=float, default=256.0, metavar="MB",
                   help="rotate OUT/results.jsonl at this size [MB] (256; the full path writes "
                   "~2.2 GB per machine-day)")
    r.add_argument("--keep-files", type=int, default=40, metavar="N",
                   help="keep this many rotated results files, delete older ones (40, about "
                   "10 GB and 4.5 machine-days; deletions are counted in status.json)")
    r.add_argument("--tls-ca", type=Path, metavar="FILE",
                   help="MQTT over TLS: the CA certificate (PEM) of the broker(s)")
    r.add_argument("--tls-cert", type=Path, metavar="FILE",
                   help="MQTT TLS client certificate (PEM), with --tls-key")
    r.add_argument("--tls-key", type=Path, metavar="FILE", help="its private key (PEM)")
    r.add_argument("--mqtt-user", metavar="NAME", help="MQTT user name")
    r.add_argument("--password-file", type=Path, metavar="FILE",
                   help="file holding the MQTT password (or CNCTWIN_MQTT_PASSWORD), or the "
                   "OPC UA source's with --user (or CNCTWIN_OPCUA_PASSWORD); never on the "
                   "command line")
    r.add_argument("--mqtt-client-id", metavar="ID",
                   help="MQTT client id of the live source (default cnctwin-edge-<machine>): "
                   "the key of its persistent session")
    r.add_argument("--session-expiry-s", type=int, default=86_400, metavar="S",
                   help="MQTT 5 session expiry of the live source [s]: the broker keeps what "
                   "arrives while the runtime is down for this long (86400; 0 = clean session, "
                   "nothing kept)")
    r.add_argument("--opcua", metavar="URL",
                   help="serve the results over OPC UA at this endpoint, e.g. "
                   "opc.tcp://0.0.0.0:4840/cnctwin (extra 'opcua')")
    r.add_argument("--opcua-insecure", action="store_true",
                   help="allow NoSecurity and anonymous OPC UA clients (the one explicit "
                   "switch; default: Basic256Sha256 Sign/SignAndEncrypt and --opcua-users)")
    r.add_argument("--opcua-cert", type=Path, metavar="FILE",
                   help="OPC UA server certificate (DER; generated, self-signed, when absent; "
                   "default OUT/opcua-cert.der)")
    r.add_argument("--opcua-key", type=Path, metavar="FILE",
                   help="its private key (PEM; default OUT/opcua-key.pem)")
    r.add_argument("--opcua-users", type=Path, metavar="FILE",
                   help="users file (name:hash lines; 'cnctwin edge opcua-user NAME --users "
                   "FILE' adds one)")
    r.add_argument("--opcua-trust", type=Path, metavar="DIR",
                   help="client-certificate trust list of --opcua: DIR/trusted/ holds the "
                   "clients let in; an unknown certificate is refused and written to "
                   "DIR/rejected/ for approval (default OUT/opcua-pki)")
    r.add_argument("--opcua-trust-any", action="store_true",
                   help="accept any client certificate (users still log in); the default "
                   "refuses certificates not in --opcua-trust")
    r.add_argument("--opcua-publish-hz", type=float, default=10.0,
                   help="OPC UA publish rate of the decimated 500 Hz values [Hz]")
    r.add_argument("--nodes", type=Path, metavar="FILE",
                   help="with --source opc.tcp://HOST:PORT: the node file of the control's "
                   "OPC UA variables (docs/opcua-client.md)")
    from cnctwin.cli.opcua import add_client_options

    add_client_options(r, password_file=False)  # the password: --password-file as for MQTT
    r.add_argument("--mtconnect", metavar="URL",
                   help="serve an MTConnect agent (/probe, /current, /sample) at "
                   "http://HOST:PORT while the runtime runs (docs/mtconnect.md)")
    r.add_argument("--mtconnect-buffer", type=int, default=131_072, metavar="N",
                   help="observations in the agent's circular buffer (default 131072)")
    r.add_argument("--mtconnect-sample-hz", type=float, default=10.0, metavar="HZ",
                   help="rate of the drive-signal samples in MTConnect (default 10 Hz)")
    r.add_argument("--mtconnect-token-file", type=Path, metavar="FILE",
                   help="access token for the agent (required on a non-loopback host; or "
                   "CNCTWIN_MTCONNECT_TOKEN)")
    r.add_argument("--mtconnect-insecure", action="store_true",
                   help="serve the agent on a non-loopback host without a token")
    r.add_argument("--shdr", metavar="URL",
                   help="serve an SHDR adapter at tcp://HOST:PORT for an MTConnect agent "
                   "(cppagent) to read")
    r.add_argument("--shdr-insecure", action="store_true",
                   help="listen for SHDR on a non-loopback host (SHDR has no authentication)")
    r.add_argument("--speed", type=float, default=0.0,
                   help="replay pace: 1 = real time, N = N x, 0 = as fast as possible")
    r.add_argument("--chunk-cycles", type=int, default=50, help="cycles per chunk (replay)")
    r.add_argument("--machine", default="", metavar="NAME|FILE.toml",
                   help="the machine file (cnctwin calibrate; its name and calibrated spindle "
                   "are used) or a machine name for the topics and the store")
    r.add_argument("--name-map", type=Path, metavar="FILE",
                   help="JSON {datapoint name: column} for the Databus (CURRENT|SP1, "
                   "CMD_SPEED|SP1, DES_POS|Z1, ..., CYCLE)")
    r.add_argument("--no-holes", action="store_true", help="skip the per-hole record")
    r.add_argument("--no-twin", action="store_true",
                   help="with --machine FILE.toml: skip the live comparison with the twin")
    r.add_argument("--twin-window-s", type=float, default=30.0, metavar="S",
                   help="window of the live twin comparison ('twin' results) [s] (30)")
    r.add_argument("--no-anomaly", action="store_true", help="skip the anomaly detector")
    r.add_argument("--detector", choices=("physics", "tapping", "spectral", "adaptive",
                                          "physics-torque"), default="physics",
                   help="anomaly detector (cnctwin.usecases.anomaly): current against the twin, "
                   "loose tap on extraction, chatter band power; adaptive: wear-adaptive "
                   "torque band around the teach-in profile of the first --learn-holes holes; "
                   "physics-torque: the same around the Kienzle torque, from the first hole "
                   "(no teach-in). Both need the hole processor (not --no-holes)")
    r.add_argument("--learn-s", type=float, default=10.0,
                   help="teach-in time of the anomaly detector [s] (physics, tapping, spectral)")
    r.add_argument("--learn-holes", type=int, default=6,
                   help="teach-in holes of --detector adaptive (6)")
    r.add_argument("--material", default="aisi1045",
                   help="workpiece material: Kienzle law for physics-torque; with --adaptive "
                   "and --stock its milling coefficients (the machine file's calibrated one "
                   "first) give the controller's edge torque (aisi1045, grey_cast_iron, "
                   "al7050, a material file)")
    r.add_argument("--adaptive", type=Path, metavar="ADAPTIVE.toml",
                   help="adaptive feed: per tool a target cutting torque (or teach-in); the "
                   "requested feed override goes on the results stream (kind override); "
                   "docs/adaptive.md")
    r.add_argument("--stock", metavar="X0,Y0,Z0,X1,Y1,Z1",
                   help="with --adaptive and --tools: the raw part [mm]; the recorded tool "
                   "positions through its Z-map tell a breakage (torque falls to air while the "
                   "model expects a cut) from a tool leaving the part")
    r.add_argument("--interval-s", type=float, default=0.1,
                   help="with --source opc.tcp://...: the server's interval between values "
                   "(default 0.1 s; a live simulator says its own in its node file)")
    r.add_argument("--tools", type=Path, metavar="TOOLS.toml",
                   help="tool table ([tools.N] with kind, diameter_mm, ...): a plunge of an "
                   "end mill outside a drilling cycle is not counted as a hole; each hole "
                   "gives its tool's life (tool_life: holes used, and with life_holes or "
                   "wear_limit_um + wear_um_per_increase the remaining life), published as "
                   "OPC 40501 Tools/Prognoses and MTConnect CuttingTool assets")
    r.add_argument("--drill-mm", type=float, default=8.5,
                   help="drill diameter for physics-torque [mm] (8.5)")
    r.add_argument("--point-angle-deg", type=float, default=140.0,
                   help="drill point angle for physics-torque [deg] (140)")
    r.add_argument("--checkpoint-s", type=float, default=10.0, metavar="S",
                   help="stream time between checkpoints of the processors' state in OUT "
                   "(a crashed run resumes from it; 10)")
    r.add_argument("--status-s", type=float, default=1.0, metavar="S",
                   help="wall time between updates of status.json and status messages [s] "
                   "(at most 5: the dashboard calls a machine stale after 10 s without one; "
                   "1)")
    r.add_argument("--max-queue", type=int, default=200_000,
                   help="store-and-forward bound [messages]")
    r.add_argument("--idle-timeout-s", type=float, default=None,
                   help="live source: stop after this long without data [s] (an OPC UA source "
                   "counts from its first value: it waits for the program to start)")
    r.add_argument("--batch-s", type=float, default=0.0, metavar="S",
                   help="live Databus machine of a plant (edge run --config): process its "
                   "messages at most every S seconds, what arrived meanwhile as one chunk "
                   "(the work per chunk is paid once per batch; up to S more latency; 0)")


class _OptionParser(argparse.ArgumentParser):
    """An ``edge run`` parser whose errors are exceptions (a plant file's machine tables)."""

    def error(self, message: str) -> Any:
        raise ConfigError(message)


def _machine_parser() -> argparse.ArgumentParser:
    mp_ = _OptionParser(prog="cnctwin edge run", add_help=False)
    _add_run_options(mp_)
    return mp_


_NOT_IN_PLANT = {"help"}


def read_plant_file(path: Path) -> Any:
    """A plant file read and every machine's ``edge run`` options checked.

    Parameters
    ----------
    path : pathlib.Path
        The plant TOML file.

    Returns
    -------
    cnctwin.edge.plant.PlantFile
    """
    from cnctwin.edge.plant import read_plant

    parser = _machine_parser()
    names = [o[2:] for a in parser._actions for o in a.option_strings if o.startswith("--")]
    paths = [o[2:] for a in parser._actions for o in a.option_strings
             if o.startswith("--") and a.type is Path]
    plant = read_plant(path, options=[n for n in names if n not in _NOT_IN_PLANT],
                       path_options=paths)
    for m in plant.machines:  # every machine's options checked before anything starts
        _machine_args(plant.path, m)
    return plant


def _machine_args(plant_path: Path, m: Any) -> argparse.Namespace:
    """The ``edge run`` options of one machine of a plant file, parsed as on the command line."""
    parser = _machine_parser()
    flags = {o[2:]: a for a in parser._actions for o in a.option_strings if o.startswith("--")}
    argv: list[str] = []
    for key, value in m.options.items():
        action = flags[key]
        if isinstance(action, argparse._StoreTrueAction):
            if not isinstance(value, bool):
                raise ConfigError(f"{plant_path}: machine {m.name!r}: {key} = {value!r}: give "
                                  "true or false")
            if value:
                argv.append(f"--{key}")
        else:
            if isinstance(value, bool):
                raise ConfigError(f"{plant_path}: machine {m.name!r}: {key} = {value}: give a "
                                  "value, not true/false")
            argv += [f"--{key}", str(value)]
    try:
        ns = parser.parse_args(argv)
    except ConfigError as exc:
        raise ConfigError(f"{plant_path}: machine {m.name!r}: {exc}") from None
    ns.quiet = True
    return ns


def _plant_worker(plant_path: str, names: list[str], report_queue: Any,
                  session_key: str = "") -> None:
    """Worker process of ``edge run --config``: run the named machines; the live ones on one
    broker share one MQTT connection (client id from ``session_key``: the same across the
    worker's restarts, so its persistent session resumes)."""
    import os

    from cnctwin.edge import session_client_id
    from cnctwin.edge.plant import raise_open_file_limit, run_machines, worker_signals
    from cnctwin.iotools.mqtt import MqttHubs

    stop = threading.Event()
    worker_signals(stop)
    report_queue.put(("", "ready", os.getpid()))  # a stop now drains instead of killing
    short = raise_open_file_limit(len(names))
    if short:
        print(f"warning: worker of {', '.join(names[:3])}{' ...' if len(names) > 3 else ''}: "
              f"{short}", file=sys.stderr)
    plant = read_plant_file(Path(plant_path))
    hubs = MqttHubs(session_client_id(f"plant-{session_key or '+'.join(names)}", ""),
                    machines=len(names))
    builders = []
    for name in names:
        ns = _machine_args(plant.path, plant.machine(name))
        ns.mqtt_hubs = hubs
        builders.append((name, lambda ns=ns: _build(ns)))
    try:
        run_machines(builders, report=lambda n, w, v: report_queue.put((n, w, v)), stop=stop)
    finally:
        hubs.stop()


def plant_table(plant: Any, results: dict[str, Any] | None = None,
                events: list[str] | None = None) -> Any:
    """A rich table of every machine of a plant: one row each, from its ``status.json``."""
    from rich.table import Table

    from cnctwin.edge import read_status

    t = Table(title=f"cnctwin edge - plant {plant.path.name} ({len(plant.machines)} machines)")
    for col in ("machine", "state", "cycles", "cyc/s", "p99 ms", "holes", "alarms", "gaps",
                "lost"):
        t.add_column(col, no_wrap=True, justify="left" if col in ("machine", "state")
                     else "right")
    t.add_column("note", no_wrap=True, overflow="ellipsis", max_width=48)
    for m in plant.machines:
        try:
            st = read_status(m.out)
        except (FileNotFoundError, ValueError):
            st = {}
        what, value = (results or {}).get(m.name, ("", None))
        state = "ERROR" if what == "error" else str(st.get("state", "no status"))
        rate = st.get("cycles_per_s_recent")
        if not isinstance(rate, float) or math.isnan(rate):
            rate = st.get("cycles_per_s")
        lost = sum(int(v) for v in (st.get("overload") or {}).values())
        note = str(value) if what == "error" else ""
        t.add_row(m.name, state, str(st.get("cycles", 0)), _fmt(rate, ".0f"),
                  _fmt((st.get("latency_ms") or {}).get("p99")), str(st.get("holes", 0)),
                  str(st.get("alarms", 0)),
                  str(st.get("gaps", 0)), str(lost) if lost else "-", note)
    if events:
        t.caption = events[-1]
    return t


def _run_plant(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live

    from cnctwin.edge.plant import PlantRunner

    own = [k for k in ("source", "out", "model", "publish") if getattr(args, k, None)]
    if own:
        raise ConfigError(f"--config takes the machines' options from the plant file; give "
                          f"{', '.join('--' + k for k in own)} there ([defaults] or a "
                          "[[machine]] table)")
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers {args.workers}: give 1 or more")
    plant = read_plant_file(args.config)
    runner = PlantRunner(plant, _plant_worker, workers=args.workers)
    main_thread = threading.current_thread() is threading.main_thread()
    old = signal.signal(signal.SIGTERM, lambda *a: runner.stop()) if main_thread else None
    console = Console(stderr=True)
    print(f"plant {plant.path}: {len(plant.machines)} machines on {runner.n_workers} worker "
          "processes", file=sys.stderr)
    try:
        if args.quiet:
            results = _supervise(runner, None)
        else:
            with Live(console=console, refresh_per_second=1, transient=False) as live:
                results = _supervise(runner, lambda r: live.update(
                    plant_table(plant, r.results, r.events)))
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, old)
    failed = {n: v for n, (w, v) in results.items() if w == "error"}
    for n, msg in failed.items():
        print(f"machine {n}: {msg}", file=sys.stderr)
    summary = {m.name: ({k: v.get(k) for k in ("cycles", "holes", "alarms", "gaps")}
                        if w == "done" else {"error": v})
               for m in plant.machines for w, v in [results.get(m.name, ("error", "no report"))]}
    print(json.dumps(summary))
    return 1 if failed else 0


def _supervise(runner: Any, on_tick: Any) -> dict[str, Any]:
    try:
        return dict(runner.run(on_tick=on_tick))
    except KeyboardInterrupt:  # Ctrl-C: stop the workers (they drain) and wait for them
        runner.stop()
        return dict(runner.run())


def _ms_to_s(v: Any) -> float | None:
    return float(v) / 1e3 if isinstance(v, int | float) else None


def _fmt(v: Any, spec: str = ".3g") -> str:
    if v is None:  # not known yet (null in status.json)
        return "-"
    if isinstance(v, float):
        return "-" if math.isnan(v) else format(v, spec)
    return str(v)


def _duration(seconds: Any) -> str:
    """A time as a person reads it: ms below 1 s, s below 2 min, then min and h."""
    if seconds is None or not isinstance(seconds, int | float) or math.isnan(seconds):
        return "-"
    v = float(seconds)
    if abs(v) < 1.0:
        return f"{v * 1e3:.3g} ms"
    if abs(v) < 120.0:
        return f"{v:.1f} s"
    if abs(v) < 7200.0:
        return f"{v / 60:.1f} min"
    return f"{v / 3600:.1f} h"


def status_table(st: dict[str, Any]) -> Any:
    """A rich table of a status dict."""
    from rich.table import Table

    t = Table(title=f"cnctwin edge - {st.get('machine', '')} ({st.get('state', '')})",
              show_header=False)
    rate = st.get("cycles_per_s_recent")
    if not isinstance(rate, float) or math.isnan(rate):
        rate = st.get("cycles_per_s")
    need = st.get("machine_rate_cycles_per_s", 500.0)
    rows = [
        ("cycles", f"{st.get('cycles', 0)} (last {st.get('last_cycle')})"),
        ("cycles/s", f"{_fmt(rate, '.0f')} (machine needs {_fmt(need, '.0f')}; "
                     f"busy {_fmt(st.get('cycles_per_busy_s', float('nan')), '.0f')}/s)"),
        ("lag", f"{_duration(st.get('lag_s'))} (arrival to publish; p99 "
                f"{_duration(_ms_to_s((st.get('latency_ms') or {}).get('p99')))}), data age "
                f"{_duration(st.get('data_age_s'))}"),
        ("holes", str(st.get("holes", 0))),
        ("alarms", str(st.get("alarms", 0))),
        ("gaps", f"{st.get('gaps', 0)} ({st.get('missing_cycles', 0)} cycles missing), "
                 f"wraps {st.get('wraps', 0)}, late rows {st.get('late_rows', 0)}"),
    ]
    for name, s in (st.get("sinks") or {}).items():
        if name == "mqtt":
            rows.append(("mqtt", f"{s.get('broker')} {'up' if s.get('connected') else 'DOWN'}"
                                 f", queued {s.get('queued')}, sent {s.get('sent')}, dropped "
                                 f"oldest {s.get('dropped_oldest')}"))
        elif name == "store":
            rows.append(("store", f"{s.get('store')} blocks {s.get('blocks')}"))
        elif name == "opcua":
            rows.append(("opcua", f"{s.get('endpoint')} published {s.get('published')}"))
        elif name == "mtconnect":
            rows.append(("mtconnect", f"{s.get('agent') or '-'} observations "
                                      f"{s.get('observations')}, next sequence "
                                      f"{s.get('next_sequence')}, SHDR clients "
                                      f"{s.get('shdr_clients')}"))
    ov = st.get("overload") or {}
    if ov:
        lost = sum(int(v) for v in ov.values())
        counts = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in ov.items())
        rows.append(("overload", f"none ({counts})" if lost == 0 else f"LOSSES: {counts}"))
    for msg in (st.get("issues") or [])[-3:]:
        rows.append(("issue", str(msg)[:120]))
    for k, v in rows:
        t.add_row(k, v)
    t.caption = f"updated {st.get('updated', '')}"
    return t


def _build(args: argparse.Namespace) -> Any:
    from cnctwin.edge import (
        AnomalyProcessor,
        DatabusSource,
        EdgeRuntime,
        HoleProcessor,
        JsonLinesSink,
        MqttSink,
        ReplaySource,
        StoreSink,
        TorqueProcessor,
        last_emitted_cycle,
        parse_mqtt_url,
        session_client_id,
    )

    # options first: nothing is opened or connected for a run that cannot start
    if args.checkpoint_s is not None and args.checkpoint_s <= 0:
        raise ConfigError(f"--checkpoint-s {args.checkpoint_s}: give a positive number of "
                          "seconds")
    if not 0 < args.status_s <= 5:
        raise ConfigError(f"--status-s {args.status_s}: give a number of seconds above 0 and "
                          "at most 5 (the dashboard calls a machine stale after 10 s without "
                          "a status)")
    batch_s = getattr(args, "batch_s", 0.0)
    if batch_s < 0 or (batch_s > 0 and (getattr(args, "mqtt_hubs", None) is None or not
                                        args.source.startswith(("mqtt://", "tcp://")))):
        raise ConfigError(f"--batch-s {batch_s}: give 0, or a positive number of seconds for "
                          "a live Databus machine of a plant (edge run --config plant.toml)")
    machine_name, model, machine_file = _machine_and_model(args)
    args.machine = machine_name
    from cnctwin.iotools.mqtt import MqttSecurity

    security = MqttSecurity.from_options(
        ca_file=args.tls_ca, cert_file=args.tls_cert, key_file=args.tls_key,
        username=args.mqtt_user, password_file=args.password_file)
    src: Any
    if args.source.startswith(("mqtt://", "tcp://", "opc.tcp://")):
        # a live source streams from its start on: the processors' compiled loops first
        # (numba, ~2 s without its cache), not while the first messages wait
        from cnctwin.edge.processors import prepare_kernels

        prepare_kernels()
    if args.source.startswith(("mqtt://", "tcp://")):
        u = parse_mqtt_url(args.source)
        if not u.topic:
            raise ConfigError("give the Databus metadata topic: mqtt://host:port/<topic>")
        name_map = json.loads(args.name_map.read_text()) if args.name_map else None
        if args.session_expiry_s < 0:
            raise ConfigError(f"--session-expiry-s {args.session_expiry_s}: give 0 (clean "
                              "session) or a positive number of seconds")
        client_id = args.mqtt_client_id or session_client_id(args.machine, u.topic)
        # what a crash cut off from the broker's acknowledgements is redelivered: skip the
        # cycles the results already hold (exactly once across restarts)
        resume = last_emitted_cycle(args.out / "results.jsonl")
        if resume is not None:
            print(f"resuming after cycle {resume} (the last in {args.out / 'results.jsonl'})",
                  file=sys.stderr)
        hubs = getattr(args, "mqtt_hubs", None)  # a plant worker: one connection per broker
        if hubs is not None and args.mqtt_client_id:
            raise ConfigError(f"mqtt-client-id = {args.mqtt_client_id!r}: the live machines of "
                              "a plant share their worker's MQTT connection and session (client "
                              f"id {hubs.client_id}); leave mqtt-client-id out of the plant file")
        hub = None if hubs is None else hubs.get(
            u.host, u.port, username=u.username, password=u.password, security=security,
            session_expiry_s=args.session_expiry_s)
        if hub is not None:
            client_id = hub.client_id
        src = DatabusSource(u.host, u.port, metadata_topic=u.topic, name_map=name_map,
                            username=u.username, password=u.password, machine=args.machine,
                            idle_timeout_s=args.idle_timeout_s, security=security,
                            client_id=client_id, session_expiry_s=args.session_expiry_s,
                            resume_after_cycle=resume, hub=hub, batch_s=batch_s)
        print(f"connecting to {u.host}:{u.port}, waiting for the Databus metadata on "
              f"{u.topic} (up to {src.ready_timeout_s:.0f} s) ...", file=sys.stderr)
        try:
            src.start()  # metadata first: its applicationName names the machine by default
        except (ConnectionError, TimeoutError) as exc:
            raise ConfigError(f"--source {u.host}:{u.port}: {exc}") from None
        if args.session_expiry_s > 0:  # one line, also with --quiet: the operator must know
            state = ("resumed: what the broker queued while the runtime was down follows"
                     if src.recorder.session_present else "new")
            print(f"MQTT session {client_id} ({state}; expiry {args.session_expiry_s} s)",
                  file=sys.stderr)
        if not src.machine:
            src.machine = str((src.recorder.decoder.metadata or {}).get("applicationName", ""))
    elif args.source.startswith("opc.tcp://"):
        from cnctwin.cli.opcua import client_options
        from cnctwin.edge.sources import OpcUaSource
        from cnctwin.iotools.opcua_client import read_node_map

        if args.nodes is None:
            raise ConfigError("an OPC UA source needs --nodes FILE (the node file: [signals] "
                              "column = node id; docs/opcua-client.md)")
        nodes = read_node_map(args.nodes)
        options = client_options(args)
        writer = None
        if getattr(args, "adaptive_config", None) is not None and nodes.write:
            from cnctwin.edge.control_write import ControlWriter

            cfg = args.adaptive_config
            # checked before anything is read or written: the session, every write node
            writer = ControlWriter(args.source, nodes.write, options=options,
                                   min_pct=cfg.min_pct, max_pct=cfg.max_pct).start()
        src = OpcUaSource(args.source, nodes, options=options,
                          idle_timeout_s=args.idle_timeout_s, machine=args.machine,
                          interval_s=args.interval_s)
        try:
            src.start()
        except BaseException:
            if writer is not None:
                writer.close()
            raise
        args.control_writer = writer
    else:
        src = ReplaySource(args.source, chunk_cycles=args.chunk_cycles, speed=args.speed)
    machine = args.machine or src.machine or "machine"
    procs: list[Any] = [TorqueProcessor(model)]
    if not args.no_holes:
        life = None
        if getattr(args, "tool_table", None) is not None:
            from cnctwin.usecases.tool_life import ToolLifeLimits, ToolLifeTracker

            table = args.tool_table
            life = ToolLifeTracker({t: ToolLifeLimits.from_tool(table.get(t)) for t in table})
        procs.append(HoleProcessor(model, tool_kinds=getattr(args, "tool_kinds", None),
                                   tool_life=life))
    if getattr(args, "adaptive_config", None) is not None:
        from cnctwin.edge.adaptive import AdaptiveProcessor

        coef = None
        if getattr(args, "stock_spec", None) is not None:  # the engagement model's torque
            from cnctwin.sim.materials import resolve_material

            own = getattr(machine_file, "materials", {}) if machine_file is not None else {}
            coef = resolve_material(args.material, machine_materials=own,
                                    machine_source=str(args.machine)).material.milling
        procs.append(AdaptiveProcessor(model, args.adaptive_config,
                                       stock=getattr(args, "stock_spec", None),
                                       diameters=getattr(args, "tool_diameters", None),
                                       coefficients=coef,
                                       flutes=getattr(args, "tool_flutes", None)))
    if not args.no_anomaly:
        from cnctwin.usecases.anomaly import (
            Detector,
            PhysicsResidualDetector,
            SpectralDetector,
            TappingDetector,
        )
        from cnctwin.usecases.monitoring import WearAdaptiveDetector

        if args.detector in ("adaptive", "physics-torque") and args.no_holes:
            raise ConfigError(f"--detector {args.detector} needs the hole processor (the live "
                              "hole number and progress): drop --no-holes")
        makers: dict[str, Callable[[], Detector]] = {
            # the air current against the twin, judged only where no tool can cut, with a
            # spread of at least 10 % of the predicted current + 0.05 A (friction drifts
            # ~0.5 %/K with the bearings' temperature; the calibration's uncertainty)
            "physics": lambda: PhysicsResidualDetector(gate="air", rel_floor=0.1,
                                                       abs_floor=0.05),
            "tapping": TappingDetector,
            "spectral": SpectralDetector, "adaptive": WearAdaptiveDetector,
            "physics-torque": lambda: WearAdaptiveDetector(expected="expected_torque_nm")}
        det = makers[args.detector]()
        kw: dict[str, Any] = {"learn_s": args.learn_s}
        if args.detector == "adaptive":
            kw["learn_holes"] = args.learn_holes
        elif args.detector == "physics-torque":
            kw = {"learn_s": 0.0, "material": args.material, "diameter_mm": args.drill_mm,
                  "point_angle_deg": args.point_angle_deg}
        if args.detector == "physics":  # the calibrated spindle's air current, not learned
            from cnctwin.usecases.air_friction import AirFrictionCheck

            kw["friction_check"] = AirFrictionCheck()
        procs.append(AnomalyProcessor(det, model=model, **kw))
    if machine_file is not None and not args.no_twin:
        from cnctwin.edge.processors import TwinCompareProcessor

        procs.append(TwinCompareProcessor(machine_file, window_s=args.twin_window_s))
    out: Path = args.out
    if args.rotate_mb <= 0 or args.keep_files < 1:
        raise ConfigError(f"--rotate-mb {args.rotate_mb} --keep-files {args.keep_files}: give "
                          "a positive size and keep at least 1 file")
    sinks: list[Any] = [JsonLinesSink(out / "results.jsonl",
                                      rotate_bytes=int(args.rotate_mb * 1e6),
                                      keep_files=args.keep_files)]
    if args.publish:
        u = parse_mqtt_url(args.publish, default_topic="cnctwin")
        sink = MqttSink(u.host, u.port, state_dir=out, machine=machine,
                        topic_prefix=u.topic, max_queue_messages=args.max_queue,
                        username=u.username, password=u.password, security=security)
        unreachable = sink.check()  # a refused password or an untrusted certificate: stop
        if unreachable:
            print(f"note: {unreachable}; results are kept in {out / 'outbox'} until "
                  "the broker can be reached", file=sys.stderr)
        sinks.append(sink)
    if args.store:
        sinks.append(StoreSink(args.store, machine=machine))
    if args.opcua:
        from cnctwin.edge.opcua import OpcUaSink

        ua_security = None
        if not args.opcua_insecure:
            from cnctwin.edge.opcua import OpcUaSecurity, read_users

            if args.opcua_users is None:
                raise ConfigError("--opcua needs --opcua-users FILE (add a user with 'cnctwin "
                                  "edge opcua-user NAME --users FILE'), or --opcua-insecure "
                                  "to serve anonymous clients without security")
            ua_security = OpcUaSecurity(args.opcua_cert or out / "opcua-cert.der",
                                        args.opcua_key or out / "opcua-key.pem",
                                        read_users(args.opcua_users),
                                        trust_dir=args.opcua_trust or out / "opcua-pki",
                                        trust_any=args.opcua_trust_any)
        sinks.append(OpcUaSink(args.opcua, machine=machine,
                               publish_hz=args.opcua_publish_hz, security=ua_security,
                               identification=dict(getattr(machine_file, "identification",
                                                           {}) or {}),
                               tools=_tool_entries(getattr(args, "tool_table", None))))
    if args.mtconnect or args.shdr:
        sinks.append(_mtconnect_sink(args, machine))
    if getattr(args, "control_writer", None) is not None:
        sinks.append(args.control_writer)
    rt = EdgeRuntime(src, procs, sinks, state_dir=out, machine=machine,
                     checkpoint_every_s=args.checkpoint_s, status_every_s=args.status_s)
    info = rt.resume()  # a run that ended without finishing (crash, kill -9) continues
    if info["resumed"]:
        how = ("from its checkpoint (open hole, detectors and estimator restored)"
               if info["from_checkpoint"] else
               "without a checkpoint of this source: a hole open at the crash is flagged "
               "partial, detectors learn again")
        print(f"{machine}: the last run in {out} did not finish; resuming after cycle "
              f"{info['after_cycle']} {how}; results it already emitted are not repeated",
              file=sys.stderr)
    return rt


def _tool_entries(table: Any) -> dict[int, dict[str, Any]]:
    """T number -> the tool table's entry as the OPC UA and MTConnect sinks describe it."""
    if table is None:
        return {}
    keys = ("name", "kind", "diameter_mm", "flutes", "life_holes", "wear_limit_um",
            "wear_um_per_increase")
    return {t: {k: getattr(table.get(t), k) for k in keys} for t in table}


def _mtconnect_sink(args: argparse.Namespace, machine: str) -> Any:
    import os

    from cnctwin.edge.mtconnect_server import MTConnectSink, parse_listen_url

    agent = (parse_listen_url(args.mtconnect, scheme="http", option="--mtconnect")
             if args.mtconnect else None)
    shdr = parse_listen_url(args.shdr, scheme="tcp", option="--shdr") if args.shdr else None
    token = None
    if args.mtconnect_token_file is not None:
        try:
            token = args.mtconnect_token_file.read_text(encoding="utf-8").strip() or None
        except OSError as exc:
            raise ConfigError(f"--mtconnect-token-file {args.mtconnect_token_file}: "
                              f"{exc.strerror or exc}") from None
    token = token or os.environ.get("CNCTWIN_MTCONNECT_TOKEN", "").strip() or None
    return MTConnectSink(machine, agent=agent, shdr=shdr, buffer_size=args.mtconnect_buffer,
                         sample_hz=args.mtconnect_sample_hz, token=token,
                         insecure=args.mtconnect_insecure, shdr_insecure=args.shdr_insecure,
                         tools=_tool_entries(getattr(args, "tool_table", None)))


def _machine_and_model(args: argparse.Namespace) -> tuple[str, Any, Any]:
    """The machine name and the spindle model from ``--machine`` and ``--model``.

    ``--machine`` naming a ``.toml`` file (or an existing file) is the machine file: its name
    and its calibrated spindle (:meth:`SpindleModel.from_machine`) are used; ``--model``, if
    also given, replaces the spindle model. Otherwise ``--machine`` is a name and ``--model``
    is required. The third value is the machine file (None for a name).
    """
    from cnctwin.edge import load_spindle_model
    from cnctwin.spindle import SpindleModel

    value = str(args.machine or "")
    if value.endswith(".toml") or (value and Path(value).is_file()):
        from cnctwin.machine import load_machine

        mf = load_machine(value)
        if args.model is not None:
            return mf.machine.name, load_spindle_model(args.model), mf
        if not mf.is_identified("spindle.kt_nm_per_a"):
            raise ConfigError(f"{value}: the spindle is not calibrated (spindle.kt_nm_per_a has "
                              "no provenance); run 'cnctwin calibrate spindle ... --machine "
                              f"{value}' first or give --model")
        return mf.machine.name, SpindleModel.from_machine(mf), mf
    if args.model is None:
        raise ConfigError("give --machine FILE.toml (a calibrated machine file) or --model "
                          "spindle.json")
    return value, load_spindle_model(args.model), None


def _run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live

    if args.config is not None:
        return _run_plant(args)
    if args.workers is not None:
        raise ConfigError("--workers goes with --config PLANT.toml (many machines)")
    missing = [k for k in ("source", "out") if getattr(args, k) is None]
    if missing:
        raise ConfigError(f"give {' and '.join('--' + k for k in missing)} (one machine), or "
                          "--config PLANT.toml (many machines)")
    if getattr(args, "adaptive", None) is not None:  # read before any source starts
        from cnctwin.edge.adaptive import read_adaptive_config

        args.adaptive_config = read_adaptive_config(args.adaptive)
    if getattr(args, "tools", None) is not None:  # read before any source starts
        from cnctwin.machine import read_tool_table

        table = read_tool_table(args.tools)
        args.tool_table = table
        args.tool_kinds = {t: table.get(t).kind for t in table}
        args.tool_diameters = {t: table.get(t).diameter_mm for t in table}
        args.tool_flutes = {t: table.get(t).flutes for t in table}
        cfg = getattr(args, "adaptive_config", None)
        unknown = sorted(set(cfg.tools) - set(table)) if cfg is not None else []
        if unknown:
            raise ConfigError(f"{args.adaptive}: tools.{unknown[0]} is not in the tool table "
                              f"{args.tools} (tools: {', '.join(map(str, sorted(table)))})")
    if getattr(args, "stock", None) is not None:
        from cnctwin.engagement import parse_stock

        if getattr(args, "adaptive_config", None) is None or args.tools is None:
            raise ConfigError("--stock goes with --adaptive and --tools (the engagement model "
                              "that tells a breakage from a tool leaving the part)")
        args.stock_spec = parse_stock(args.stock)
    rt = _build(args)
    main_thread = threading.current_thread() is threading.main_thread()
    old = signal.signal(signal.SIGTERM, lambda *a: rt.stop()) if main_thread else None
    console = Console(stderr=True)
    try:
        if args.quiet:
            final = rt.run()
        else:
            with Live(console=console, refresh_per_second=2, transient=False) as live:
                final = rt.run(on_status=lambda st: live.update(status_table(st)))
                live.update(status_table(final))
            console.line()  # the summary line below starts on its own line
    except KeyboardInterrupt:  # run() has already finished the processors and sinks
        final = rt.final_status or rt.status()
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, old)
    print(json.dumps({k: final[k] for k in ("cycles", "holes", "alarms", "gaps",
                                            "missing_cycles", "late_rows", "wraps")}))
    return 0


def _status(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cnctwin.edge import read_status

    if args.config is not None:
        plant = read_plant_file(args.config)
        if args.json:
            out: dict[str, Any] = {}
            for m in plant.machines:
                try:
                    out[m.name] = read_status(m.out)
                except FileNotFoundError:
                    out[m.name] = None
            print(json.dumps(out, indent=1))
        else:
            Console().print(plant_table(plant))
        return 0
    if args.dir is None:
        raise ConfigError("give the state directory (the --out of `edge run`) or --config "
                          "PLANT.toml")
    try:
        st = read_status(args.dir)
    except FileNotFoundError as exc:
        raise ConfigError(str(exc)) from None
    if args.json:
        print(json.dumps(st, indent=1))
    else:
        Console().print(status_table(st))
    return 0


def _opcua_user(args: argparse.Namespace) -> int:
    import getpass
    import os

    from cnctwin.edge.opcua import hash_password

    if not args.name or ":" in args.name or any(c.isspace() for c in args.name):
        raise ConfigError(f"user name {args.name!r}: no ':' and no blanks")
    pw = os.environ.get("CNCTWIN_OPCUA_PASSWORD")
    if not pw:
        pw = (getpass.getpass(f"password for {args.name}: ") if sys.stdin.isatty()
              else sys.stdin.readline().rstrip("\n"))
    if len(pw) < 8:
        raise ConfigError("the password must have 8 characters or more")
    lines = []
    if args.users.exists():
        lines = [ln for ln in args.users.read_text(encoding="utf-8").splitlines()
                 if ln.partition(":")[0].strip() != args.name]
    lines.append(f"{args.name}:{hash_password(pw)}")
    args.users.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.users.with_suffix(args.users.suffix + ".tmp")
    tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    tmp.chmod(0o600)
    tmp.replace(args.users)
    print(f"{args.users}: user {args.name} set")
    return 0

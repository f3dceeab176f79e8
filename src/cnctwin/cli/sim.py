"""Simulator subcommand: ``cnctwin simulate NAME --out DIR --seed N [--set key=value ...]``.

Runs one scenario of :mod:`cnctwin.sim.scenarios` (each on :func:`cnctwin.sim.simulate`) with
a rich progress bar over the program's machine time; ``--format`` chooses Capture4Analysis JSON
(chained files) or a Parquet chunk directory for the recording.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from cnctwin.exceptions import ConfigError

__all__ = ["register"]


SCENARIO_NAMES: tuple[str, ...] = ("air_cut_sweep", "axis_test", "drilling_validation",
                                   "loose_tap", "milling_square_circle", "tool_wear_run",
                                   "warm_up")
"""The names of :data:`cnctwin.sim.scenarios.SCENARIOS` (sorted; a test keeps them equal),
written out so that ``cnctwin --help`` does not import the simulator."""


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``simulate`` to the ``cnctwin`` command line.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers; the module adds its commands to them.
    """
    p = sub.add_parser(
        "simulate",
        help="run a simulator scenario and write recordings + truth.json",
        description="Run a thesis scenario of the physics simulator. Writes Capture4Analysis "
        "JSON, external-sensor CSVs and truth.json (every true parameter) to --out.",
    )
    p.add_argument("name", nargs="?", choices=[*SCENARIO_NAMES, "fleet"],
                   help="scenario (or --program for your own part program); 'fleet' writes a "
                   "synthetic fleet (--machines, --days, --cycles-per-day) with hidden faults")
    p.add_argument("--program", type=Path, metavar="PART.mpf",
                   help="simulate this part program (supported G-code subset) instead of a "
                   "scenario; prints the cycle time and the peak loads against the drive limits")
    p.add_argument("--machine", type=Path, metavar="FILE",
                   help="machine file (cnctwin calibrate) to simulate; default the thesis machine")
    p.add_argument("--material", default=None, metavar="NAME|FILE.toml",
                   help="with --program: workpiece material (aisi1045, grey_cast_iron, al7050, "
                   "one calibrated into --machine, or a material file with [milling]; "
                   "--set material.NAME.* uses the library's NAME with those values); "
                   "default air (no cutting load)")
    p.add_argument("--tools", type=Path, metavar="TOOLS.toml",
                   help="with --program: tool table ([tools.N] with kind, diameter_mm, ...); "
                   "each tool cuts by its kind, so a program that drills and mills does both")
    p.add_argument("--stock", metavar="X0,Y0,Z0,X1,Y1,Z1",
                   help="with --program and --tools: the raw part [mm]; end mills cut what is "
                   "left of it (engagement from a Z-map; a second pass cuts air)")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a parameter, e.g. spindle.kt_nm_per_a=1.1 or "
        "material.aisi1045.kc1_n_per_mm2=1600 (repeatable); with --program, --tools and "
        "--stock the hidden workpiece: part.hardness_along_x='[[60, 1.15], [110, 0.95]]' "
        "(hardness factor from each X [mm] on) and part.break_at_x_mm=80 (the end mill "
        "breaks there)",
    )
    p.add_argument(
        "--option",
        dest="options",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="scenario option, e.g. n_holes=60 for tool_wear_run (repeatable; JSON values, "
        'e.g. faults=\'[{"type": "ToolBreakage", "hole": 40}]\')',
    )
    p.add_argument(
        "--format",
        dest="fmt",
        choices=("c4a", "parquet"),
        default=None,
        help="recording format: c4a (Capture4Analysis JSON) or parquet (chunk directory); "
        "default: the scenario's (parquet for tool_wear_run, c4a otherwise)",
    )
    p.add_argument("--serve-opcua", metavar="opc.tcp://HOST:PORT",
                   help="after simulating, serve the recording in real time from a "
                   "SINUMERIK-like OPC UA server (Ctrl-C ends; writes OUT/nodes.toml for "
                   "`cnctwin record`)")
    p.add_argument("--serve-speed", type=float, default=1.0,
                   help="with --serve-opcua: recording seconds per second (default 1)")
    p.add_argument("--realtime", action="store_true",
                   help="with --program and --serve-opcua: simulate while serving, in real "
                   "time, obeying the feed override an edge writes to the PLC nodes of "
                   "OUT/nodes.toml ([write]; heartbeat watchdog, clamp, stop/feed-hold ends the "
                   "program); OUT/control.csv and OUT/adaptive.json at the end "
                   "(docs/adaptive.md)")
    p.add_argument("--serve-interval-s", type=float, default=0.1,
                   help="with --realtime: control time between served values (default 0.1 s, "
                   "SINUMERIK's OPC UA rate)")
    p.add_argument("--serve-user", metavar="NAME",
                   help="with --realtime: the OPC UA user (password from "
                   "CNCTWIN_OPCUA_PASSWORD); the server then offers Basic256Sha256 only and "
                   "its PLC nodes are writable; without it nothing can be written")
    p.add_argument("--wait-for-client-s", type=float, default=0.0, metavar="S",
                   help="with --realtime: start the program once a client subscribed (the "
                   "edge is connected), waiting at most S seconds (default 0: at once)")
    p.add_argument("--heartbeat-s", type=float, default=0.5,
                   help="with --realtime: the PLC falls back to 100 %% when the edge's "
                   "heartbeat is older (default 0.5 s)")
    p.add_argument("--plc-bounds", default="50,120", metavar="MIN,MAX",
                   help="with --realtime: the PLC clamps the edge's override to these [%%] "
                   "(default 50,120)")
    f = p.add_argument_group("fleet (cnctwin simulate fleet)")
    f.add_argument("--machines", type=int, default=20, help="machines (default 20)")
    f.add_argument("--days", type=int, default=5, help="days from --start-day (default 5)")
    f.add_argument("--cycles-per-day", type=int, default=2,
                   help="recorded part cycles per machine and day (default 2; ~21 s each)")
    f.add_argument("--start-day", default="2026-03-02", help="first day (UTC, YYYY-MM-DD)")
    f.add_argument("--fault-fraction", type=float, default=0.4,
                   help="fraction of machines with a hidden fault (default 0.4)")
    f.add_argument("--scheduler", metavar="ADDR",
                   help="simulate on this Dask scheduler (default: an embedded cluster)")
    f.add_argument("--workers", type=int, metavar="N",
                   help="worker processes of the embedded cluster (default: the cores)")
    p.set_defaults(func=_cmd_simulate)


def _parse_pairs(items: list[str], what: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"{what} {item!r}: expected KEY=VALUE")
        try:
            out[key.strip()] = json.loads(raw)
        except json.JSONDecodeError:
            out[key.strip()] = raw
    return out


def _cmd_simulate(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from cnctwin.sim.scenarios import part_program, run_scenario

    if args.name == "fleet":
        return _cmd_fleet(args)
    if (args.name is None) == (args.program is None):
        raise ConfigError("give a scenario NAME or --program PART.mpf (one of them)")
    for opt in ("material", "tools", "stock"):
        if getattr(args, opt) is not None and args.program is None:
            raise ConfigError(f"--{opt} goes with --program")
    machine = None
    mfile = None
    if args.machine is not None:
        from cnctwin.machine import load_machine

        mfile = load_machine(args.machine)
        machine = mfile.machine
    program_kw = _program_inputs(args, mfile) if args.program is not None else {}
    overrides = _parse_pairs(args.overrides, "--set")
    options = _parse_pairs(args.options, "--option")
    if args.fmt is not None:
        options["fmt"] = args.fmt
    if args.realtime:
        if args.program is None or not args.serve_opcua:
            raise ConfigError("--realtime goes with --program PART.mpf and --serve-opcua URL")
        if not args.program.exists():
            raise ConfigError(f"{args.program}: no such file")
        return _realtime(args, program_kw, overrides, options, machine)
    label = args.name or args.program.name
    with Progress(transient=True) as bar:
        task = bar.add_task(label, total=1.0)

        def progress(fraction: float, text: str) -> None:
            bar.update(task, completed=fraction, description=f"{label}: {text}")

        if args.program is not None:
            if not args.program.exists():
                raise ConfigError(f"{args.program}: no such file")
            res = part_program(args.out, program=args.program, seed=args.seed,
                               overrides=overrides, machine=machine, progress=progress,
                               **program_kw, **options)
        else:
            res = run_scenario(args.name, args.out, seed=args.seed, overrides=overrides,
                               progress=progress, machine=machine, **options)
    for p in res.paths:
        print(p)
    if args.program is not None:
        _print_limits(res.truth["limits"])
    if args.serve_opcua:
        from cnctwin.iotools import read_recording

        _serve_opcua(read_recording(res.recording_paths[0]), args)
    return 0


def _realtime(args: argparse.Namespace, program_kw: dict[str, Any],
              overrides: dict[str, Any], options: dict[str, Any], machine: Any) -> int:
    """``simulate --program ... --serve-opcua URL --realtime``: the closed loop's control."""
    import os
    import time

    from cnctwin.edge.sinumerik_live import (
        LiveSinumerikServer,
        PlcOverride,
        write_live_node_file,
    )
    from cnctwin.sim.part import LiveOverride
    from cnctwin.sim.scenarios import part_program
    from cnctwin.usecases.adaptive_report import write_live_summary

    try:
        lo, hi = (float(v) for v in str(args.plc_bounds).split(","))
    except ValueError:
        raise ConfigError(f"--plc-bounds {args.plc_bounds!r}: give MIN,MAX in %, e.g. 50,120"
                          ) from None
    plc = PlcOverride(min_pct=lo, max_pct=hi, heartbeat_s=args.heartbeat_s)
    out = Path(args.out)
    users = None
    if args.serve_user:
        pw = os.environ.get("CNCTWIN_OPCUA_PASSWORD")
        if not pw:
            raise ConfigError("--serve-user needs its password in CNCTWIN_OPCUA_PASSWORD")
        users = {args.serve_user: pw}

    def listening(sig: dict[str, str], text: dict[str, str]) -> None:
        nodes = write_live_node_file(sig, text, out / "nodes.toml",
                                     interval_s=args.serve_interval_s)
        print(f"serving on {args.serve_opcua} in real time (node file {nodes})", flush=True)

    server = LiveSinumerikServer(args.serve_opcua, plc, interval_s=args.serve_interval_s,
                                 speed=args.serve_speed, users=users,
                                 cert_file=out / "opcua-server-cert.der",
                                 key_file=out / "opcua-server-key.pem",
                                 on_listening=listening,
                                 wait_for_client_s=args.wait_for_client_s)
    from cnctwin.sim.machine import Machine

    dt = (machine or Machine.thesis_default()).cycle_time_s
    chunk = max(1, min(10, round(args.serve_interval_s / dt)))
    calls: list[float] = []

    def requested() -> float | None:
        calls.append(time.time())
        return plc.requested()

    live = LiveOverride(requested=requested, chunk_cycles=chunk, tee=server)
    try:
        res = part_program(args.out, program=args.program, seed=args.seed, overrides=overrides,
                           machine=machine, live=live, **program_kw, **options)
    finally:
        server.stop()
    summary = write_live_summary(out, log=live.log, truth=res.truth, plc=plc,
                                 served_at=server.served_at, requested_at=calls)
    for p in res.paths:
        print(p)
    _print_limits(res.truth["limits"])
    mean = summary["override_pct"]["mean"]  # None: no override applied while cutting
    print(f"adaptive: cycle time {summary['cycle_time_s']:.2f} s, override "
          f"{'n/a' if mean is None else f'{mean:.1f} %'} mean, stop request "
          f"{summary['stop_request'] or 'none'}, {summary['writes']} writes from the edge, "
          f"{len(plc.fallbacks)} heartbeat fallbacks; {out / 'adaptive.json'}")
    return 0


def _program_inputs(args: argparse.Namespace, mfile: Any) -> dict[str, Any]:
    """--material, --tools and --stock of a program run, read and checked."""
    from cnctwin.engagement import parse_stock
    from cnctwin.machine import read_tool_table
    from cnctwin.sim.materials import resolve_material

    out: dict[str, Any] = {"material": args.material}
    if args.material is not None:
        own = getattr(mfile, "materials", {}) if mfile is not None else {}
        spec = str(args.material)
        # --set material.NAME.* states the simulated truth: the library's NAME with those
        # values, not the machine file's calibrated NAME
        overridden = any(o.split("=", 1)[0].strip().startswith(f"material.{spec}.")
                         for o in args.overrides)
        if spec in own and overridden:
            own = {}
        if spec.lower().endswith(".toml") or Path(spec).is_file() or spec in own:
            out["material"] = resolve_material(
                spec, machine_materials=own, machine_source=str(args.machine)).material
        else:
            resolve_material(spec)  # a library name: checked here, overrides apply in the sim
    if args.tools is not None:
        out["tools"] = read_tool_table(args.tools)
    if args.stock is not None:
        out["stock"] = parse_stock(args.stock)
    return out


def _serve_opcua(rec: Any, args: argparse.Namespace) -> None:
    import time

    from cnctwin.edge.sinumerik_opcua import SinumerikOpcUaServer, write_node_file

    srv = SinumerikOpcUaServer(rec, args.serve_opcua, speed=args.serve_speed, loop=True).start()
    nodes = write_node_file(rec, Path(args.out) / "nodes.toml")  # once the server listens
    print(f"serving on {args.serve_opcua} (node file {nodes}); Ctrl-C ends", flush=True)
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        srv.stop()


def _print_limits(lim: dict[str, Any]) -> None:
    import sys

    sp = lim["spindle"]
    print(f"cycle time {lim['cycle_time_s']:.2f} s")
    for key, unit in (("torque_nm", "Nm"), ("power_w", "W"), ("current_a", "A")):
        if key not in sp:
            continue
        v = sp[key]
        what = key.rsplit("_", 1)[0]
        if v.get("limit") is not None:
            print(f"  spindle {what:7s} peak {v['peak']:8.4g} {unit:2s} (limit {v['limit']:.4g})"
                  f"  line {v['line']}: {v['block']}")
        s1 = v.get("s1")
        if s1 is not None:
            print(f"  spindle {what:7s} S1   {s1['mean']:8.4g} {unit:2s} (limit "
                  f"{s1['limit']:.4g}, over {s1['window_s']:g} s)  line {s1['line']}: "
                  f"{s1['block']}")
    for ax, v in lim.get("axes", {}).items():
        c = v["current_a"]
        print(f"  {ax:7s} current peak {c['peak']:8.4g} A  (limit {v['current_limit_a']:.4g})"
              f"  line {c['line']}: {c['block']}")
    for t, v in lim.get("tools", {}).items():
        c = v["chip_mm"]
        limit = "-" if c["limit"] is None else f"{c['limit']:.4g}"
        print(f"  {t:7s} chip    peak {c['peak']:8.4g} mm (limit {limit})  line {c['line']}: "
              f"{c['block']}")
    for w in lim["warnings"]:
        print(f"warning: {w}", file=sys.stderr)


def _cmd_fleet(args: argparse.Namespace) -> int:
    from cnctwin.cli.fleet import run_cluster_tasks
    from cnctwin.sim.fleet import plan_fleet, simulate_fleet_cycle

    if args.program is not None or args.machine is not None or args.overrides:
        raise ConfigError("simulate fleet draws every machine itself: --program, --machine "
                          "and --set do not apply")
    plan = plan_fleet(machines=args.machines, days=args.days,
                      cycles_per_day=args.cycles_per_day, seed=args.seed,
                      start_day=args.start_day, fault_fraction=args.fault_fraction)
    out = Path(args.out)
    plan.write(out)
    paths = run_cluster_tasks(args, "simulate", simulate_fleet_cycle, plan.cycles,
                              out=str(out.resolve()))
    print(f"{len(paths)} recordings of {len(plan.machines)} machines x {len(plan.days)} days "
          f"in {out}; {len(plan.faults)} hidden faults in {out / 'truth.json'}")
    return 0

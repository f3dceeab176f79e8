"""Many machines in one edge process: the plant file and the runner that serves it.

A plant file (TOML) lists the machines one ``cnctwin edge run --config plant.toml`` serves,
each with the options it would get on its own command line::

    workers = 2                  # worker processes (default: the cores, at most one per machine)
    out = "state"                # a machine's --out defaults to <out>/<name>

    [defaults]                   # options of every machine (a machine's own value wins)
    publish = "mqtt://broker:1883/cnctwin"
    password-file = "secrets/mqtt.txt"

    [[machine]]
    name = "mill-1"
    source = "mqtt://ie-databus:1883/ie/m/j/simatic/v1/nck1/dp"
    machine = "machines/mill-1.toml"   # the calibrated machine file

    [[machine]]
    name = "mill-2"
    source = "recordings/mill-2.json"
    model = "spindle-mill-2.json"

Relative paths are taken from the plant file's folder. Every machine keeps its own source,
model or machine file, state directory (``seq``, status, results, outbox) and topics, so what
:mod:`cnctwin.edge.runtime` guarantees for one machine (exactly once across restarts, counted
losses) holds for each machine of the plant.

:func:`run_machines` runs the runtimes of some machines in one process: the live machines on
one broker share one MQTT connection (:class:`~cnctwin.iotools.mqtt.MqttHub`) and are driven
from one thread, each message routed to its machine; the replays at full speed are driven
from that thread too, a chunk of each in turn; any other source (a paced replay, OPC UA) runs
in a thread of its own;
:class:`PlantRunner` spreads the machines over worker processes (``spawn``), one per core, so
the interpreter lock never limits a plant to one core, restarts a worker that dies and stops
them all on SIGTERM or Ctrl-C.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import multiprocessing as mp
import os
import queue as queue_mod
import select
import signal
import threading
import time
import tomllib
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any, Protocol

from cnctwin.exceptions import CnctwinError, ConfigError

__all__ = ["FILES_PER_MACHINE", "PlantFile", "PlantMachine", "PlantRunner", "raise_open_file_limit",
           "read_plant", "run_machines"]


@dataclass(frozen=True)
class PlantMachine:
    """One machine of a plant file.

    Attributes
    ----------
    name : str
        Label of the machine in the plant (unique; the default state directory name).
    options : dict
        Its ``edge run`` options, keys as on the command line without the dashes
        (``"password-file"``); paths made absolute.
    out : pathlib.Path
        Its state directory (``--out``).
    """

    name: str
    options: dict[str, Any]
    out: Path


@dataclass(frozen=True)
class PlantFile:
    """A plant file: its machines and the number of worker processes it asks for."""

    path: Path
    machines: tuple[PlantMachine, ...]
    workers: int | None = None

    def machine(self, name: str) -> PlantMachine:
        """The machine called ``name``."""
        for m in self.machines:
            if m.name == name:
                return m
        raise ConfigError(f"{self.path}: no machine named {name!r}; it lists "
                          f"{[m.name for m in self.machines]}")


_TOP_KEYS = {"workers", "out", "defaults", "machine"}


def _norm(key: str) -> str:
    return key.strip().replace("_", "-")


def read_plant(path: str | PathLike[str], *, options: Collection[str],
               path_options: Collection[str] = ()) -> PlantFile:
    """Read and check a plant file.

    Parameters
    ----------
    path : str or path-like
        The TOML file.
    options : collection of str
        Option names a machine may set (``edge run``'s, without dashes: ``"source"``).
    path_options : collection of str
        Options whose relative values are paths from the plant file's folder (``source``
        and ``machine`` are resolved too when they name a file rather than a URL or a name).

    Returns
    -------
    PlantFile

    Raises
    ------
    ConfigError
        Naming the file, the machine and the key: a TOML syntax error, an unknown key, a
        machine without a name, two machines with one name or one state directory.
    """
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such plant file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read the plant file ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    unknown = sorted(set(doc) - _TOP_KEYS)
    if unknown:
        raise ConfigError(f"{p}: unknown top-level key(s) {unknown}; a plant file has "
                          f"{sorted(_TOP_KEYS)} (machine options go under [defaults] or a "
                          "[[machine]] table)")
    base = p.resolve().parent
    workers = doc.get("workers")
    if workers is not None and (not isinstance(workers, int) or isinstance(workers, bool)
                                or workers < 1):
        raise ConfigError(f"{p}: workers = {workers!r}: give a whole number >= 1 (or leave "
                          "it out: one worker per core)")
    out_base = doc.get("out")
    if out_base is not None and not isinstance(out_base, str):
        raise ConfigError(f"{p}: out = {out_base!r}: give a folder name")
    allowed = {_norm(o) for o in options}
    paths = {_norm(o) for o in path_options}

    def _options(table: Any, where: str) -> dict[str, Any]:
        if not isinstance(table, Mapping):
            raise ConfigError(f"{p}: {where} must be a table of options")
        out: dict[str, Any] = {}
        for k, v in table.items():
            key = _norm(k)
            if key == "name" and where != "[defaults]":
                continue
            if key not in allowed:
                raise ConfigError(f"{p}: {where}: unknown option {k!r}; the options are those "
                                  f"of `cnctwin edge run` ({', '.join(sorted(allowed))})")
            if isinstance(v, Mapping | list):
                raise ConfigError(f"{p}: {where}: {k} = {v!r}: give a string, number or "
                                  "true/false")
            out[key] = _resolve(key, v, base, paths)
        return out

    defaults = _options(doc.get("defaults", {}), "[defaults]")
    tables = doc.get("machine", [])
    if not isinstance(tables, list) or not tables:
        raise ConfigError(f"{p}: no machines: add a [[machine]] table per machine (name, "
                          "source, machine or model)")
    machines: list[PlantMachine] = []
    seen_out: dict[Path, str] = {}
    for k, t in enumerate(tables, 1):
        where = f"[[machine]] #{k}"
        name = t.get("name") if isinstance(t, Mapping) else None
        if not isinstance(name, str) or not name.strip() or "/" in name:
            raise ConfigError(f"{p}: {where} needs name = \"...\" (a label without '/')")
        where = f"[[machine]] {name!r}"
        if any(m.name == name for m in machines):
            raise ConfigError(f"{p}: two machines are named {name!r}: names must be unique")
        opts = {**defaults, **_options(t, where)}
        opts.setdefault("machine", name)
        if "out" not in opts:
            if out_base is None:
                raise ConfigError(f"{p}: {where} has no out = \"DIR\" and the file has no "
                                  "top-level out = \"DIR\" to put it under")
            opts["out"] = str((base / out_base / name).resolve())
        out = Path(opts["out"])
        if out in seen_out:
            raise ConfigError(f"{p}: machines {seen_out[out]!r} and {name!r} share the state "
                              f"directory {out}: each machine needs its own")
        seen_out[out] = name
        for need in ("source",):
            if need not in opts:
                raise ConfigError(f"{p}: {where} has no {need} (a recording file or "
                                  "mqtt://host:port/<metadata topic> or opc.tcp://...)")
        machines.append(PlantMachine(name, opts, out))
    return PlantFile(p, tuple(machines), workers)


def _resolve(key: str, value: Any, base: Path, paths: Collection[str]) -> Any:
    if not isinstance(value, str) or not value:
        return value
    if key in paths or key == "out":
        return str((base / value).resolve()) if not Path(value).is_absolute() else value
    if key in ("source", "machine") and "://" not in value and not Path(value).is_absolute():
        cand = base / value
        if key == "source" or value.endswith(".toml") or cand.is_file():
            return str(cand.resolve())
    return value


# ---------------------------------------------------------------------- one process
class _Runtime(Protocol):
    def run(self) -> dict[str, Any]: ...

    def stop(self) -> None: ...


Report = Callable[[str, str, Any], None]
"""``report(machine, what, value)``: ``what`` is ``"started"``, ``"done"`` (value: the final
status) or ``"error"`` (value: the message)."""


def _error_text(exc: BaseException) -> str:
    if isinstance(exc, CnctwinError):
        return str(exc)
    if isinstance(exc, (OSError, ConnectionError, TimeoutError)):
        return f"{type(exc).__name__}: {exc}"
    return f"internal error: {type(exc).__name__}: {exc}"


class _Pumped:
    """A machine whose live source shares its worker's MQTT hub, driven from the worker's
    thread: its runtime takes what the source has each time the hub routed messages to it
    (at most once per the source's ``batch_s``: what arrived meanwhile is one chunk), and an
    idle tick every ``tick_s``."""

    def __init__(self, name: str, rt: Any) -> None:
        self.name = name
        self.rt = rt
        src = rt.source
        src.window_s = 0.0  # chunks() never waits: it yields an idle chunk when empty
        self.batch_s = float(src.batch_s)
        self.chunks = rt.begin()
        self.next_tick = 0.0
        self.ticked = 0.0  # when its last tick was due
        self.last_data = -1e9
        self.due = 0.0  # messages wait until then (batch_s); 0: none waiting
        self.hub = src.hub

    def tick(self) -> bool:
        """The idle tick's work (status when due, the sinks) while messages wait for their
        batch (they stay in the source); never ends the run."""
        self.rt.idle()
        return False

    def pump(self, *, idle: bool) -> bool:
        """Process what arrived (and an idle tick if ``idle``); True when the run ended."""
        self.due = 0.0
        for chunk in self.chunks:
            if len(chunk):
                self.last_data = time.monotonic()
                self.rt.process(chunk)
                if self.rt.stopping:
                    return False  # the next pump ends the source and drains it
                continue
            if idle:
                self.rt.idle()
            return False
        return True


class _Replayed:
    """A replay at full speed driven from the worker's thread: a chunk per turn (its source
    never waits, so many of them in one thread lose nothing to one another, where a thread
    each spent as much CPU handing the interpreter lock around as on the pipelines)."""

    def __init__(self, name: str, rt: Any) -> None:
        self.name = name
        self.rt = rt
        self.chunks = rt.begin()

    def turn(self) -> bool:
        """Process the next chunk; True when the run ended (the source or a stop)."""
        chunk = next(self.chunks, None)
        if chunk is None:
            return True
        self.rt.handle(chunk)
        return bool(self.rt.stopping)


def _unpaced_replay(rt: Any) -> bool:
    """Whether ``rt`` replays a recording as fast as it can (no pace to wait for)."""
    from cnctwin.edge.sources import ReplaySource

    src = getattr(rt, "source", None)
    return isinstance(src, ReplaySource) and not src.speed


class _PumpLoop:
    """The machines of one process driven from one thread: those that share MQTT hubs and the
    replays at full speed."""

    def __init__(self, report: Report, wake: threading.Event, tick_s: float) -> None:
        self.report = report
        self.wake = wake
        self.tick_s = tick_s
        self.machines: dict[Any, _Pumped] = {}  # the source's hub port -> machine
        self.hubs: set[Any] = set()
        self.replays: list[_Replayed] = []
        self.driven = False  # the hubs' socket work done by this thread (drive())

    def drive(self) -> None:
        """Every machine is built (their starts waited for the metadata, which the hubs'
        network threads delivered): the hubs' socket work moves to this thread, which then
        reads, routes and processes in turn; no thread takes the interpreter lock from it
        per message (BENCHMARKS.md, "the hub driven from the worker's thread")."""
        for h in self.hubs:
            h.drive()
        self.driven = True

    def wait(self, wait_s: float, wake: threading.Event) -> None:
        """Wait up to ``wait_s`` for work: a message on a hub's socket once driven, else
        the hubs' threads (``wake``)."""
        if not self.driven:
            wake.wait(wait_s)
            return
        if any(h.buffered() for h in self.hubs):
            return  # TLS: decrypted bytes wait inside a socket object already
        socks = [s for s in (h.socket() for h in self.hubs) if s is not None]
        if socks:
            select.select(socks, [], [], wait_s)
        else:  # every hub reconnecting
            time.sleep(wait_s)

    def add_replay(self, name: str, rt: Any) -> None:
        try:
            self.replays.append(_Replayed(name, rt))
        except Exception as exc:
            self.report(name, "error", _error_text(exc))

    def _over(self, m: _Pumped | _Replayed, turn: Callable[[], bool]) -> bool:
        """Give ``m`` its turn; True when its run is over (ended: reported done; or failed:
        reported with its error), and the caller forgets it."""
        try:
            if not turn():
                return False
        except Exception as exc:  # one machine's failure must not stop the others
            self.report(m.name, "error", _error_text(exc))
            with contextlib.suppress(Exception):
                m.rt.end()
            return True
        try:
            self.report(m.name, "done", m.rt.end())
        except Exception as exc:
            self.report(m.name, "error", _error_text(exc))
        return True

    def _replay_turns(self) -> None:
        """One chunk of every replay (then the live machines get their turn again)."""
        self.replays = [m for m in self.replays if not self._over(m, m.turn)]

    def add(self, name: str, rt: Any) -> None:
        try:
            m = _Pumped(name, rt)
        except Exception as exc:
            self.report(name, "error", _error_text(exc))
            return
        hub = rt.source.hub
        hub.notify = self.wake
        self.hubs.add(hub)
        # the machines' idle ticks (status files, sinks) spread over the tick, so that no
        # arrival waits behind all of them
        m.next_tick = time.monotonic() + self.tick_s * (len(self.machines) % 16 + 1) / 16
        self.machines[rt.source.recorder._client] = m

    def step(self, *, stopping: bool) -> float:
        """Pump the machines with new messages (or whose batch or tick is due); returns how
        long to wait for the next [s] (0: go on at once)."""
        touched: set[Any] = set()
        for h in self.hubs:
            if self.driven:
                h.io()
            touched |= h.take_touched()
        now = time.monotonic()
        for port, m in list(self.machines.items()):
            tick = stopping or now >= m.next_tick
            if port in touched and not m.due:
                m.due = max(m.last_data + m.batch_s, now)
            if not (tick or (m.due and now >= m.due)):
                continue
            if tick:
                # a machine whose data came since its last tick needs none: its chunks kept
                # the sinks going (each write sends and takes the acknowledgements) and
                # carry its status when due; only a due status or nothing new is ticked
                quiet = not stopping and not m.due and m.last_data >= m.ticked \
                    and not getattr(m.rt, "status_due", True)
                m.ticked, m.next_tick = now, now + self.tick_s
                if quiet:
                    continue
                if not stopping and m.due > now:
                    # a batch is gathering: the tick's own work (a due status, the sinks)
                    # without its messages, which stay for the batch's one chunk (taken
                    # here, a 1 s batch became two chunks at a 0.5 s tick, each paying the
                    # work per chunk: BENCHMARKS.md, session 27)
                    if self._over(m, m.tick):
                        del self.machines[port]
                    continue
            if self.driven:
                # what came while the machines before it were processed (a step can take
                # tens of ms): a batch then takes its messages up to now, as with a thread
                m.hub.io()
            if self._over(m, functools.partial(m.pump, idle=tick)):
                del self.machines[port]
        if self.replays:
            self._replay_turns()
        if touched or self.replays:
            return 0.0
        nxt = [m.next_tick for m in self.machines.values()] + \
            [m.due for m in self.machines.values() if m.due]
        return max(0.0, min(min(nxt, default=now + self.tick_s) - time.monotonic(), 0.2))


def _closing(rt: Any) -> None:
    """The whole process stops: a shared MQTT connection keeps its session's subscriptions
    (the broker keeps the machines' messages for the restart)."""
    hub = getattr(getattr(rt, "source", None), "hub", None)
    if hub is not None:
        hub.closing = True


def run_machines(builders: Sequence[tuple[str, Callable[[], _Runtime]]], *,
                 report: Report, stop: threading.Event, tick_s: float = 0.5) -> None:
    """Build and run the runtimes of some machines in one process, until all have ended.

    Parameters
    ----------
    builders : sequence of (str, callable)
        Machine name and a function that builds its runtime (called in a thread of its own,
        so a slow connection of one machine does not hold the others up).
    report : callable
        ``report(name, what, value)`` on start, end and error of each machine.
    stop : threading.Event
        Set it to stop every runtime (each drains what it received and closes its sinks).
    tick_s : float, default 0.5
        Idle tick of the machines driven from this thread [s].

    Notes
    -----
    A machine whose live source shares an MQTT hub (:class:`cnctwin.iotools.mqtt.MqttHub`: a
    plant worker's machines on one broker) is driven from this function's thread once built:
    the hub routes each message to its machine's queue (its network thread while machines
    are being built, whose start waits for the metadata; then this thread, which reads the
    hub's socket itself: :meth:`~cnctwin.iotools.mqtt.MqttHub.drive`), this thread runs
    that machine's pipeline on it (what arrived within the source's ``batch_s`` as one
    chunk), and ticks every machine (status, sinks, idle timeout) once per ``tick_s``, the
    machines' ticks spread over it: no thread per machine. A replay at full speed (no
    ``speed``) is driven from this thread too, one chunk of each in turn. Any other runtime
    (a paced replay, OPC UA) runs in its build thread. A machine whose build or run fails (a
    broker that refuses it, a missing file) is reported and ends; the others go on.
    """
    runtimes: dict[str, _Runtime] = {}
    lock = threading.Lock()
    wake = threading.Event()
    # built, to be driven from this thread: (name, runtime, a full-speed replay)
    handed: list[tuple[str, Any, bool]] = []

    def one(name: str, build: Callable[[], _Runtime]) -> None:
        try:
            rt = build()
            with lock:
                runtimes[name] = rt
                stopping = stop.is_set()
            if stopping:
                _closing(rt)
                rt.stop()
            report(name, "started", None)
            replay = _unpaced_replay(rt)
            if replay or getattr(getattr(rt, "source", None), "hub", None) is not None:
                with lock:
                    handed.append((name, rt, replay))
                wake.set()
                return
            report(name, "done", rt.run())
        except Exception as exc:  # one machine's bug must not take the plant down
            report(name, "error", _error_text(exc))

    threads = [threading.Thread(target=one, args=(n, b), name=f"edge-{n}", daemon=True)
               for n, b in builders]
    for th in threads:
        th.start()
    loop = _PumpLoop(report, wake, tick_s)
    stopped = False
    while True:
        with lock:
            new, handed[:] = list(handed), []
        for name, rt, replay in new:
            (loop.add_replay if replay else loop.add)(name, rt)
        if not loop.machines and not loop.replays and not new and \
                not any(th.is_alive() for th in threads):
            with lock:
                if not handed:
                    break
        if stop.is_set() and not stopped:
            stopped = True
            with lock:
                for rt in runtimes.values():
                    _closing(rt)
                for rt in runtimes.values():
                    rt.stop()
        if not loop.driven and loop.hubs and not handed and \
                not any(th.is_alive() for th in threads):
            loop.drive()
        wait_s = loop.step(stopping=stopped)
        if wait_s > 0:
            loop.wait(wait_s, wake)
    for th in threads:
        th.join()


# ---------------------------------------------------------------------- many processes
FILES_PER_MACHINE = 9
"""Open files one machine of a plant worker holds: its outbox (the newest segment, and an
older one while a backlog is sent), ``results.jsonl``, its MQTT sink's socket and paho's
wake-up socket pair, its checkpoint's two slot files, and one being written (the status
file)."""


def raise_open_file_limit(machines: int) -> str:
    """Raise this process's soft limit of open files to what ``machines`` need.

    Parameters
    ----------
    machines : int
        Machines this process runs.

    Returns
    -------
    str
        Empty, or what to do when the hard limit is below the need (the soft limit is then
        raised to the hard one).

    Notes
    -----
    Linux's usual soft limit of 1024 open files would stop a worker at about 125 machines
    (:data:`FILES_PER_MACHINE` each) with "Too many open files"; the hard limit (often 4096 to
    1048576) is the administrator's, and only the soft one is raised to it (as nginx's
    ``worker_rlimit_nofile`` or Go's runtime do). Nothing to do where the platform has no such
    limit (Windows).
    """
    try:
        import resource
    except ImportError:
        return ""
    need = machines * FILES_PER_MACHINE + 64  # + the interpreter, broker sockets, logs
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or soft >= need:
        return ""
    target = need if hard == resource.RLIM_INFINITY else min(need, hard)
    if target > soft:
        resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
    if target < need:
        return (f"{machines} machines need about {need} open files, but this process may "
                f"open at most {hard} (the hard limit): raise it (ulimit -Hn, systemd "
                "LimitNOFILE=) or give the plant more workers (workers = N in the plant file)")
    return ""


BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""Read by the BLAS libraries when NumPy loads them; a plant's workers start with 1 (unless
the user set them): one worker per core, so BLAS threads in a worker would only compete for
the cores (and OpenBLAS's idle threads spin)."""


@contextlib.contextmanager
def _one_blas_thread() -> Iterator[None]:
    """The environment a worker process is spawned with: one BLAS thread (restored after)."""
    saved = {k: os.environ.get(k) for k in BLAS_THREAD_VARIABLES}
    for k in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(k, "1")
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


Worker = Callable[[str, list[str], Any, str], None]
"""``worker(plant_path, machine_names, report_queue, session_key)``: a top-level function
(picklable by reference) that runs the named machines of the plant file in a worker process
(``session_key``: the same for a worker slot across restarts, the key of its MQTT session)
and puts ``(name, what, value)`` tuples on the queue (:func:`run_machines` does the
running); first ``("", "ready", os.getpid())`` once its SIGTERM handler is installed
(:func:`worker_signals`), so that a stop never kills it half-started."""


@dataclass
class _Slot:
    names: list[str]
    proc: Any = None
    restarts: int = 0
    next_start: float = 0.0
    finished: set[str] = field(default_factory=set)
    ready: bool = False  # its SIGTERM handler is installed (a stop is then a clean drain)
    term_sent: bool = False


class PlantRunner:
    """Spread the machines of a plant over worker processes and supervise them.

    Parameters
    ----------
    plant : PlantFile
        The plant.
    worker : callable
        See :data:`Worker`.
    workers : int, optional
        Worker processes (default the plant file's, else the CPUs this process may use; at
        most one per machine).
    restart_backoff_s : float, default 1.0
        First wait before a worker that died (killed, crashed) is started again; doubles on
        each restart up to 60 s. Its machines resume from their state directories.

    Attributes
    ----------
    results : dict
        Machine name -> ``("done", final status)`` or ``("error", message)``.
    """

    def __init__(self, plant: PlantFile, worker: Worker, *, workers: int | None = None,
                 restart_backoff_s: float = 1.0) -> None:
        n_cpu = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") \
            else (os.cpu_count() or 1)
        w = workers or plant.workers or n_cpu
        if w < 1:
            raise ConfigError(f"workers = {w}: give 1 or more")
        self.plant = plant
        self.worker = worker
        self.n_workers = min(w, len(plant.machines))
        names = [m.name for m in plant.machines]
        self.slots = [_Slot(names[k::self.n_workers]) for k in range(self.n_workers)]
        self.restart_backoff_s = restart_backoff_s
        self.results: dict[str, tuple[str, Any]] = {}
        self.events: list[str] = []
        self._ctx = mp.get_context("spawn")
        self._queue: Any = self._ctx.Queue()
        self._stop = threading.Event()
        self._started = False
        self._stop_sent: float | None = None

    def stop(self) -> None:
        """Stop every worker (SIGTERM: each machine drains and closes); thread-safe."""
        self._stop.set()

    def _start(self, slot: _Slot) -> None:
        names = [n for n in slot.names if n not in slot.finished]
        slot.ready = slot.term_sent = False
        # the worker's MQTT session key: its slot's machines, the same across its restarts
        key = hashlib.sha1("+".join(slot.names).encode()).hexdigest()[:12]
        slot.proc = self._ctx.Process(target=self.worker,
                                      args=(str(self.plant.path), names, self._queue, key),
                                      name=f"cnctwin-edge-{'+'.join(names)[:40]}", daemon=False)
        with _one_blas_thread():  # a worker per core: BLAS threads would only compete
            slot.proc.start()

    def _drain_reports(self, timeout_s: float) -> None:
        try:
            item = self._queue.get(timeout=timeout_s)
        except queue_mod.Empty:
            return
        while True:
            name, what, value = item
            if what == "ready":  # value: the worker's pid
                for s in self.slots:
                    if s.proc is not None and s.proc.pid == value:
                        s.ready = True
            elif what in ("done", "error"):
                self.results[name] = (what, value)
                for s in self.slots:
                    if name in s.names:
                        s.finished.add(name)
            try:
                item = self._queue.get_nowait()
            except queue_mod.Empty:
                return

    def run(self, *, on_tick: Callable[[PlantRunner], None] | None = None,
            tick_s: float = 1.0, stop_timeout_s: float = 60.0) -> dict[str, tuple[str, Any]]:
        """Start the workers and supervise them until every machine has ended or a stop.

        Returns
        -------
        dict
            :attr:`results`.
        """
        if not self._started:
            self._started = True
            for s in self.slots:
                self._start(s)
        last_tick = 0.0
        stop_sent: float | None = self._stop_sent
        while True:
            self._drain_reports(0.2)
            now = time.monotonic()
            if self._stop.is_set() and stop_sent is None:
                stop_sent = self._stop_sent = now
            if stop_sent is not None:
                # SIGTERM once a worker can take it (its handler installed: it drains); one
                # still starting gets it as soon as it reports ready
                for s in self.slots:
                    if s.proc is not None and s.proc.is_alive() and s.ready \
                            and not s.term_sent:
                        s.term_sent = True
                        os.kill(s.proc.pid, signal.SIGTERM)
            if stop_sent is not None and now - stop_sent > stop_timeout_s:
                for s in self.slots:  # drained too long: the state directories still hold
                    if s.proc is not None and s.proc.is_alive():  # the resume point
                        s.proc.kill()
            alive = False
            for s in self.slots:
                if s.proc is None:
                    if stop_sent is None and now >= s.next_start:
                        self._start(s)
                    alive = alive or stop_sent is None
                    continue
                if s.proc.is_alive():
                    alive = True
                    continue
                code = s.proc.exitcode
                s.proc.join()
                self._drain_reports(0.0)
                open_ = [n for n in s.names if n not in s.finished]
                if open_ and stop_sent is None:
                    wait = min(self.restart_backoff_s * 2 ** s.restarts, 60.0)
                    s.restarts += 1
                    self.events.append(f"worker of {', '.join(open_)} ended with code {code}; "
                                       f"restart #{s.restarts} in {wait:.0f} s (the machines "
                                       "resume from their state directories)")
                    s.proc, s.next_start = None, now + wait
                    alive = True
                elif open_:
                    for n in open_:
                        self.results.setdefault(n, ("error", f"worker ended with code {code} "
                                                             "while stopping"))
                    s.finished.update(open_)
            if on_tick is not None and now - last_tick >= tick_s:
                last_tick = now
                on_tick(self)
            if not alive:
                break
        self._drain_reports(0.0)
        if on_tick is not None:
            on_tick(self)
        return self.results


def worker_signals(stop: threading.Event) -> None:
    """In a worker process: SIGTERM sets ``stop``; Ctrl-C is left to the supervisor."""
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    with contextlib.suppress(ValueError, OSError):
        signal.signal(signal.SIGINT, signal.SIG_IGN)

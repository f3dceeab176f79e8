"""A SINUMERIK-like OPC UA server for tests and demos, fed by a (simulated) recording.

``cnctwin simulate NAME --serve-opcua opc.tcp://HOST:PORT`` runs a scenario and serves its
recording in real time the way a SINUMERIK 840D sl's OPC UA server (Access MyMachine /
OPC UA) exposes the NC variables: string node ids in namespace 2 with the NC variable paths
(SINUMERIK 840D sl, *NC variables and interface signals*, List Manual 01/2017)::

    ns=2;s=/Channel/MachineAxis/actToolBasePos[u1,<n>]   ENC_POS|<axis>    position [mm]
    ns=2;s=/Channel/MachineAxis/aaLoad[u1,<n>]           LOAD|<axis>       load [%]
    ns=2;s=/Channel/MachineAxis/aaCurr[u1,<n>]           CURRENT|<axis>    current [A]
    ns=2;s=/Channel/MachineAxis/aaPower[u1,<n>]          POWER|<axis>      power [W]
    ns=2;s=/Channel/Spindle/cmdSpeed[u1,1]               CMD_SPEED|SP1     speed [rpm]
    ns=2;s=/Channel/ProgramInfo/progName[u1]             program name (text)
    ns=2;s=/Channel/State/actTNumber[u1]                 active tool (text)

``<n>`` is the axis' number in the recording's axis map. Every value is written with the
source timestamp of the recorded cycle it comes from, every ``interval_s`` of the recording
(default 100 ms: the rate SINUMERIK's server delivers), and logged in :attr:`served` so a test
can compare what a client recorded with what was served. All nodes are read-only.
:func:`node_map` writes the matching node file for ``cnctwin record``.
"""

from __future__ import annotations

import asyncio
import math
import os
import threading
import time
import urllib.parse
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cnctwin.exceptions import ConfigError
from cnctwin.recording import Recording

__all__ = ["SinumerikOpcUaServer", "data_value", "node_ids", "node_ids_for", "sinumerik_server",
           "write_node_file", "write_nodes"]

_AXIS_VARS = (("ENC_POS", "actToolBasePos", "mm"), ("LOAD", "aaLoad", "%"),
              ("CURRENT", "aaCurr", "A"), ("POWER", "aaPower", "W"))


def node_ids_for(columns: list[str], axis_map: Mapping[Any, str]
                 ) -> tuple[dict[str, str], dict[str, str]]:
    """Column -> node id and text name -> node id of the variables served for these columns.

    Parameters
    ----------
    columns : list of str
        ``CODE|AXIS`` columns.
    axis_map : mapping
        Axis number (int or text) -> axis name; empty: the axes numbered in column order.

    Returns
    -------
    tuple of dict
        Column -> node id, and text (LF) signal name -> node id.
    """
    numbers = {name: int(n) for n, name in axis_map.items()}
    if not numbers:
        for c in columns:
            numbers.setdefault(c.split("|", 1)[1], len(numbers) + 1)
    sig: dict[str, str] = {}
    for code, var, _ in _AXIS_VARS:
        for ax, n in sorted(numbers.items(), key=lambda kv: kv[1]):
            if f"{code}|{ax}" in columns:
                sig[f"{code}|{ax}"] = f"ns=2;s=/Channel/MachineAxis/{var}[u1,{n}]"
    sp = next((ax for ax in numbers if ax.startswith("SP")), None)
    if sp is not None and f"CMD_SPEED|{sp}" in columns:
        sig[f"CMD_SPEED|{sp}"] = "ns=2;s=/Channel/Spindle/cmdSpeed[u1,1]"
    text = {"program": "ns=2;s=/Channel/ProgramInfo/progName[u1]",
            "tool": "ns=2;s=/Channel/State/actTNumber[u1]"}
    return sig, text


def node_ids(rec: Recording) -> tuple[dict[str, str], dict[str, str]]:
    """:func:`node_ids_for` a recording's columns and axis map.

    Parameters
    ----------
    rec : Recording
        The recording.

    Returns
    -------
    tuple of dict
        Column -> node id, and text (LF) signal name -> node id.
    """
    return node_ids_for(list(rec.columns), rec.meta.axis_map)


def write_nodes(signals: dict[str, str], text: dict[str, str], path: str | Path, *,
                comments: tuple[str, ...] = (), write: dict[str, str] | None = None) -> Path:
    """Write a node file: ``[signals]``, ``[text]``, ``[units]`` and, if given, ``[write]``
    (replaced whole: a reader polling for the file never sees half of it).

    Parameters
    ----------
    signals, text : dict
        From :func:`node_ids_for`.
    path : str or path-like
        TOML file to write.
    comments : tuple of str
        Comment lines at the top.
    write : dict, optional
        Writable nodes (``[write]``, after a comment line).

    Returns
    -------
    pathlib.Path
    """
    units = {c: u for code, _, u in _AXIS_VARS for c in signals if c.startswith(code + "|")}
    lines = [f"# {c}" for c in comments] + ["[signals]"]
    lines += [f'"{c}" = "{n}"' for c, n in signals.items()]
    lines += ["", "[text]"] + [f'{k} = "{n}"' for k, n in text.items()]
    lines += ["", "[units]"] + [f'"{c}" = "{u}"' for c, u in units.items()]
    if write:
        lines += ["", "# written by edge run --adaptive (secured session only)", "[write]"]
        lines += [f'{k} = "{n}"' for k, n in write.items()]
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_suffix(".tmp")
    tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    tmp.replace(p)
    return p


def write_node_file(rec: Recording, path: str | Path) -> Path:
    """Write the node file (``cnctwin record --nodes``) for the variables served for ``rec``.

    Parameters
    ----------
    rec : Recording
        The recording.
    path : str or path-like
        TOML file to write.

    Returns
    -------
    pathlib.Path
    """
    sig, text = node_ids(rec)
    return write_nodes(sig, text, path, comments=(
        "SINUMERIK-like OPC UA server of cnctwin (cnctwin.edge.sinumerik_opcua)",))


def data_value(value: Any, ts: Any) -> Any:
    """The served data value of a number (``BadNoData`` when not finite) or a text.

    Parameters
    ----------
    value : float or str
        The value.
    ts : datetime
        Its source (and server) time.

    Returns
    -------
    asyncua.ua.DataValue
    """
    from asyncua import ua

    if isinstance(value, str):
        return ua.DataValue(ua.Variant(value, ua.VariantType.String), SourceTimestamp=ts,
                            ServerTimestamp=ts)
    if not math.isfinite(value):
        return ua.DataValue(StatusCode_=ua.StatusCode(ua.StatusCodes.BadNoData),
                            SourceTimestamp=ts, ServerTimestamp=ts)
    return ua.DataValue(ua.Variant(float(value), ua.VariantType.Double), SourceTimestamp=ts,
                        ServerTimestamp=ts)


async def sinumerik_server(endpoint: str, *, name: str, users: dict[str, str] | None,
                           cert_file: str | Path | None, key_file: str | Path | None
                           ) -> tuple[Any, Any]:
    """An initialised (not yet started) asyncua server shaped like SINUMERIK's: namespace 2
    ``SinumerikVarProvider``, a ``Sinumerik`` folder; with ``users`` Basic256Sha256 Sign and
    SignAndEncrypt with a user name only (certificate generated if missing, key 0600),
    without them anonymous and no security.

    Parameters
    ----------
    endpoint : str
        ``opc.tcp://HOST:PORT``.
    name : str
        Server name.
    users : dict, optional
        User name -> password.
    cert_file, key_file : path, optional
        Server certificate (DER) and key (PEM) (with ``users``).

    Returns
    -------
    tuple
        The server and the ``Sinumerik`` folder node.
    """
    from asyncua import Server, ua

    if users:
        from asyncua.crypto.cert_gen import setup_self_signed_certificate
        from cryptography.x509.oid import ExtendedKeyUsageOID

        from cnctwin.edge.opcua import _UserManager, hash_password

        hashed = {u: hash_password(p, iterations=1000) for u, p in users.items()}
        server = Server(user_manager=_UserManager(hashed))
    else:
        server = Server()
    await server.init()
    server.set_endpoint(endpoint)
    server.set_server_name(name)
    if users:
        uri = "urn:cnctwin:sinumerik-sim"
        await server.set_application_uri(uri)
        Path(str(cert_file)).parent.mkdir(parents=True, exist_ok=True)
        await setup_self_signed_certificate(
            Path(str(key_file)), Path(str(cert_file)), uri, "localhost",
            [ExtendedKeyUsageOID.SERVER_AUTH], {"commonName": "sinumerik-sim"})
        os.chmod(str(key_file), 0o600)
        await server.load_certificate(str(cert_file))
        await server.load_private_key(str(key_file))
        server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_Sign,
                                    ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
        server.set_security_IDs(["Username"])
    else:
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    idx = await server.register_namespace("SinumerikVarProvider")
    if idx != 2:
        raise ConfigError(f"namespace index {idx}, expected 2")
    folder = await server.nodes.objects.add_folder(ua.NodeId("Sinumerik", idx),
                                                   ua.QualifiedName("Sinumerik", idx))
    return server, folder


def _last_at(ev_cycles: np.ndarray, values: np.ndarray, cycles: np.ndarray) -> list[str]:
    """For each cycle the last value of an event at or before it ("" before the first)."""
    pos = np.searchsorted(ev_cycles, cycles, side="right") - 1
    return [str(values[p]) if p >= 0 else "" for p in pos]


class SinumerikOpcUaServer:
    """Serve a recording's values in real time from SINUMERIK-style nodes.

    Parameters
    ----------
    rec : Recording
        What to serve (e.g. a simulator scenario's recording).
    endpoint : str, default 'opc.tcp://127.0.0.1:4840'
        Where to listen.
    interval_s : float, default 0.1
        Recording time between served values [s].
    speed : float, default 1
        Recording seconds per wall-clock second.
    loop : bool, default False
        Start over at the end (a demo that runs until stopped; the times go on).
    start_s : float, default 0
        Start this far into the recording (a server restarted mid-run goes on from there).
    users : dict, optional
        User name -> password: username authentication with Basic256Sha256 Sign and
        SignAndEncrypt (certificate ``cert_file``/``key_file``, generated if missing);
        without it anonymous access with no security (a test and demo server).
    cert_file, key_file : path, optional
        Server certificate (DER) and key (PEM).
    """

    def __init__(self, rec: Recording, endpoint: str = "opc.tcp://127.0.0.1:4840", *,
                 interval_s: float = 0.1, speed: float = 1.0, loop: bool = False,
                 start_s: float = 0.0, users: dict[str, str] | None = None,
                 cert_file: str | Path | None = None, key_file: str | Path | None = None) -> None:
        u = urllib.parse.urlsplit(endpoint)
        if u.scheme != "opc.tcp" or not u.hostname or not u.port:
            raise ConfigError(f"--serve-opcua {endpoint!r}: expected opc.tcp://HOST:PORT")
        if users and not (cert_file and key_file):
            raise ConfigError("a secured server needs cert_file and key_file")
        self.rec, self.endpoint, self.interval_s = rec, endpoint, interval_s
        self.speed, self.loop, self.users = speed, loop, users
        self.start_s = start_s
        self.cert_file, self.key_file = cert_file, key_file
        self.signals, self.text = node_ids(rec)
        self.served: list[tuple[int, dict[str, Any]]] = []
        self._stop = threading.Event()
        self._done = threading.Event()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> SinumerikOpcUaServer:
        """Start serving in a background thread (returns once the server listens)."""
        self._thread = threading.Thread(target=lambda: asyncio.run(self._main()),
                                        name="sinumerik-opcua", daemon=True)
        self._thread.start()
        self._ready.wait(30)
        if self._error is not None:
            raise ConfigError(f"the OPC UA server on {self.endpoint} did not start: "
                              f"{self._error}")
        return self

    @property
    def finished(self) -> bool:
        """The recording has been served to its end."""
        return self._done.is_set()

    def stop(self) -> None:
        """Stop serving (the port is free afterwards)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(15)

    async def _main(self) -> None:
        import logging

        from asyncua import ua

        for name in ("asyncua", "asyncua.server"):
            logging.getLogger(name).setLevel(logging.ERROR)
        try:
            server, folder = await sinumerik_server(
                self.endpoint, name="SINUMERIK 840D sl (cnctwin simulator)", users=self.users,
                cert_file=self.cert_file, key_file=self.key_file)
            idx = 2  # SinumerikVarProvider (sinumerik_server checks it)
            nodes: dict[str, Any] = {}
            for name, nid in {**self.signals, **self.text}.items():
                vt = ua.VariantType.Double if name in self.signals else ua.VariantType.String
                init: Any = 0.0 if name in self.signals else ""
                node = await folder.add_variable(ua.NodeId.from_string(nid),
                                                 ua.QualifiedName(nid.split("s=", 1)[1], idx),
                                                 init, varianttype=vt)
                nodes[name] = node.nodeid
            async with server:
                self._ready.set()
                await self._feed(server, nodes)
        except BaseException as exc:
            self._error = exc
            self._ready.set()

    def _values(self) -> tuple[np.ndarray, dict[str, np.ndarray], list[tuple[str, str]]]:
        rec = self.rec
        t_ns = rec.hf["time"].to_numpy(dtype="datetime64[ns]").view(np.int64)
        step = max(1, round(self.interval_s / rec.meta.cycle_time_s))
        first = min(rec.n_cycles - 1, max(0, round(self.start_s / rec.meta.cycle_time_s)))
        idx = np.arange(first, rec.n_cycles, step)
        cols = {c: rec.hf[c].to_numpy(dtype=float)[idx] for c in self.signals}
        ev = rec.events.sort_values("cycle", kind="stable")
        at = rec.cycles[idx]
        calls = ev[ev["kind"] == "call"].dropna(subset=["path"])
        progs = _last_at(calls["cycle"].to_numpy(), calls["path"].astype(str).to_numpy(), at)
        tools = [""] * len(at)
        if "active_tool" in ev:
            t = ev.dropna(subset=["active_tool"])
            tools = _last_at(t["cycle"].to_numpy(),
                             np.array([str(int(v)) for v in t["active_tool"]], dtype=object), at)
        text = list(zip(progs, tools, strict=True))
        return t_ns[idx], cols, text

    async def _feed(self, server: Any, nodes: dict[str, Any]) -> None:

        t_src, cols, text = self._values()
        span = int(t_src[-1] - t_src[0]) + round(self.interval_s * 1e9) if len(t_src) else 0
        offset = 0
        while True:
            t0 = time.monotonic()
            for k in range(len(t_src)):
                if self._stop.is_set():
                    return
                due = t0 + k * self.interval_s / self.speed
                await asyncio.sleep(max(0.0, due - time.monotonic()))
                t_k = int(t_src[k]) + offset
                ts = pd.Timestamp(t_k, tz="UTC").to_pydatetime()
                vals: dict[str, Any] = {c: float(v[k]) for c, v in cols.items()}
                vals["program"], vals["tool"] = text[k]
                for name, value in vals.items():
                    await server.write_attribute_value(nodes[name], data_value(value, ts))
                self.served.append((t_k, vals))
            offset += span
            if not self.loop:
                self._done.set()
                while not self._stop.is_set():
                    await asyncio.sleep(0.1)
                return

"""OPC UA server sink of the edge runtime: the twin's computed quantities for SCADA/MES.

:class:`OpcUaSink` runs an asyncua server in a background thread (its own asyncio loop; the
runtime stays synchronous) and publishes, per machine, an object with variables that a client
such as UaExpert or asyncua's ``uals``/``uaread`` can browse::

    Objects/<machine>/                      (namespace ``urn:cnctwin:edge`` by default)
        SpindleSpeed [rpm], CuttingTorque [Nm], CuttingTorquePeak [Nm], Cycle
        ToolWear [um], ToolTipTemperature [degC], HoleCount
        LastHole/  HoleNumber, Tool, StartTime, Depth [mm], TorqueMean [Nm],
                   TorquePeak [Nm], TorqueEnergy [J], CurrentPeak [A], SpindleSpeed [rpm],
                   Feed [mm/min], CutDuration [s], X [mm], Y [mm], DeviationXMaxAbs [mm],
                   DeviationYMaxAbs [mm], DeviationZMaxAbs [mm], DeviationZRms [mm], Record
        Alarm/     Active, Message, Detector, Score, Threshold, Cycle, Count

Analog variables carry the ``EngineeringUnits`` property (``EUInformation`` with the UNECE
code of the unit). Every value's SourceTimestamp is the time of the cycle it belongs to on the
recording's time base (the CYCLE counter), not the wall clock; the ServerTimestamp is the
server's clock. See docs/edge.md, "Open outputs: OPC UA".

The 500 Hz torque and speed are decimated to ``publish_hz`` on the cycle grid: window ``k``
holds cycles ``k*m .. k*m + m - 1`` with ``m = round(1 / (publish_hz * cycle_time_s))``. A
window is published once a later cycle arrives (or at the end of the stream): the window mean
of speed and torque, and the torque value of largest magnitude (sign kept) as the peak.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import re
import threading
import time
import urllib.parse
from collections import deque
from collections.abc import Mapping
from concurrent.futures import Future
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cnctwin.edge.listen import check_bindable
from cnctwin.edge.opcua_machinetool import EU_CODES, EU_NAMESPACE, eu_unit_id
from cnctwin.edge.pipeline import Chunk
from cnctwin.exceptions import ConfigError
from cnctwin.recording import nc_program_name

__all__ = [
    "DEFAULT_NAMESPACE",
    "EU_CODES",
    "OpcUaSecurity",
    "OpcUaSink",
    "decimate_peak",
    "eu_unit_id",
    "hash_password",
    "read_users",
    "verify_password",
]

DEFAULT_NAMESPACE = "urn:cnctwin:edge"
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)

def decimate_peak(
    cycles: NDArray[np.int64], values: NDArray[np.float64], *, window_cycles: int
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """Window statistics on the cycle grid: mean and signed peak of ``values``.

    Parameters
    ----------
    cycles : numpy.ndarray of int64
        Increasing cycle numbers (gaps allowed).
    values : numpy.ndarray of float64
        One value per cycle.
    window_cycles : int
        Window length ``m`` [cycles]; window ``k`` holds cycles ``k*m .. k*m + m - 1``.

    Returns
    -------
    window : numpy.ndarray of int64
        Window index ``k`` of each non-empty window, increasing.
    mean : numpy.ndarray of float64
        Mean of the values in the window (NaN ignored).
    peak : numpy.ndarray of float64
        The value of largest magnitude in the window, sign kept (NaN if all NaN).
    last_cycle : numpy.ndarray of int64
        Last cycle present in each window (its time stamps the window).
    """
    if cycles.size == 0:
        e = np.empty(0)
        return np.empty(0, np.int64), e, e, np.empty(0, np.int64)
    w = cycles // window_cycles
    starts = np.flatnonzero(np.concatenate([[True], w[1:] != w[:-1]]))
    ends = np.concatenate([starts[1:], [w.size]])
    ok = np.isfinite(values)
    v0 = np.where(ok, values, 0.0)
    cnt = np.add.reduceat(ok.astype(np.int64), starts)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.add.reduceat(v0, starts) / cnt
    a = np.where(ok, np.abs(values), -1.0)
    peak = np.full(starts.size, np.nan)
    for j, (s, e) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
        if cnt[j]:
            peak[j] = values[s + int(np.argmax(a[s:e]))]
    return w[starts], mean, peak, cycles[ends - 1]


def _dt(t_ns: int) -> datetime:
    return _EPOCH + timedelta(microseconds=int(t_ns) // 1000)


def hash_password(password: str, *, iterations: int = 200_000) -> str:
    """A users-file entry's hash: ``pbkdf2_sha256$ITERATIONS$SALT$HASH`` (hex).

    Parameters
    ----------
    password : str
        The password.
    iterations : int, default 200000
        PBKDF2-SHA256 iterations.

    Returns
    -------
    str
        ``pbkdf2_sha256$iterations$salt$hash`` for the users file.

    Examples
    --------
    >>> h = hash_password("secret", iterations=1000)
    >>> verify_password("secret", h), verify_password("other", h)
    (True, False)
    """
    import hashlib
    import secrets

    salt = secrets.token_bytes(16)
    digest = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), salt, iterations)
    return f"pbkdf2_sha256${iterations}${salt.hex()}${digest.hex()}"


def verify_password(password: str, stored: str) -> bool:
    """Check a password against :func:`hash_password` output (constant time).

    Parameters
    ----------
    password : str
        The password given.
    stored : str
        The stored hash (:func:`hash_password`).

    Returns
    -------
    bool
    """
    import hashlib
    import hmac

    try:
        algo, iterations, salt, digest = stored.split("$")
        if algo != "pbkdf2_sha256":
            return False
        got = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), bytes.fromhex(salt),
                                  int(iterations))
    except ValueError:
        return False
    return hmac.compare_digest(got.hex(), digest)


def read_users(path: str | os.PathLike[str]) -> dict[str, str]:
    """The users file: one ``name:HASH`` line per user (``#`` comments), HASH from
    :func:`hash_password` (``cnctwin edge opcua-user NAME --users FILE`` adds one).

    Parameters
    ----------
    path : str or path-like
        Users file: ``name:hash`` lines (:func:`hash_password`).

    Returns
    -------
    dict
        User name -> stored hash.

    Raises
    ------
    ConfigError
        Missing file, a line that is not ``name:pbkdf2_sha256$...`` (with its number).
    """
    p = Path(path)
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise ConfigError(f"--opcua-users {p}: {exc.strerror or exc}") from None
    users: dict[str, str] = {}
    for n, line in enumerate(lines, 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        name, sep, stored = line.partition(":")
        if not sep or not name or not stored.startswith("pbkdf2_sha256$"):
            raise ConfigError(f"{p} line {n}: expected 'name:pbkdf2_sha256$...' (add users "
                              "with 'cnctwin edge opcua-user NAME --users FILE')")
        users[name.strip()] = stored.strip()
    if not users:
        raise ConfigError(f"{p}: no user; add one with 'cnctwin edge opcua-user NAME --users "
                          f"{p}'")
    return users


@dataclass(frozen=True)
class OpcUaSecurity:
    """Security of the OPC UA server: Basic256Sha256 (Sign, SignAndEncrypt) and users.

    Attributes
    ----------
    cert_file, key_file : Path
        The server's application certificate (DER) and private key (PEM); generated
        (self-signed, one year) when they do not exist.
    users : dict
        User name -> password hash (:func:`read_users`); anonymous access is refused.
    trust_dir : Path, optional
        Client-certificate trust list: ``trust_dir/trusted/`` holds the certificates (DER or
        PEM) of the clients let in; an unknown one is refused and written to
        ``trust_dir/rejected/`` for the administrator to approve (move it to ``trusted/``;
        read at every connect, no restart). None with ``trust_any``: any certificate.
    trust_any : bool, default False
        Accept any client certificate (the user's explicit opt-in, ``--opcua-trust-any``).
    """

    cert_file: Path
    key_file: Path
    users: dict[str, str]
    trust_dir: Path | None = None
    trust_any: bool = False


def _fingerprint(cert: Any) -> str:
    from cryptography.hazmat.primitives import hashes

    return str(cert.fingerprint(hashes.SHA256()).hex())


class TrustList:
    """The client certificates a secured server lets in (:attr:`OpcUaSecurity.trust_dir`).

    Parameters
    ----------
    directory : path
        ``trusted/`` and ``rejected/`` below it (created).
    log : callable, optional
        Called with one line per newly rejected certificate (default: stderr).
    """

    def __init__(self, directory: str | os.PathLike[str], *, log: Any = None) -> None:
        self.dir = Path(directory)
        (self.dir / "trusted").mkdir(parents=True, exist_ok=True)
        (self.dir / "rejected").mkdir(parents=True, exist_ok=True)
        self.log = log
        self.rejected = 0

    def trusted(self) -> set[str]:
        """SHA-256 fingerprints of ``trusted/`` (read anew: approvals need no restart)."""
        from cryptography import x509

        out = set()
        for f in sorted((self.dir / "trusted").iterdir()):
            try:
                data = f.read_bytes()
                cert = (x509.load_pem_x509_certificate(data) if data.lstrip().startswith(b"-----")
                        else x509.load_der_x509_certificate(data))
            except (OSError, ValueError):
                continue  # not a certificate: ignored (the server's log would say which)
            out.add(_fingerprint(cert))
        return out

    async def __call__(self, cert: Any, app_description: Any) -> None:
        """asyncua's certificate validator: refuse what ``trusted/`` does not hold."""
        from asyncua import ua
        from asyncua.common.utils import ServiceError
        from cryptography.hazmat.primitives.serialization import Encoding

        fp = _fingerprint(cert)
        if fp in self.trusted():
            return
        self.rejected += 1
        path = self.dir / "rejected" / f"{fp[:16]}.der"
        if not path.exists():
            path.write_bytes(cert.public_bytes(Encoding.DER))
            try:
                cn = cert.subject.rfc4514_string()
            except Exception:
                cn = "?"
            line = (f"OPC UA: refused the client certificate {cn} (SHA-256 {fp[:16]}...); to "
                    f"trust it, move {path} to {self.dir / 'trusted'}")
            if self.log is not None:
                self.log(line)
            else:
                import sys

                print(line, file=sys.stderr, flush=True)
        raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)


class OpcUaSink:
    """Publish torque, speed, hole records, wear, temperature and alarms over OPC UA.

    Parameters
    ----------
    endpoint : str, default 'opc.tcp://0.0.0.0:4840/cnctwin'
        Endpoint the server listens on (``opc.tcp://host:port/path``; port 0 is not allowed).
    machine : str
        Machine name: the browse name of the machine object.
    publish_hz : float, default 10
        Publish rate of the decimated 500 Hz values on the recording's clock [Hz]; between
        0.01 Hz and the cycle rate.
    namespace_uri : str, default 'urn:cnctwin:edge'
        Namespace of the cnctwin nodes (node ids ``ns=<i>;s=<machine>.<path>``).
    thermal : ToolThermalModel, optional
        Calibrated :class:`cnctwin.usecases.thermal.ToolThermalModel`: ``ToolTipTemperature``
        after each hole from its energy. Without it the variable stays
        ``BadWaitingForInitialData`` (nothing is invented).
    wear : WearEstimator, optional
        Calibrated :class:`cnctwin.usecases.wear.WearEstimator`: ``ToolWear`` from the relative
        increase of the holes' mean torque over the first ``wear_baseline_holes``.
    wear_baseline_holes : int, default 6
        New-tool reference holes for the wear estimate.
    wear_set_size : int or None, default 6
        Set size for :func:`cnctwin.usecases.wear.relative_increase` (``None``: per hole).
    alarm_hold_s : float, default 1.0
        ``Alarm/Active`` stays true this long on the recording clock after the last alarm [s].
    hole_history_s : float, default 300
        Cutting torque kept per cycle to find a hole's peak torque [s].
    start_timeout_s : float, default 60
        Time to wait for the server to listen [s] (building the OPC 40501 address space from
        the NodeSets takes a few seconds, more on a loaded machine).
    max_pending : int, default 64
        Batches of writes queued for the server loop before :meth:`write` waits (back
        pressure instead of dropping values).
    security : OpcUaSecurity, optional
        Basic256Sha256 and users; None serves anonymous clients without security.
    machine_tool : bool, default True
        Also offer the OPC 40501 (Machine Tools) structure built from the official NodeSets
        (:mod:`cnctwin.edge.opcua_machinetool`; about 3 s more at start).
    identification : dict, optional
        The machine file's ``[identification]`` for the OPC 40501 Identification.
    tools : mapping, optional
        T number -> the tool table's entry (``name``, ``life_holes``, ``wear_limit_um``,
        ``wear_um_per_increase``): OPC 40501 ``Equipment/Tools`` with each tool's
        ``ToolLife`` and ``Notification/Prognoses`` with its ``ToolChangePrognosis``, filled
        from the ``tool_life`` results.

    Raises
    ------
    ConfigError
        Bad endpoint or rate, the port in use, or the server not starting.
    """

    name = "opcua"
    needs: tuple[str, ...] = ()  # results and NC events only

    def __init__(self, endpoint: str = "opc.tcp://0.0.0.0:4840/cnctwin", *, machine: str,
                 publish_hz: float = 10.0, namespace_uri: str = DEFAULT_NAMESPACE,
                 thermal: Any = None, wear: Any = None, wear_baseline_holes: int = 6,
                 wear_set_size: int | None = 6, alarm_hold_s: float = 1.0,
                 hole_history_s: float = 300.0, start_timeout_s: float = 60.0,
                 max_pending: int = 64, security: OpcUaSecurity | None = None,
                 machine_tool: bool = True,
                 identification: dict[str, Any] | None = None,
                 tools: Mapping[int, Mapping[str, Any]] | None = None) -> None:
        try:
            import asyncua  # noqa: F401
        except ImportError as exc:  # pragma: no cover - depends on the environment
            raise ConfigError("the OPC UA sink needs asyncua: pip install 'cnctwin[opcua]'") \
                from exc
        if not (isinstance(publish_hz, int | float) and math.isfinite(publish_hz)
                and 0.01 <= publish_hz <= 500.0):
            raise ConfigError(f"publish_hz must be between 0.01 and 500 Hz (the 2 ms cycle "
                              f"rate), not {publish_hz!r}")
        u = urllib.parse.urlsplit(endpoint)
        if u.scheme != "opc.tcp" or not u.hostname:
            raise ConfigError(f"OPC UA endpoint {endpoint!r} must look like "
                              "opc.tcp://0.0.0.0:4840/cnctwin")
        try:
            port = u.port or 4840
        except ValueError as exc:
            raise ConfigError(f"OPC UA endpoint {endpoint!r}: bad port ({exc})") from None
        if port == 0:
            raise ConfigError("give the OPC UA server a fixed port (clients must know it)")
        # before seconds of address-space building
        check_bindable(u.hostname, port, service="OPC UA", option="--opcua")
        self.endpoint, self.host, self.port = endpoint, u.hostname, port
        self.machine = machine or "machine"
        self.publish_hz = float(publish_hz)
        self.namespace_uri = namespace_uri
        self.thermal, self.wear = thermal, wear
        self.wear_baseline_holes, self.wear_set_size = wear_baseline_holes, wear_set_size
        self.alarm_hold_s, self.hole_history_s = alarm_hold_s, hole_history_s
        self.max_pending = max_pending
        self.security = security
        self.machine_tool = machine_tool
        self.identification = dict(identification or {})
        self.tools = {int(k): dict(v) for k, v in (tools or {}).items()}
        self._conditions: Any = None
        self._parts = 0
        self._state = "Initializing"
        self._programmed_rpm = 0.0
        self._spindle_override = math.nan
        self._mirror: dict[Any, list[tuple[Any, Any]]] = {}
        self._program = ""
        self.published = 0
        self.windows = 0
        self.last_error = ""
        self._cycle_time_s = 0.002
        self._window: int | None = None
        self._anchor: tuple[int, int] | None = None  # (cycle, time_ns) of the newest chunk
        self._pend_c: list[NDArray[np.int64]] = []
        self._pend_t: list[NDArray[np.float64]] = []
        self._pend_n: list[NDArray[np.float64]] = []
        self._hist: deque[tuple[NDArray[np.int64], NDArray[np.float64]]] = deque()
        self._hole_torque: list[float] = []
        self._temp: tuple[float, float] | None = None  # (temperature_c, end_s) of last hole
        self._holes = 0
        self._alarms = 0
        self._alarm_until: int | None = None
        self._futures: deque[Future[None]] = deque()
        self._nodes: dict[str, Any] = {}
        self.trust: TrustList | None = None
        self._channel_active = False
        self._mt_ns = 0
        self._power_on_h = -1
        self._started = time.monotonic()
        self._users: _UserManager | None = None
        self._server: Any = None
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._start_error: BaseException | None = None
        self._thread = threading.Thread(target=self._serve, name=f"opcua-{self.machine}",
                                        daemon=True)
        self._thread.start()
        if not self._ready.wait(start_timeout_s):
            self._shutdown()
            raise ConfigError(f"the OPC UA server on {endpoint} did not start within "
                              f"{start_timeout_s:g} s")
        if self._start_error is not None:
            err = self._start_error
            self._shutdown()
            if isinstance(err, OSError):
                raise ConfigError(f"cannot listen on {self.host}:{port} for OPC UA ({err}); "
                                  "the port is in use or not allowed: choose another "
                                  "--opcua port") from err
            raise ConfigError(f"the OPC UA server on {endpoint} failed to start: {err}") \
                from err

    # ---------------------------------------------------------------- server thread
    def _serve(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._start())
        except BaseException as exc:  # reported to the constructor
            self._start_error = exc
            self._ready.set()
            return
        self._ready.set()
        self._loop.run_forever()

    async def _start(self) -> None:
        import logging

        from asyncua import Server, ua

        for name in ("asyncua", "asyncua.server"):  # the server logs every session at INFO
            logging.getLogger(name).setLevel(logging.WARNING)
        sec = self.security
        self._users = _UserManager(sec.users) if sec is not None else None
        server = Server(user_manager=self._users)
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_server_name(f"cnctwin edge ({self.machine})")
        if sec is None:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        else:
            from asyncua.crypto.cert_gen import setup_self_signed_certificate
            from cryptography.x509.oid import ExtendedKeyUsageOID

            uri = f"urn:cnctwin:edge:{self.machine}"
            await server.set_application_uri(uri)
            sec.cert_file.parent.mkdir(parents=True, exist_ok=True)
            await setup_self_signed_certificate(
                sec.key_file, sec.cert_file, uri, self.host if self.host != "0.0.0.0"
                else "localhost", [ExtendedKeyUsageOID.SERVER_AUTH],
                {"commonName": f"cnctwin edge {self.machine}"})
            os.chmod(sec.key_file, 0o600)  # the private key: its owner only
            await server.load_certificate(str(sec.cert_file))
            await server.load_private_key(str(sec.key_file))
            server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_Sign,
                                        ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
            server.set_security_IDs(["Username"])  # no anonymous access
            if not sec.trust_any:
                self.trust = TrustList(sec.trust_dir or sec.cert_file.parent / "opcua-pki")
                server.set_certificate_validator(self.trust)
        idx = await server.register_namespace(self.namespace_uri)
        self._idx = idx
        m = self.machine
        obj = await server.nodes.objects.add_object(ua.NodeId(m, idx), ua.QualifiedName(m, idx))
        nodes = self._nodes

        async def var(parent: Any, path: str, value: Any, vt: Any, unit: str | None = None,
                      description: str = "") -> None:
            name = path.rsplit(".", 1)[-1]
            node = await parent.add_variable(ua.NodeId(f"{m}.{path}", idx),
                                             ua.QualifiedName(name, idx), value,
                                             varianttype=vt)
            if unit is not None:
                eu = ua.EUInformation(NamespaceUri=EU_NAMESPACE,
                                      UnitId=eu_unit_id(EU_CODES[unit]),
                                      DisplayName=ua.LocalizedText(unit),
                                      Description=ua.LocalizedText(unit))
                await node.add_property(ua.NodeId(f"{m}.{path}.EngineeringUnits", idx),
                                        ua.QualifiedName("EngineeringUnits", 0), eu,
                                        datatype=ua.NodeId(ua.ObjectIds.EUInformation))
            if description:
                await node.write_attribute(ua.AttributeIds.Description, ua.DataValue(
                    ua.Variant(ua.LocalizedText(description), ua.VariantType.LocalizedText)))
            nodes[path] = node.nodeid

        D, L, S, B = (ua.VariantType.Double, ua.VariantType.Int64, ua.VariantType.String,
                      ua.VariantType.Boolean)
        nan = float("nan")
        await var(obj, "SpindleSpeed", nan, D, "rpm", "commanded spindle speed, window mean")
        await var(obj, "CuttingTorque", nan, D, "Nm", "estimated cutting torque, window mean")
        await var(obj, "CuttingTorquePeak", nan, D, "Nm",
                  "cutting torque of largest magnitude in the window (sign kept)")
        await var(obj, "Cycle", -1, L, None, "last CYCLE of the published window")
        await var(obj, "ToolWear", nan, D, "um", "flank wear estimate (WearEstimator)")
        await var(obj, "ToolTipTemperature", nan, D, "degC",
                  "tool-tip temperature after the last hole (ToolThermalModel)")
        await var(obj, "HoleCount", 0, L, None, "holes completed")
        hole = await obj.add_object(ua.NodeId(f"{m}.LastHole", idx),
                                    ua.QualifiedName("LastHole", idx))
        for path, vt, unit in _HOLE_VARS:
            init: Any = nan if vt == "d" else ("" if vt == "s" else -1)
            if vt == "t":
                init = _EPOCH
            await var(hole, f"LastHole.{path}", init, {"d": D, "i": L, "s": S,
                                                      "t": ua.VariantType.DateTime}[vt], unit)
        alarm = await obj.add_object(ua.NodeId(f"{m}.Alarm", idx), ua.QualifiedName("Alarm", idx))
        await var(alarm, "Alarm.Active", False, B, None, "an anomaly alarm is active")
        await var(alarm, "Alarm.Message", "", S, None, "text of the last alarm")
        await var(alarm, "Alarm.Detector", "", S)
        await var(alarm, "Alarm.Score", nan, D)
        await var(alarm, "Alarm.Threshold", nan, D)
        await var(alarm, "Alarm.Cycle", -1, L)
        await var(alarm, "Alarm.Count", 0, L)
        # no value before the stream gives one (wear/temperature: only with a calibrated model)
        waiting = ua.DataValue(StatusCode_=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData))
        for path in nodes:
            if path not in ("HoleCount", "Alarm.Active", "Alarm.Count"):
                await server.write_attribute_value(nodes[path], waiting)
        if self.machine_tool:
            from cnctwin.edge.opcua_machinetool import add_machine_tool

            mt = await add_machine_tool(server, m, idx, identification=self.identification,
                                        tools=self.tools)
            same = lambda dv: dv  # noqa: E731

            def inverted(dv: Any) -> Any:
                return ua.DataValue(ua.Variant(not bool(dv.Value.Value), ua.VariantType.Boolean),
                                    SourceTimestamp=dv.SourceTimestamp,
                                    ServerTimestamp=dv.ServerTimestamp)

            # the stack light follows the alarm: red while active, green otherwise
            self._mirror = {
                nodes["SpindleSpeed"]: [(mt["ActualSpeed"], same)],
                nodes["CuttingTorque"]: [(mt["CuttingTorque"], same)],
                nodes["HoleCount"]: [(mt["HoleCount"], same)],
                nodes["Alarm.Active"]: [(mt["AlarmActive"], same), (mt["Light.Red"], same),
                                        (mt["Light.Green"], inverted)],
                nodes["Alarm.Message"]: [(mt["AlarmMessage"], same)],
            }
            for key in ("ChannelState", "FeedOverride", "PowerOnDuration", "Light.Yellow",
                        "Light.Green", "CurrentState", "CurrentState.Id",
                        "CurrentState.Number"):
                nodes[f"MT.{key}"] = mt[key]
            self._mt_ns = int(mt["mt_ns"])
            nodes["MT.ProgramName"] = mt["ProgramName"]
            # IsRotating is the state at the window's end (a spindle that stopped inside the
            # window is not rotating, though the window's mean speed is not zero)
            nodes["MT.IsRotating"] = mt["IsRotating"]
            nodes["MT.PartsProduced"] = mt["PartsProduced"]
            nodes["MT.SpindleOverride"] = mt["SpindleOverride"]
            for key, nid in mt.items():
                if key.startswith("Tool."):
                    nodes[f"MT.{key}"] = nid
            from cnctwin.edge.opcua_alarms import AlarmConditions

            self._conditions = AlarmConditions(server, mt["Messages"], mt["Machine"],
                                               own_idx=idx, mt_idx=self._mt_ns, machine=m)
            await self._conditions.setup()
        await server.start()
        self._server = server

    async def _apply(self, updates: list[tuple[Any, Any]]) -> None:
        for nodeid, dv in updates:
            if nodeid is _RAISE:  # an alarm condition's event: (alarm, text, time)
                if self._conditions is not None:
                    await self._conditions.raise_alarm(*dv)
                continue
            if nodeid is _CLEAR:
                if self._conditions is not None:
                    await self._conditions.clear_all(dv)
                continue
            await self._server.write_attribute_value(nodeid, dv)
            for target, fn in self._mirror.get(nodeid, ()):
                if dv.Value is not None and dv.Value.Value is not None:
                    await self._server.write_attribute_value(target, fn(dv))

    # ---------------------------------------------------------------- values
    def _dv(self, value: Any, vt: str, t_ns: int) -> Any:
        from asyncua import ua

        variant = {"d": ua.VariantType.Double, "i": ua.VariantType.Int64,
                   "u": ua.VariantType.UInt32, "s": ua.VariantType.String,
                   "b": ua.VariantType.Boolean, "t": ua.VariantType.DateTime}[vt]
        if vt == "d":
            value = float("nan") if value is None else float(value)
        elif vt == "i":
            value = -1 if value is None else int(value)
        elif vt == "u":
            value = int(value)
        return ua.DataValue(ua.Variant(value, variant), SourceTimestamp=_dt(t_ns),
                            ServerTimestamp=datetime.now(UTC))

    def _time_ns(self, cycle: int) -> int:
        if self._anchor is None:
            return 0
        c0, t0 = self._anchor
        return t0 + round((cycle - c0) * self._cycle_time_s * 1e9)

    def _submit(self, updates: list[tuple[Any, Any]]) -> None:
        if not updates:
            return
        while self._futures and self._futures[0].done():
            self._check(self._futures.popleft())
        self._futures.append(asyncio.run_coroutine_threadsafe(self._apply(updates), self._loop))
        self.published += len(updates)
        while len(self._futures) > self.max_pending:  # back pressure, nothing dropped
            self._check(self._futures.popleft(), wait=True)

    def _check(self, fut: Future[None], *, wait: bool = False) -> None:
        try:
            fut.result(timeout=30.0 if wait else 0)
        except Exception as exc:
            self.last_error = f"{type(exc).__name__}: {exc}"

    def _windows(self, *, final: bool) -> list[tuple[Any, Any]]:
        if not self._pend_c:
            return []
        cyc = np.concatenate(self._pend_c)
        tau = np.concatenate(self._pend_t)
        spd = np.concatenate(self._pend_n)
        m = self._window or 50
        last_w = int(cyc[-1]) // m
        n_done = cyc.size if final else int(np.searchsorted(cyc, last_w * m))
        keep = slice(n_done, None)
        self._pend_c = [cyc[keep]] if n_done < cyc.size else []
        self._pend_t = [tau[keep]] if n_done < cyc.size else []
        self._pend_n = [spd[keep]] if n_done < cyc.size else []
        if n_done == 0:
            return []
        c, t, n = cyc[:n_done], tau[:n_done], spd[:n_done]
        _, t_mean, t_peak, last = decimate_peak(c, t, window_cycles=m)
        _, n_mean, n_peak, _ = decimate_peak(c, n, window_cycles=m)
        n_end = n[np.minimum(np.searchsorted(c, last), c.size - 1)]
        out: list[tuple[Any, Any]] = []
        nd = self._nodes
        for j in range(last.size):
            ts = self._time_ns(int(last[j]))
            if "MT.IsRotating" in nd:
                out.append((nd["MT.IsRotating"], self._dv(bool(abs(n_end[j]) > 1.0), "b", ts)))
                s_prog = self._programmed_rpm
                # the spindle override: commanded / programmed speed, only at a constant
                # command (a run-up or a new S word is not an override)
                if (s_prog > 0.0 and abs(n_end[j]) > 1.0
                        and abs(abs(n_peak[j]) - abs(n_mean[j])) <= 0.002 * s_prog):
                    pct = round(100.0 * abs(float(n_end[j])) / s_prog, 1)
                    if pct != self._spindle_override:
                        self._spindle_override = pct
                        out.append((nd["MT.SpindleOverride"], self._dv(pct, "d", ts)))
            out += [(nd["SpindleSpeed"], self._dv(n_mean[j], "d", ts)),
                    (nd["CuttingTorque"], self._dv(t_mean[j], "d", ts)),
                    (nd["CuttingTorquePeak"], self._dv(t_peak[j], "d", ts)),
                    (nd["Cycle"], self._dv(int(last[j]), "i", ts))]
            if self._alarm_until is not None and int(last[j]) > self._alarm_until:
                out += self._clear_alarm(ts)
        self.windows += last.size
        return out

    def _hole_peak(self, first: int, last: int) -> float:
        vals = [t[(c >= first) & (c <= last)] for c, t in self._hist]
        v = np.concatenate(vals) if vals else np.empty(0)
        v = v[np.isfinite(v)]
        return float(v[np.argmax(np.abs(v))]) if v.size else float("nan")

    def _hole(self, msg: dict[str, Any]) -> list[tuple[Any, Any]]:
        row = msg["row"]
        ts = self._time_ns(int(msg["cycle"]))
        nd = self._nodes
        self._holes += 1
        peak = self._hole_peak(int(row["cut_start_cycle"]), int(row["cut_end_cycle"]))
        out = [(nd["HoleCount"], self._dv(self._holes, "i", ts))]
        for path, vt, _unit in _HOLE_VARS:
            key = _HOLE_KEYS[path]
            if key == "*peak":
                val: Any = peak
            elif key == "*row":
                val = json.dumps(row, default=str)
            elif key == "start_time":
                st = row.get("start_time")
                val = pd.Timestamp(st).to_pydatetime() if st else _EPOCH
            else:
                val = row.get(key)
            out.append((nd[f"LastHole.{path}"], self._dv(val, vt, ts)))
        energy = row.get("energy_j")
        if self.thermal is not None and energy is not None:
            th = self.thermal
            end_s = float(row["end_s"])
            decay = 0.0 if self._temp is None else math.exp(
                -max(end_s - self._temp[1], 0.0) / th.tau_s)
            prev = th.ambient_c if self._temp is None else self._temp[0]
            temp = th.ambient_c + (prev - th.ambient_c) * decay + float(energy) / th.c_eff_j_per_k
            self._temp = (temp, end_s)
            out.append((nd["ToolTipTemperature"], self._dv(temp, "d", ts)))
        tq = row.get("torque_mean_nm")
        self._hole_torque.append(float("nan") if tq is None else float(tq))
        if self.wear is not None and len(self._hole_torque) >= self.wear_baseline_holes:
            from cnctwin.usecases.wear import relative_increase

            inc = relative_increase(self._hole_torque, baseline=self.wear_baseline_holes,
                                    set_size=self.wear_set_size)
            wear_um = float(self.wear.predict(inc[-1:])[0])
            out.append((nd["ToolWear"], self._dv(wear_um, "d", ts)))
        return out

    def _alarm(self, msg: dict[str, Any]) -> list[tuple[Any, Any]]:
        c = int(msg["cycle"])
        ts = self._time_ns(c)
        nd = self._nodes
        self._alarms += 1
        self._alarm_until = c + round(self.alarm_hold_s / self._cycle_time_s)
        det = str(msg.get("detector", ""))
        score = float(msg.get("score", math.nan))
        thr = float(msg.get("threshold", math.nan))
        text = (f"{det}: {msg['message']} at cycle {c}" if msg.get("message") else
                f"{det}: anomaly score {score:.3g} above {thr:.3g} at cycle {c}"
                + (f" ({msg['time']})" if msg.get("time") else ""))
        return [(nd["Alarm.Active"], self._dv(True, "b", ts)),
                (_RAISE, (dict(msg), text, _dt(ts))),
                (nd["Alarm.Message"], self._dv(text, "s", ts)),
                (nd["Alarm.Detector"], self._dv(det, "s", ts)),
                (nd["Alarm.Score"], self._dv(score, "d", ts)),
                (nd["Alarm.Threshold"], self._dv(thr, "d", ts)),
                (nd["Alarm.Cycle"], self._dv(c, "i", ts)),
                (nd["Alarm.Count"], self._dv(self._alarms, "i", ts))]

    def _clear_alarm(self, ts: int) -> list[tuple[Any, Any]]:
        """The held alarm is over at ``ts``: ``Alarm/Active`` false, conditions inactive."""
        self._alarm_until = None
        return [(self._nodes["Alarm.Active"], self._dv(False, "b", ts)), (_CLEAR, _dt(ts))]

    def _tool_life(self, msg: dict[str, Any]) -> list[tuple[Any, Any]]:
        """OPC 40501 ToolLife and ToolChangePrognosis of the hole's tool."""
        from asyncua import ua

        nd = self._nodes
        k = f"MT.Tool.{int(msg['tool'])}"
        if f"{k}.Usages" not in nd:
            return []
        ts = self._time_ns(int(msg["cycle"]))
        out = [(nd[f"{k}.Usages"], self._dv(msg.get("used_holes"), "d", ts)),
               (nd[f"{k}.LastUsage"], self._dv(_dt(ts), "t", ts))]
        if f"{k}.FlankWear" in nd and msg.get("wear_um") is not None:
            out.append((nd[f"{k}.FlankWear"], self._dv(msg["wear_um"], "d", ts)))
        never = bool(msg.get("never_reaches_limit"))
        if msg.get("remaining_holes") is None and not never:
            return out  # no estimate yet: the nodes keep BadWaitingForInitialData
        beyond = ua.DataValue(StatusCode_=ua.StatusCode(ua.StatusCodes.BadOutOfRange),
                              SourceTimestamp=_dt(ts))

        def holes(key: str) -> float:
            v = msg.get(key)
            return math.inf if v is None else float(v)

        for node, key in ((f"{k}.RemainingUsages", "remaining_holes"),
                          (f"{k}.RemainingUsages.LowerBound", "remaining_low"),
                          (f"{k}.RemainingUsages.UpperBound", "remaining_high"),
                          (f"{k}.RemainingHoles", "remaining_holes")):
            out.append((nd[node], self._dv(holes(key), "d", ts)))
        out.append((nd[f"{k}.RemainingUsages.Basis"], self._dv(str(msg.get("basis", "")),
                                                                "s", ts)))
        # the predicted change: the remaining time from this hole (beyond the forecast's
        # horizon: BadOutOfRange, nothing invented)
        for node, key in ((f"{k}.PredictedTime", "remaining_s"),
                          (f"{k}.PredictedTimeEarliest", "remaining_low_s"),
                          (f"{k}.PredictedTimeLatest", "remaining_high_s")):
            v = msg.get(key)
            if v is None or not math.isfinite(float(v)):
                out.append((nd[node], beyond))
            else:
                out.append((nd[node], self._dv(_dt(ts + round(float(v) * 1e9)), "t", ts)))
        return out

    # ---------------------------------------------------------------- Sink protocol
    def write(self, messages: list[dict[str, Any]], chunk: Chunk | None) -> None:
        prog = self._program_update(chunk)
        if chunk is not None and len(chunk):
            self._cycle_time_s = chunk.cycle_time_s
            self._anchor = (chunk.first_cycle, int(chunk.time_ns[0]))
            if self._window is None:
                m = round(1.0 / (self.publish_hz * chunk.cycle_time_s))
                if m < 1:
                    raise ConfigError(f"publish_hz {self.publish_hz:g} is above the cycle "
                                      f"rate {1 / chunk.cycle_time_s:g} Hz")
                self._window = m
        updates: list[tuple[Any, Any]] = list(prog) + self._machine_tool_state(messages, chunk)
        for msg in messages:
            kind = msg["kind"]
            if kind == "torque":
                c0 = int(msg["first_cycle"])
                cyc = np.arange(c0, c0 + int(msg["n"]), dtype=np.int64)
                tau = np.asarray(msg["torque_nm"], dtype=np.float64)
                self._pend_c.append(cyc)
                self._pend_t.append(tau)
                self._pend_n.append(np.asarray(msg["speed_rpm"], dtype=np.float64))
                self._hist.append((cyc, tau))
                updates += self._windows(final=False)
            elif kind == "hole":
                updates += self._hole(msg)
            elif kind == "alarm":
                updates += self._alarm(msg)
            elif kind == "tool_life":
                updates += self._tool_life(msg)
        if (chunk is not None and len(chunk) and self._alarm_until is not None
                and int(chunk.cycles[-1]) > self._alarm_until + (self._window or 50)):
            # the hold is over and no torque window closed it (no torque in the stream)
            updates += self._clear_alarm(self._time_ns(self._alarm_until))
        if self._hist:
            horizon = int(self._hist[-1][0][-1]) - round(self.hole_history_s
                                                          / self._cycle_time_s)
            while len(self._hist) > 1 and int(self._hist[0][0][-1]) < horizon:
                self._hist.popleft()
        self._submit(updates)

    def _machine_tool_state(self, messages: list[dict[str, Any]], chunk: Chunk | None
                            ) -> list[tuple[Any, Any]]:
        """OPC 40501 channel and machine state: ChannelState Active once data flows (with the
        green light), the feed override the adaptive feed requests, the yellow light on its
        feed-hold (overload) request, PowerOnDuration [h] since the runtime started."""
        from asyncua import ua

        nd = self._nodes
        if "MT.ChannelState" not in nd:
            return []
        out: list[tuple[Any, Any]] = []
        t = int(chunk.time_ns[-1]) if chunk is not None and len(chunk) else time.time_ns()
        if chunk is not None and len(chunk) and not self._channel_active:
            self._channel_active = True
            out.append((nd["MT.ChannelState"],
                        ua.DataValue(ua.Variant(0, ua.VariantType.Int32))))  # Active
            out.append((nd["MT.Light.Green"], self._dv(True, "b", t)))
            out += self._set_state("Running")
        out += self._nc_state(chunk, t)
        hours = int((time.monotonic() - self._started) // 3600)
        if hours != self._power_on_h:
            self._power_on_h = hours
            out.append((nd["MT.PowerOnDuration"],
                        ua.DataValue(ua.Variant(hours, ua.VariantType.UInt32))))
        for msg in messages:
            if msg.get("kind") == "override" and msg.get("override_pct") is not None:
                out.append((nd["MT.FeedOverride"], self._dv(msg["override_pct"], "d", t)))
            elif (msg.get("kind") == "alarm" and msg.get("detector") == "AdaptiveFeed"
                  and msg.get("fault") == "overload"):
                out.append((nd["MT.Light.Yellow"], self._dv(True, "b", t)))
                out += self._set_state("Interrupted")  # the control holds the feed
            elif (msg.get("kind") == "alarm" and msg.get("detector") == "AdaptiveFeed"
                  and msg.get("fault") == "breakage"):
                out += self._set_state("Aborted")  # the control stops the program
        return out

    def _set_state(self, name: str) -> list[tuple[Any, Any]]:
        """The active program's state machine to ``name`` (nothing if it is there)."""
        from cnctwin.edge.opcua_machinetool import program_state

        if name == self._state:
            return []
        self._state = name
        return [(self._nodes[f"MT.{key}"], dv)
                for key, dv in program_state(name, self._mt_ns).items()]

    def _nc_state(self, chunk: Chunk | None, t: int) -> list[tuple[Any, Any]]:
        """Program transitions from the NC events: M30/M2 ends the program (a part
        produced), M0/M1 interrupts it, a program call or any later block runs it again."""
        if chunk is None or chunk.events.empty:
            return []
        ev = chunk.events
        out: list[tuple[Any, Any]] = []
        kinds = [str(k) for k in ev["kind"].tolist()]
        codes = ([c if isinstance(c, str) else "" for c in ev["gcode"].tolist()]
                 if "gcode" in ev else [""] * len(kinds))
        for kind, code in zip(kinds, codes, strict=True):
            upper = code.upper()
            words = set(_M_WORD.findall(upper))
            speed = _S_WORD.search(upper)
            if speed is not None:
                self._programmed_rpm = float(speed.group(1))
            if kind == "block" and words & {"M30", "M2", "M02"}:
                out += self._set_state("Ended")
                self._parts += 1
                out.append((self._nodes["MT.PartsProduced"], self._dv(self._parts, "u", t)))
            elif kind == "block" and words & {"M0", "M00", "M1", "M01"}:
                out += self._set_state("Interrupted")
            elif kind == "call" or (kind == "block" and code.strip()
                                    and self._state in ("Ended", "Interrupted")):
                out += self._set_state("Running")
        return out

    def _program_update(self, chunk: Chunk | None) -> list[tuple[Any, Any]]:
        """``Production/ActiveProgram/Name`` of the OPC 40501 object from the NC call events."""
        if chunk is None or "MT.ProgramName" not in self._nodes or chunk.events.empty:
            return []
        ev = chunk.events
        calls = ev[ev["kind"].astype(str) == "call"]
        if "path" not in calls:
            return []
        # the main program as the operator knows it (PART.MPF), not a cycle it calls
        names = [n for n in map(nc_program_name, calls["path"].tolist()) if n is not None]
        if not names:
            return []
        name = names[-1]
        if name == self._program:
            return []
        self._program = name
        return [(self._nodes["MT.ProgramName"], self._dv(name, "s", int(chunk.time_ns[-1])))]

    def status(self) -> dict[str, Any]:
        return {"endpoint": self.endpoint, "published": self.published,
                "windows": self.windows, "holes": self._holes, "alarms": self._alarms,
                "last_error": self.last_error,
                "refused_logins": self._users.refused if self._users is not None else 0,
                "refused_certificates": self.trust.rejected if self.trust is not None else 0}

    def flush(self, *, timeout_s: float = 30.0) -> None:
        """Wait until every write handed to the server is applied."""
        while self._futures:
            fut = self._futures.popleft()
            try:
                fut.result(timeout=timeout_s)
            except Exception as exc:
                self.last_error = f"{type(exc).__name__}: {exc}"

    def finish(self) -> None:
        """Publish the open window (end of stream) and wait for the server to apply it."""
        self._submit(self._windows(final=True))
        self.flush()

    def close(self) -> None:
        """Publish what is open, then stop the server and its thread; with subscriptions the
        server stays up for one more second so that the final values (the ended program,
        the last tool life) reach the subscribed clients."""
        if self._server is not None:
            self.finish()
            subs = getattr(getattr(getattr(self._server, "iserver", None),
                                   "subscription_service", None), "subscriptions", None)
            if subs:
                time.sleep(1.0)
        self._shutdown()

    def _shutdown(self) -> None:
        loop = self._loop
        if self._server is not None and loop.is_running():
            with contextlib.suppress(Exception):  # already stopping
                asyncio.run_coroutine_threadsafe(self._server.stop(), loop).result(10)
            self._server = None
        if loop.is_running():
            loop.call_soon_threadsafe(loop.stop)
        self._thread.join(timeout=10)
        if not loop.is_running() and not loop.is_closed():
            loop.close()


_M_WORD = re.compile(r"\bM\d+\b")
_S_WORD = re.compile(r"(?<![A-Z_])S=?(\d+(?:\.\d*)?)\b")  # S2400, S=2400; not SPOS
_RAISE = object()  # an update that raises an alarm condition (not a node)
_CLEAR = object()  # an update that clears the active alarm conditions

# LastHole variables: (browse name, value kind d/i/s/t, unit) and the hole-row key they show
_HOLE_VARS: tuple[tuple[str, str, str | None], ...] = (
    ("HoleNumber", "i", None), ("Tool", "i", None), ("StartTime", "t", None),
    ("Depth", "d", "mm"), ("TorqueMean", "d", "Nm"), ("TorquePeak", "d", "Nm"),
    ("TorqueEnergy", "d", "J"), ("CurrentPeak", "d", "A"), ("SpindleSpeed", "d", "rpm"),
    ("Feed", "d", "mm/min"), ("CutDuration", "d", "s"), ("X", "d", "mm"), ("Y", "d", "mm"),
    ("DeviationXMaxAbs", "d", "mm"), ("DeviationYMaxAbs", "d", "mm"),
    ("DeviationZMaxAbs", "d", "mm"), ("DeviationZRms", "d", "mm"), ("Record", "s", None),
)
_HOLE_KEYS: dict[str, str] = {
    "HoleNumber": "hole", "Tool": "tool", "StartTime": "start_time", "Depth": "depth_mm",
    "TorqueMean": "torque_mean_nm", "TorquePeak": "*peak", "TorqueEnergy": "energy_j",
    "CurrentPeak": "current_peak_a", "SpindleSpeed": "speed_rpm", "Feed": "feed_mm_min",
    "CutDuration": "cut_duration_s", "X": "x_mm", "Y": "y_mm",
    "DeviationXMaxAbs": "dev_x_maxabs_mm", "DeviationYMaxAbs": "dev_y_maxabs_mm",
    "DeviationZMaxAbs": "dev_z_maxabs_mm", "DeviationZRms": "dev_z_rms_mm", "Record": "*row",
}


class _UserManager:
    """asyncua user manager over a users file: a known name with its password, or nobody.

    An unknown user costs the same key derivation as a wrong password (a dummy hash with the
    users' iteration count), so the time of a refusal does not tell which names exist.
    After ``max_failures`` refusals of one name within ``window_s`` that name is refused
    without a check for ``lockout_s`` (throttling a password guess), counted in
    :attr:`refused`.
    """

    def __init__(self, users: dict[str, str], *, max_failures: int = 5, window_s: float = 60.0,
                 lockout_s: float = 30.0) -> None:
        self.users = users
        iterations = 200_000
        for stored in users.values():
            try:
                iterations = int(stored.split("$")[1])
                break
            except (IndexError, ValueError):
                continue
        self._dummy = hash_password(_random_text(), iterations=iterations)
        self.max_failures, self.window_s, self.lockout_s = max_failures, window_s, lockout_s
        self._failures: dict[str, list[float]] = {}
        self._locked: dict[str, float] = {}
        self.refused = 0

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> Any:
        import time

        from asyncua.server.user_managers import User, UserRole

        name = username or ""
        now = time.monotonic()
        if self._locked.get(name, 0.0) > now:
            self.refused += 1
            return None
        stored = self.users.get(name)
        ok = verify_password(password or "", stored if stored is not None else self._dummy)
        if stored is None or password is None or not ok:
            self.refused += 1
            recent = [t for t in self._failures.get(name, []) if now - t < self.window_s]
            recent.append(now)
            self._failures[name] = recent
            if len(recent) >= self.max_failures:
                self._locked[name] = now + self.lockout_s
                self._failures[name] = []
            return None
        self._failures.pop(name, None)
        return User(role=UserRole.User, name=username)


def _random_text() -> str:
    """A random text (the dummy password of :class:`_UserManager`)."""
    import secrets

    return secrets.token_hex(16)

"""``cnctwin record opc.tcp://HOST:PORT --nodes nodes.toml --out FILE``: record the control's
OPC UA variables (:mod:`cnctwin.iotools.opcua_client`) into a recording file.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from cnctwin.exceptions import ConfigError

__all__ = ["client_options", "register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``record`` to the ``cnctwin`` command line.

    Parameters
    ----------
    sub : argparse._SubParsersAction[argparse.ArgumentParser]
        The ``cnctwin`` subcommand parsers; the module adds its commands to them.
    """
    p = sub.add_parser(
        "record", help="record the control's OPC UA variables into a recording file",
        description="Subscribe to the variables of a node file on an OPC UA server (SINUMERIK "
        "Access MyMachine / OPC UA) and write them as a recording: one row per source "
        "timestamp the server delivers (about 100 ms on SINUMERIK), a lost connection as a "
        "recorded gap. Ctrl-C or --duration-s ends it.")
    p.add_argument("url", metavar="opc.tcp://HOST:PORT", help="the OPC UA server")
    p.add_argument("--nodes", type=Path, required=True, metavar="FILE",
                   help="node file: [signals] column = node id, [text], [units] "
                   "(docs/opcua-client.md)")
    p.add_argument("--out", type=Path, required=True, metavar="FILE",
                   help="recording to write (.parquet directory, .json Capture4Analysis, .csv)")
    p.add_argument("--duration-s", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--interval-s", type=float, default=0.1,
                   help="publishing interval asked of the server (default 0.1 s)")
    p.add_argument("--machine", default="", help="machine name of the recording")
    add_client_options(p)
    p.set_defaults(func=_cmd_record)


def add_client_options(p: argparse.ArgumentParser, *, password_file: bool = True) -> None:
    """The OPC UA client's security and user options (``password_file=False`` where the
    command has its own ``--password-file`` already, e.g. ``edge run``)."""
    p.add_argument("--security", default="None",
                   choices=("None", "Basic256Sha256_Sign", "Basic256Sha256_SignAndEncrypt"),
                   help="OPC UA security policy and mode (default None)")
    p.add_argument("--client-cert", type=Path, metavar="FILE",
                   help="client certificate (DER/PEM) for a secured channel")
    p.add_argument("--client-key", type=Path, metavar="FILE", help="its private key (PEM)")
    p.add_argument("--server-cert", type=Path, metavar="FILE",
                   help="the server certificate to trust")
    p.add_argument("--user", metavar="NAME", help="OPC UA user name")
    if password_file:
        p.add_argument("--password-file", type=Path, metavar="FILE",
                       help="file holding the password (or CNCTWIN_OPCUA_PASSWORD); never on "
                       "the command line")


def client_options(args: argparse.Namespace) -> object:
    """:class:`~cnctwin.iotools.opcua_client.OpcUaClientOptions` from the options.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options (``--security``, ``--user``, ``--password-file``, certificates).

    Returns
    -------
    OpcUaClientOptions
    """
    from cnctwin.iotools.opcua_client import OpcUaClientOptions

    password = None
    if args.password_file is not None:
        try:
            password = args.password_file.read_text(encoding="utf-8").strip()
        except OSError as exc:
            raise ConfigError(f"--password-file {args.password_file}: "
                              f"{exc.strerror or exc}") from None
    password = password or os.environ.get("CNCTWIN_OPCUA_PASSWORD") or None
    if args.user and password is None:
        raise ConfigError(f"--user {args.user} needs a password: --password-file FILE or "
                          "CNCTWIN_OPCUA_PASSWORD")
    return OpcUaClientOptions(
        security=args.security, cert_file=str(args.client_cert) if args.client_cert else None,
        key_file=str(args.client_key) if args.client_key else None,
        server_cert_file=str(args.server_cert) if args.server_cert else None,
        user=args.user, password=password)


def _cmd_record(args: argparse.Namespace) -> int:
    import time

    from cnctwin.iotools.opcua_client import OpcUaRecorder, read_node_map

    nodes = read_node_map(args.nodes)
    rec = OpcUaRecorder(args.url, nodes, options=client_options(args),  # type: ignore[arg-type]
                        interval_s=args.interval_s, machine=args.machine).start()
    print(f"recording {len(nodes.all)} variables from {args.url} (Ctrl-C ends)",
          file=sys.stderr)
    t0 = time.monotonic()
    try:
        while args.duration_s is None or time.monotonic() - t0 < args.duration_s:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        rec.stop()
    out = rec.recording()
    path = _write(out, args.out)
    print(f"{path}: {out.n_cycles} rows, {len(out.meta.gaps)} gaps, "
          f"{rec.reconnects} reconnects")
    return 0


def _write(rec: object, out: Path) -> Path:
    from cnctwin.iotools import write_capture4analysis, write_csv, write_parquet

    suffix = out.suffix.lower()
    if suffix == ".json":
        return write_capture4analysis(rec, out)[0]  # type: ignore[arg-type]
    if suffix == ".csv":
        return Path(write_csv(rec, out))  # type: ignore[arg-type]
    return write_parquet(rec, out)  # type: ignore[arg-type]

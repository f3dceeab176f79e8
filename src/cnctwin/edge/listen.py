"""Checks shared by every server cnctwin starts (dashboard, OPC UA, MTConnect, SHDR): can this
address be listened on, and does it face the network."""

from __future__ import annotations

import ipaddress
import socket

from cnctwin.exceptions import ConfigError

__all__ = ["check_bindable", "is_loopback"]


def check_bindable(host: str, port: int, *, service: str, option: str) -> None:
    """Raise at once if ``host:port`` cannot be listened on (before a slow start-up).

    Parameters
    ----------
    host, port : str, int
        The address.
    service : str
        What would listen there (for the message: ``"OPC UA"``, ``"the dashboard"``).
    option : str
        The option that chooses the port (``--port``, ``--opcua``).

    Raises
    ------
    ConfigError
        The host is not an address of this machine, or the port is in use or not allowed.
    """
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise ConfigError(f"{option} {host}: not an address of this machine ({exc})") from None
    family, _, _, _, addr = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind(addr)
        except OSError as exc:
            raise ConfigError(f"cannot listen on {host}:{port} for {service} "
                              f"({exc.strerror or exc}); the port is in use or not allowed: "
                              f"choose another with {option}") from None


def is_loopback(host: str) -> bool:
    """True if every address ``host`` resolves to is a loopback address (``localhost``,
    ``127.0.0.1``, ``::1``): a server there does not face the network.

    Parameters
    ----------
    host : str
        Host name or address (``127.0.0.1``, ``::1``, ``localhost``).

    Returns
    -------
    bool
        True when only this machine can reach it.
    """
    if host in ("localhost", ""):
        return True
    try:
        return all(ipaddress.ip_address(info[4][0]).is_loopback
                   for info in socket.getaddrinfo(host, None))
    except (OSError, ValueError):
        return False

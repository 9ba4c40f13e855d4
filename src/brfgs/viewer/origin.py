"""Which web pages may open the viewer's websocket (the pure rule; :mod:`.serve` applies it).

A browser sends the page's origin (``scheme://host:port``) with every websocket handshake, and the
``Host`` it addressed. Any web page the user visits could otherwise open ``ws://localhost:PORT``
and read or drive the viewer (cross-site websocket hijacking), also through a domain name that an
attacker points at 127.0.0.1 (DNS rebinding). A handshake is accepted when

- its ``Origin`` is one of the ``--allow-origin`` values (a reverse proxy's address), or
- the page is the viewer's own: ``Origin`` is ``http://`` + the ``Host`` header, and that host
  is an IP address, a loopback name (``localhost``), this machine's name, or the ``--host`` name.

Handshakes without an ``Origin`` header are refused (browsers always send one).
"""

from __future__ import annotations

import ipaddress
import socket
from dataclasses import dataclass
from urllib.parse import urlsplit

from brfgs.errors import UserError

__all__ = ["OriginPolicy", "normalise_origin", "own_host_names"]

_DEFAULT_PORTS = {"http": 80, "https": 443}
LOOPBACK_NAMES = ("localhost", "localhost.localdomain", "ip6-localhost")


def normalise_origin(text: str) -> str:
    """``scheme://host[:port]`` in lower case without the scheme's default port; UserError naming
    ``--allow-origin`` when ``text`` is not an http(s) origin (no path, query or user part)."""
    t = str(text).strip()
    bad = UserError(f"{t!r} is not a web origin; write scheme://host[:port], e.g. https://viewer.example.org",
                    field="--allow-origin")
    try:
        u = urlsplit(t)
        port = u.port
    except ValueError:
        raise bad from None
    if u.scheme.lower() not in _DEFAULT_PORTS or not u.hostname or u.username or u.password or u.query \
            or u.fragment or u.path not in ("", "/"):
        raise bad
    scheme, host = u.scheme.lower(), u.hostname.lower()
    host = f"[{host}]" if ":" in host else host
    return f"{scheme}://{host}" + ("" if port in (None, _DEFAULT_PORTS[scheme]) else f":{port}")


def _host_and_port(netloc: str, scheme: str) -> tuple[str, int] | None:
    """(lower-case host without brackets, port) of a ``Host`` header; None when malformed."""
    try:
        u = urlsplit(f"{scheme}://{netloc.strip()}")
        port = u.port
    except ValueError:
        return None
    if not u.hostname or u.username or u.path or u.query or u.fragment:
        return None
    return u.hostname.lower(), port if port is not None else _DEFAULT_PORTS[scheme]


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def own_host_names(listen_host: str) -> tuple[str, ...]:
    """Host names under which this machine serves its own page: loopback names, the machine's name
    and fully qualified name, and ``listen_host`` when it is a name."""
    names = {*LOOPBACK_NAMES, socket.gethostname().lower(), socket.getfqdn().lower()}
    if listen_host and not _is_ip(listen_host):
        names.add(listen_host.lower())
    return tuple(sorted(n for n in names if n))


@dataclass(frozen=True)
class OriginPolicy:
    """The handshake rule (module docstring): ``allowed`` origins (normalised) and the host names
    that count as this machine's."""

    allowed: tuple[str, ...] = ()
    host_names: tuple[str, ...] = LOOPBACK_NAMES

    @classmethod
    def for_server(cls, listen_host: str, allow_origin: tuple[str, ...] = ()) -> "OriginPolicy":
        return cls(tuple(normalise_origin(o) for o in allow_origin), own_host_names(listen_host))

    def refusal(self, origin: str | None, host_header: str | None) -> str | None:
        """Why a handshake with these headers is refused, or None when it is accepted."""
        if not origin:
            return "no Origin header (only the viewer's page may connect)"
        try:
            o = normalise_origin(origin)
        except UserError:
            return f"malformed Origin {origin!r}"
        if o in self.allowed:
            return None
        scheme = o.split("://", 1)[0]
        page = _host_and_port(o.split("://", 1)[1], scheme)
        addressed = _host_and_port(host_header or "", scheme)
        if scheme != "http" or page is None or addressed is None or page != addressed:  # the viewer serves http
            return (f"origin {o} is not the viewer's page (Host {host_header!r}); a proxy's address can be "
                    "allowed with --allow-origin")
        host = page[0]
        if _is_ip(host.strip("[]")) or host in self.host_names:
            return None
        return f"origin {o}: {host!r} is not a name of this machine; allow it with --allow-origin {o}"

"""The viewer's listening address, checked before viser starts (viser itself is not needed here)."""

from __future__ import annotations

import socket

from brfgs.errors import UserError

__all__ = ["check_port_free"]


def check_port_free(host: str, port: int) -> None:
    """UserError naming ``--port`` when ``host:port`` cannot be bound (busy or not allowed)."""
    if not (0 < int(port) < 65536):
        raise UserError(f"port must be 1..65535, got {port}", field="--port")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, int(port)))
        except OSError as exc:
            raise UserError(f"cannot listen on {host}:{port} ({exc.strerror}); pick another --port",
                            field="--port") from None

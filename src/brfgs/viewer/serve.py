"""The viewer's viser server with the handshake rule of :mod:`.origin` in place.

viser opens its server with ``websockets.asyncio.server.serve`` (static files and the websocket on
one port) and offers no hook for the handshake. :func:`start_server` therefore starts viser while
that function is wrapped: the wrapper puts a check in front of viser's own ``process_request``
that answers a websocket handshake from a foreign ``Origin`` with HTTP 403, before viser sees the
connection (nothing of the page or the model is sent). The wrapper is in place only while viser
starts its server, and :func:`start_server` refuses to serve when viser did not go through it.
"""

from __future__ import annotations

import contextlib
import http
import inspect
import sys
import threading

import viser
import websockets.asyncio.server as ws_server

from brfgs.viewer.origin import OriginPolicy

__all__ = ["start_server", "checked_handshakes"]

_PATCH_LOCK = threading.Lock()


def _refuse_foreign(policy: OriginPolicy, inner, log):
    """``process_request`` for websockets: 403 for a websocket handshake the policy refuses, else ``inner``'s."""

    async def process_request(connection, request):
        if request.headers.get("Upgrade", "").lower() == "websocket":
            why = policy.refusal(request.headers.get("Origin"), request.headers.get("Host"))
            if why is not None:
                log(why)
                return connection.respond(http.HTTPStatus.FORBIDDEN, f"brfgs view: connection refused: {why}\n")
        if inner is None:
            return None
        out = inner(connection, request)
        return await out if inspect.isawaitable(out) else out

    return process_request


@contextlib.contextmanager
def checked_handshakes(policy: OriginPolicy, used: list, log):
    """While the block runs, every ``websockets.asyncio.server.serve`` call gets the origin check
    (``used`` records each call)."""
    with _PATCH_LOCK:
        original = ws_server.serve

        def serve(*args, process_request=None, **kwargs):
            used.append(True)
            return original(*args, process_request=_refuse_foreign(policy, process_request, log), **kwargs)

        ws_server.serve = serve
        try:
            yield
        finally:
            ws_server.serve = original


def _log_refusal(why: str) -> None:
    print(f"brfgs view: refused a connection: {why}", file=sys.stderr, flush=True)


def start_server(host: str, port: int, allow_origin: tuple[str, ...], label: str, log=_log_refusal
                 ) -> viser.ViserServer:
    """A running :class:`viser.ViserServer` on ``host:port`` whose websocket accepts only the
    viewer's own page and the ``allow_origin`` origins (:class:`OriginPolicy`)."""
    used: list = []
    with checked_handshakes(OriginPolicy.for_server(host, allow_origin), used, log):
        server = viser.ViserServer(host=host, port=port, label=label, verbose=False)
    if not used:
        server.stop()
        raise RuntimeError("this viser version does not start its server through websockets.asyncio.server.serve, "
                           "so the viewer cannot check the origin of connections; install the viser version that "
                           "brfgs lists (pip install 'brfgs[viewer]')")
    return server

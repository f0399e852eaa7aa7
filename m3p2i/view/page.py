"""The page's web server: viser (an optional dependency), bound to loopback unless asked, with
an origin guard so that a page of another site cannot drive the world through it."""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass

log = logging.getLogger("m3p2i.view")


def import_viser():
    """viser, or an ImportError telling how to install it."""
    try:
        import viser
    except ImportError as exc:
        raise ImportError(
            "the browser view needs viser: pip install 'm3p2i[view]' (or pip install viser)"
        ) from exc
    return viser


_LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})


@dataclass(frozen=True)
class OriginPolicy:
    """Which pages may open the view's websocket; :meth:`refusal` says why one may not."""

    public: bool = False
    names: frozenset[str] = frozenset()  # with ``public``: this machine's names

    @classmethod
    def for_bind(cls, bind: str) -> OriginPolicy:
        import socket as _socket

        if bind in ("127.0.0.1", "localhost", "::1"):
            return cls()
        names = {_socket.gethostname(), _socket.getfqdn(), bind}
        return cls(public=True, names=frozenset(n.lower() for n in names if n))

    def refusal(self, origin: str | None, host: str | None) -> str | None:
        if origin is None:
            return None
        if not host or origin.lower() != f"http://{host.lower()}":
            return f"origin {origin!r} is not this page's (http://{host})"
        name = host.lower().rsplit(":", 1)[0] if not host.endswith("]") else host.lower()
        name = name.strip("[]")
        if name in _LOOPBACK_NAMES:
            return None
        if self.public and (name in self.names or _is_ip(name)):
            return None
        return f"host {name!r} is not loopback" + (
            "" if not self.public else ", an IP address or this machine's name"
        )


def _is_ip(name: str) -> bool:
    import ipaddress

    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


_guard_lock = threading.Lock()


_guard_next: OriginPolicy | None = None  # the policy of the ViserServer being constructed


_guard_applied = False


class _Proxy:
    """A module with some attributes replaced (the rest read from the real one)."""

    def __init__(self, real, **override):
        self._real, self._override = real, override

    def __getattr__(self, name: str):
        return self._override[name] if name in self._override else getattr(self._real, name)


def _install_origin_guard() -> None:
    """Wrap viser's call of websockets' ``serve`` (only viser's: its module's ``websockets`` is
    replaced by a proxy) so that the server it starts checks :data:`_guard_next`'s policy in
    ``process_request``, ahead of viser's own (which serves the page's files)."""
    import http

    try:
        from viser.infra import _infra

        real = _infra.websockets
        serve = real.asyncio.server.serve
    except (ImportError, AttributeError):  # another viser: viser_server says so
        return
    if isinstance(real, _Proxy):
        return

    def guarded_serve(*args, process_request=None, **kwargs):
        global _guard_applied
        policy = _guard_next
        if policy is None:
            return serve(*args, process_request=process_request, **kwargs)

        def check(connection, request):
            if request.headers.get("Upgrade", "").lower() == "websocket":
                origins, hosts = (request.headers.get_all(h) for h in ("Origin", "Host"))
                why = (
                    "several Origin or Host headers"
                    if len(origins) > 1 or len(hosts) != 1
                    else policy.refusal(origins[0] if origins else None, hosts[0])
                )
                if why is not None:
                    log.warning("refused a websocket from %s: %s", connection.remote_address, why)
                    return connection.respond(http.HTTPStatus.FORBIDDEN, f"refused: {why}\n")
            return None if process_request is None else process_request(connection, request)

        _guard_applied = True
        return serve(*args, process_request=check, **kwargs)

    _infra.websockets = _Proxy(
        real, asyncio=_Proxy(real.asyncio, server=_Proxy(real.asyncio.server, serve=guarded_serve))
    )


def viser_server(host: str, port: int, label: str):
    """A started ViserServer whose websocket accepts only its own pages
    (:class:`OriginPolicy`); ImportError when viser is missing or its server cannot be guarded."""
    global _guard_next, _guard_applied
    viser = import_viser()
    with _guard_lock:
        _install_origin_guard()
        _guard_next, _guard_applied = OriginPolicy.for_bind(host), False
        try:
            server = viser.ViserServer(host=host, port=port, label=label, verbose=False)
        finally:
            _guard_next, applied = None, _guard_applied
    if not applied:
        server.stop()
        raise ImportError(
            f"viser {getattr(viser, '__version__', '?')} starts its web server in "
            f"a way m3p2i cannot guard (the websocket's Origin check): use the "
            f"viser version of m3p2i[view]"
        )
    return server

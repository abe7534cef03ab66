"""A local HTTP server on the standard library (``ThreadingHTTPServer``) that answers only its own page.

A page served on a lab's machine is a door, so every request is checked before it is routed: its Host must be one
of the server's own names with its port (a DNS-rebinding page names another), and an Origin, when the browser
sends one, must be the server's own (a page elsewhere must not drive it). A POST must say how long its body is, at
most ``body_limit`` bytes, and carry JSON (so a cross-site form cannot send it without a preflight, which is never
answered). The paths are a fixed table (the site's ``get`` and ``post``): nothing is read from the disk by a path a
request names. Every answer forbids framing, sniffing and scripts from elsewhere.
"""

from __future__ import annotations

import ipaddress
import json
import socket
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Protocol
from urllib.parse import parse_qs, urlsplit

from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.stopping import stop_on_signals

BODY_LIMIT = 1 << 20  # bytes: a recording's corrections are a few KB
HEADERS = {
    "Content-Security-Policy": "default-src 'none'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
                               "img-src 'self' data:; connect-src 'self'; base-uri 'none'; form-action 'none'; "
                               "frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}


@dataclass(frozen=True)
class Reply:
    """An answer: status, content type and body."""

    status: int
    content_type: str
    body: bytes

    @classmethod
    def json(cls, value: Any, status: int = HTTPStatus.OK) -> Reply:
        return cls(status, "application/json", json.dumps(value).encode())

    @classmethod
    def error(cls, status: int, message: str) -> Reply:
        return cls.json({"error": message}, status)


class Site(Protocol):
    """What a guarded server serves: a GET by path and query, a POST by path and its JSON body; None: no such
    path (404)."""

    def get(self, path: str, query: Mapping[str, list[str]]) -> Reply | None: ...

    def post(self, path: str, body: Any) -> Reply | None: ...


def own_names(host: str) -> set[str]:
    """The host names a browser may use for a server bound to ``host``."""
    names = {host.strip("[]").lower()}
    if _loopback(host):
        names |= {"localhost", "127.0.0.1", "::1"}
    elif host in ("0.0.0.0", "::", ""):  # every interface: the machine's own names and addresses
        names |= {"localhost", "127.0.0.1", "::1", socket.gethostname().lower(), socket.getfqdn().lower()}
        try:
            names |= set(socket.gethostbyname_ex(socket.gethostname())[2])
        except OSError:
            pass
    return names


def _loopback(host: str) -> bool:
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def reachable_from(host: str) -> str | None:
    """Who else can open a page served on ``host``, in words; None where only this machine can (loopback)."""
    if _loopback(host):
        return None
    if host.strip("[]") in ("0.0.0.0", "::", ""):
        names = sorted(own_names(host) - {"localhost", "127.0.0.1", "::1", "0.0.0.0", "::", ""})
        shown = f" ({', '.join(names[:4])})" if names else ""
        return f"any machine that can reach this one at any of its addresses{shown}"
    return f"any machine that can reach {host}"


def split_host(value: str) -> tuple[str, int | None]:
    """``name:port`` (``[v6]:port``) as (name, port); a bad port: -1."""
    value = value.strip().lower()
    name, _, port = value.rpartition(":") if not value.endswith("]") else (value, "", "")
    if not name:
        return value.strip("[]"), None
    return name.strip("[]"), int(port) if port.isdigit() else -1


class GuardedServer(ThreadingHTTPServer):
    """Serves ``site`` at (host, port); port 0: a free one. ``bound``: the address it listens on."""

    daemon_threads = True
    allow_reuse_address = True  # SO_REUSEADDR: the port again at once after a stop; on Linux a port another socket
    # listens on is still refused (that takes SO_REUSEPORT, never set)

    def __init__(self, host: str, port: int, site: Site, body_limit: int = BODY_LIMIT):
        self.site, self.body_limit, self.names = site, body_limit, own_names(host)
        self.lock = threading.Lock()  # one request at a time reaches the site
        if ":" in host.strip("[]"):
            self.address_family = socket.AF_INET6
        try:
            super().__init__((host.strip("[]"), port), GuardedHandler)
        except OSError as error:
            raise BadInput(f"--host {host} --port {port}: cannot listen there ({error.strerror or error}); "
                           "choose another --port (0: any free one)") from error
        self.port = self.server_address[1]

    def url(self, host: str) -> str:
        name = "127.0.0.1" if host in ("0.0.0.0", "") else ("[::1]" if host == "::" else host)
        return f"http://{name}:{self.port}/"

    def allowed_host(self, value: str | None) -> bool:
        if not value:
            return False
        name, port = split_host(value)
        return name in self.names and (port if port is not None else 80) == self.port  # a browser leaves out :80

    def allowed_origin(self, value: str | None) -> bool:
        if value is None:
            return True  # a same-origin GET, or a client that is no browser
        parts = urlsplit(value)
        return parts.scheme == "http" and self.allowed_host(parts.netloc)


class GuardedHandler(BaseHTTPRequestHandler):
    """Checks Host and Origin, bounds the body, routes through the site's table."""

    server: GuardedServer
    server_version = "mlnseq"
    sys_version = ""

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the base class's name
        pass  # the page's requests are not the user's business; refusals answer the browser

    def _refused(self) -> Reply | None:
        if not self.server.allowed_host(self.headers.get("Host")):
            return Reply.error(HTTPStatus.FORBIDDEN, "this server answers only its own address (Host)")
        if not self.server.allowed_origin(self.headers.get("Origin")):
            return Reply.error(HTTPStatus.FORBIDDEN, "requests from another site are refused (Origin)")
        return None

    def do_GET(self) -> None:  # noqa: N802 - the base class's name
        self._answer(lambda path, query: self.server.site.get(path, query))

    def do_POST(self) -> None:  # noqa: N802
        self._answer(self._post)

    def _post(self, path: str, query: Mapping[str, list[str]]) -> Reply | None:
        length = self.headers.get("Content-Length")
        if length is None or not length.isdigit():
            self.close_connection = True
            return Reply.error(HTTPStatus.LENGTH_REQUIRED, "a body needs its Content-Length")
        if int(length) > self.server.body_limit:
            self.close_connection = True  # its body is never read
            return Reply.error(HTTPStatus.REQUEST_ENTITY_TOO_LARGE,
                               f"a body of {int(length):,} bytes; at most {self.server.body_limit:,}")
        kind = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
        raw = self.rfile.read(int(length))
        if kind != "application/json":
            return Reply.error(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, "a body must be application/json")
        try:
            body = json.loads(raw)
        except (ValueError, UnicodeDecodeError):
            return Reply.error(HTTPStatus.BAD_REQUEST, "the body is not JSON")
        return self.server.site.post(path, body)

    def _answer(self, route: Callable[[str, Mapping[str, list[str]]], Reply | None]) -> None:
        reply = self._refused()
        if reply is None:
            parts = urlsplit(self.path)
            with self.server.lock:
                try:
                    reply = route(parts.path, parse_qs(parts.query))
                except BadInput as error:
                    reply = Reply.error(HTTPStatus.BAD_REQUEST, str(error))
            reply = reply or Reply.error(HTTPStatus.NOT_FOUND, "no such page")
        self.send_response(reply.status)
        for name, value in {**HEADERS, "Content-Type": reply.content_type,
                            "Content-Length": str(len(reply.body))}.items():
            self.send_header(name, value)
        if self.close_connection:
            self.send_header("Connection", "close")
        self.end_headers()
        self.wfile.write(reply.body)


def serve(server: GuardedServer) -> str:
    """Serve until SIGINT or SIGTERM (from the main thread), then stop answering, close the socket and return the
    signal's name; outside the main thread, until ``server.shutdown()``."""
    with stop_on_signals() as heard:
        worker = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.2}, daemon=True)
        worker.start()
        try:
            if not heard.listening:  # not the main thread: the caller stops it
                worker.join()
            while heard.listening and not heard.stop.wait(0.5):
                pass
        finally:
            server.shutdown()
            server.server_close()
    return heard.signal or "shutdown"

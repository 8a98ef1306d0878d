"""The HTTP(S) server of ``ltm capture``: the routes of the two phone pages over a
:class:`~ltmstore.capture.live.LiveSession`.

The standard library's :class:`~http.server.ThreadingHTTPServer` (as ``ltm view``). On loopback
it serves plain HTTP (browsers treat loopback as a secure context); on any other interface HTTPS
with a self-signed certificate made for the session (``cryptography``), since phones give a page
camera access only over a secure connection. Every request must carry the session token
(``?token=T`` or the ``X-Ltm-Token`` header), otherwise it gets 403 and nothing else.

Routes (JSON answers, errors ``{"error": "one line"}`` with a 4xx status):
``GET /a``, ``GET /b`` (the pages), ``GET /static/NAME`` (their assets, from
``ltmstore/capture/live_pages/``), ``GET /api/config``, ``GET /api/state``,
``POST /api/a/frame`` (one JPEG, header ``X-Frame-Time``: the live feedback),
``POST /api/a/chunk?index=N`` and ``POST /api/b/chunk?index=N`` (a piece of the phone's
recording, header ``X-Mime-Type``), ``POST /api/a/finish?chunks=N`` and
``POST /api/b/finish?chunks=N``, ``POST /api/finish`` (the server stops after answering it).
An unexpected failure in a route answers 500 with its one line (the page shows it).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import ipaddress
import json
import os
import socket
import ssl
import sys
import tempfile
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import parse_qs, urlsplit

from ltmstore.capture.live import LiveSession, RequestError
from ltmstore.core.errors import LtmError

PAGES = {"/a": "phone_a.html", "/b": "camera_b.html"}
SHUTDOWN_DELAY_S = 1.0  # after POST /api/finish
MAX_FRAME_BYTES = 16 * 2**20
MAX_CHUNK_BYTES = 256 * 2**20
TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
         ".css": "text/css; charset=utf-8", ".png": "image/png", ".svg": "image/svg+xml",
         ".json": "application/json", ".ico": "image/x-icon"}


def page_file(name: str) -> bytes | None:
    """A file of ``ltmstore/capture/live_pages/`` (None if absent or not a plain name)."""
    if not name or "/" in name or "\\" in name or name.startswith("."):
        return None
    entry = resources.files("ltmstore.capture").joinpath("live_pages", name)
    return entry.read_bytes() if entry.is_file() else None


class Handler(BaseHTTPRequestHandler):
    """One request: token check, then the route."""

    server: LiveServer
    protocol_version = "HTTP/1.1"
    timeout = 60  # a client that stops sending mid-request frees its thread
    disable_nagle_algorithm = True  # small answers go out at once (no 40 ms delayed-ACK wait)

    def log_message(self, format, *args) -> None:  # noqa: A002 - quiet: the terminal shows state
        pass

    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        self._dispatch("GET")

    def do_POST(self) -> None:  # noqa: N802
        self._dispatch("POST")

    def do_PUT(self) -> None:  # noqa: N802 - no such route, but the token is checked first
        self._dispatch("PUT")

    def do_DELETE(self) -> None:  # noqa: N802
        self._dispatch("DELETE")

    def do_PATCH(self) -> None:  # noqa: N802
        self._dispatch("PATCH")

    def do_OPTIONS(self) -> None:  # noqa: N802
        self._dispatch("OPTIONS")

    def do_HEAD(self) -> None:  # noqa: N802 - headers only: 403 without the token, else 405
        query = {k: v[-1] for k, v in parse_qs(urlsplit(self.path).query).items()}
        allowed = self.server.session.check_token(query.get("token")
                                                  or self.headers.get("X-Ltm-Token"))
        self.send_response(HTTPStatus.METHOD_NOT_ALLOWED if allowed else HTTPStatus.FORBIDDEN)
        self.send_header("Content-Length", "0")
        self.end_headers()

    def _dispatch(self, method: str) -> None:
        url = urlsplit(self.path)
        query = {k: v[-1] for k, v in parse_qs(url.query).items()}
        session = self.server.session
        if not session.check_token(query.get("token") or self.headers.get("X-Ltm-Token")):
            self._drain()
            return self._json(HTTPStatus.FORBIDDEN, {"error": "forbidden"})
        try:
            route = ROUTES.get((method, url.path))
            if route is not None:
                return route(self, query)
            if method == "GET":
                name = PAGES.get(url.path) or (url.path[len("/static/"):]
                                               if url.path.startswith("/static/") else "")
                body = page_file(name)
                if body is not None:
                    kind = TYPES.get(os.path.splitext(name)[1], "application/octet-stream")
                    return self._send(HTTPStatus.OK, body, kind)
            self._drain()
            self._json(HTTPStatus.NOT_FOUND, {"error": f"no route {method} {url.path}"})
        except RequestError as exc:
            self._json(HTTPStatus(exc.status), {"error": str(exc)})
        except LtmError as exc:
            self._json(HTTPStatus.INTERNAL_SERVER_ERROR, {"error": str(exc)})
        except Exception as exc:  # noqa: BLE001 - tell the page rather than drop the connection
            self.close_connection = True
            self._json(HTTPStatus.INTERNAL_SERVER_ERROR,
                       {"error": f"server error: {type(exc).__name__}: {exc}"})
            raise

    # -- routes --------------------------------------------------------------------------------

    def config(self, query: dict) -> None:
        self._json(HTTPStatus.OK, self.server.session.config.to_json())

    def state(self, query: dict) -> None:
        self._json(HTTPStatus.OK, self.server.session.state())

    def a_frame(self, query: dict) -> None:
        body = self._body(MAX_FRAME_BYTES)
        t = _number(self.headers.get("X-Frame-Time"), "X-Frame-Time header")
        self._json(HTTPStatus.OK, self.server.session.add_frame(body, t))

    def a_chunk(self, query: dict) -> None:
        self._chunk("a", query)

    def b_chunk(self, query: dict) -> None:
        self._chunk("b", query)

    def _chunk(self, who: str, query: dict) -> None:
        index = _integer(query.get("index"), "index")
        body = self._body(MAX_CHUNK_BYTES)
        self._json(HTTPStatus.OK, self.server.session.add_chunk(
            who, index, body, self.headers.get("X-Mime-Type")))

    def a_finish(self, query: dict) -> None:
        self._drain()
        self._json(HTTPStatus.OK, self.server.session.finish_a(
            _integer(query.get("chunks"), "chunks")))

    def b_finish(self, query: dict) -> None:
        self._drain()
        self._json(HTTPStatus.OK, self.server.session.finish_b(
            _integer(query.get("chunks"), "chunks")))

    def finish_capture(self, query: dict) -> None:
        """``POST /api/finish`` (not ``finish``: that name is the request handler's own,
        which the base class calls after every request to flush and close the stream)."""
        self._drain()
        self._json(HTTPStatus.OK, self.server.session.finish())
        # a moment for the pages' last /api/state, then serve_forever returns
        threading.Timer(SHUTDOWN_DELAY_S, self.server.shutdown).start()

    # -- plumbing ------------------------------------------------------------------------------

    def _length(self) -> int:
        try:
            return max(int(self.headers.get("Content-Length") or 0), 0)
        except ValueError:
            raise RequestError("Content-Length must be a whole number of bytes") from None

    def _body(self, limit: int) -> bytes:
        length = self._length()
        if length > limit:
            self.close_connection = True
            raise RequestError(f"body of {length} bytes is larger than the {limit} allowed", 413)
        body = self.rfile.read(length)
        if len(body) != length:
            self.close_connection = True
            raise RequestError(f"body ended after {len(body)} of {length} bytes")
        return body

    def _drain(self) -> None:
        """Read a body no route wants (keeps the connection usable), or close it if large."""
        length = self._length() if self.command not in ("GET", "HEAD") else 0
        if length > MAX_FRAME_BYTES:
            self.close_connection = True
        elif length:
            self.rfile.read(length)

    def _json(self, status: HTTPStatus, value: dict) -> None:
        self._send(status, json.dumps(value, allow_nan=False).encode(), "application/json")

    def _send(self, status: HTTPStatus, body: bytes, kind: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("Referrer-Policy", "no-referrer")  # the token stays in the address
        self.end_headers()
        self.wfile.write(body)


ROUTES = {("GET", "/api/config"): Handler.config, ("GET", "/api/state"): Handler.state,
          ("POST", "/api/a/frame"): Handler.a_frame, ("POST", "/api/a/chunk"): Handler.a_chunk,
          ("POST", "/api/a/finish"): Handler.a_finish, ("POST", "/api/b/chunk"): Handler.b_chunk,
          ("POST", "/api/b/finish"): Handler.b_finish,
          ("POST", "/api/finish"): Handler.finish_capture}


def _number(text: str | None, what: str) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        raise RequestError(f"{what} {text!r} must be a number of seconds") from None


def _integer(text: str | None, what: str) -> int:
    try:
        return int(text)
    except (TypeError, ValueError):
        raise RequestError(f"{what}={text!r} must be a whole number") from None


class LiveServer(ThreadingHTTPServer):
    """The capture's server, holding the :class:`LiveSession`; HTTPS when ``tls`` is given."""

    daemon_threads = True
    request_queue_size = 64  # a burst of the pages' requests waits (the default 5 resets them)

    def __init__(self, session: LiveSession, host: str, port: int,
                 tls: ssl.SSLContext | None = None, fingerprint: str | None = None) -> None:
        self.session = session
        self.host = host
        self.fingerprint = fingerprint
        self.address_family = socket.AF_INET6 if ":" in host else socket.AF_INET
        address = "127.0.0.1" if host == "localhost" else host
        super().__init__((address, port), Handler)
        if tls is not None:  # the handshake runs in the request's thread, not in accept()
            self.socket = tls.wrap_socket(self.socket, server_side=True,
                                          do_handshake_on_connect=False)
        self.scheme = "https" if tls is not None else "http"

    def url(self, path: str = "/") -> str:
        """Address of ``path`` with the token."""
        port = self.server_address[1]
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme}://{host}:{port}{path}?token={self.session.token}"

    def handle_error(self, request, client_address) -> None:
        """Quiet about a phone that drops its connection mid-request (it sends again); any
        other error is reported as the standard library does."""
        if not isinstance(sys.exc_info()[1], (ConnectionError, TimeoutError, ssl.SSLError)):
            super().handle_error(request, client_address)


def session_certificate(host: str) -> tuple[ssl.SSLContext, str]:
    """A self-signed certificate for ``host`` (one day), as a server TLS context, and its
    SHA-256 fingerprint (``AB:CD:...``). The key never touches the disk longer than loading it
    takes (a private temporary folder)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"ltm capture {host}")])
    try:
        alt = [x509.IPAddress(ipaddress.ip_address(host))]
    except ValueError:
        alt = [x509.DNSName(host)]
    now = dt.datetime.now(dt.UTC)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=1))
            .add_extension(x509.SubjectAlternativeName(alt), critical=False)
            .sign(key, hashes.SHA256()))
    der = cert.public_bytes(serialization.Encoding.DER)
    fingerprint = ":".join(f"{b:02X}" for b in hashlib.sha256(der).digest())
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    with tempfile.TemporaryDirectory(prefix="ltm-capture-") as tmp:
        cert_path, key_path = os.path.join(tmp, "cert.pem"), os.path.join(tmp, "key.pem")
        with open(cert_path, "wb") as fh:
            fh.write(cert.public_bytes(serialization.Encoding.PEM))
        fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as fh:
            fh.write(key.private_bytes(serialization.Encoding.PEM,
                                       serialization.PrivateFormat.PKCS8,
                                       serialization.NoEncryption()))
        context.load_cert_chain(cert_path, key_path)
    return context, fingerprint


def is_loopback(host: str) -> bool:
    """``localhost`` or a loopback address (127.0.0.0/8, ::1): browsers' secure context."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def make_server(session: LiveSession, *, host: str = "127.0.0.1", port: int = 0,
                https: bool | None = None) -> LiveServer:
    """Start ``session`` (folder marked incomplete) and bind its server.

    Parameters
    ----------
    session : LiveSession
    host : str
        Interface to listen on; loopback serves HTTP, any other HTTPS.
    port : int
        0: a free port.
    https : bool, optional
        Force HTTPS (or HTTP) whatever the host.

    Raises
    ------
    LtmError
        A port out of range or in use, a host that cannot be bound, a folder that is not new.
    """
    if not 0 <= port <= 65535:
        raise LtmError(f"port {port} must lie in 0-65535 (0: a free port)")
    tls, fingerprint = (None, None)
    if https if https is not None else not is_loopback(host):
        tls, fingerprint = session_certificate(host)
    try:
        server = LiveServer(session, host, port, tls, fingerprint)
    except (OSError, UnicodeError) as exc:
        raise LtmError(f"cannot listen on {host} port {port}: "
                       f"{getattr(exc, 'strerror', None) or exc}") from exc
    try:
        session.start()
    except LtmError:
        server.server_close()
        raise
    return server

"""``ltm view``: an interactive page on 127.0.0.1 where the light follows the pointer.

The server (the standard library's :class:`~http.server.ThreadingHTTPServer`) opens the store
once and keeps it open; the page (static HTML and JavaScript shipped in ``share/viewer/``) asks
it for relit images, one request in flight at a time:

``GET /info``
    The store's shape, light kind, plane or disk, view plane and overlays, as JSON.
``GET /relight?u=U&v=V[&radius=R][&view=P,Q][&ev=E|auto][&region=X,Y,W,H][&size=WS,HS][&preview=1]``
    A PNG of the store relit by :func:`ltmstore.stages.relight.relight`: of the whole image,
    or of ``region`` (pixels from the top left) only, area-averaged in linear light to
    ``size`` (at most the region's own; default it); the page asks for what is on the screen
    at the screen's resolution, so a huge store is read where it is shown. ``preview=1``
    relights every n-th pixel only where the size is at most half the region (``X-Ltm-Preview:
    1`` says it did): the page shows it first, then asks the same without, with ``yield=1``:
    such a request is given up between two bands of rows once a newer ``/relight`` arrives
    (409), so the pointer's next light does not wait for a whole picture nobody wants. ``U, V`` in
    ``[-1, 1]`` are the pointer over the image (``U`` right, ``V`` up): for a near-light store the
    plane rectangle spans the image, for a far-light store the unit disk of ``(lx, ly)`` does
    (a direction). ``R`` (same units, 0: a point light) makes an area light: a uniform disk on the
    plane (or a cone of directions) of the same total power. ``ev=E`` (default 0) is the
    capture's exposure ``E`` stops brighter, as ``ltm relight --ev E`` writes it (photometric:
    the page starts there); ``ev=auto`` scales each image so that its brightest 0.5 % clip, as
    ``ltm relight --exposure auto`` (of the region asked: what is on the screen). An ``E``
    that is not a finite number of stops within :data:`~ltmstore.core.transfer.EV_LIMIT`, a
    region outside the image or a size larger than it are answered 400. The light used is in the
    ``X-Ltm-Light`` header (JSON).
``GET /expected_error.png``
    The store's ``expected_error (y, x)`` as a colour map (transparent where unknown).
``GET /iiif/{light}/info.json``, ``GET /iiif/{light}/{region}/{size}/0/default.png|jpg``
    Each light an IIIF Image API 3.0 image service (:mod:`ltmstore.share.iiif`): ``{light}``
    is ``R,S`` (``ltm relight --light``) or ``LX,LY,LZ`` (``--direction``), with ``;ev=E``
    and, 6D, ``;view=P,Q``; any tiled IIIF viewer shows the store relit there. A tile reads
    and relights its region only (:mod:`ltmstore.share.relit_tiles`) and equals that region of
    ``ltm relight``'s image (a reduced size: area-averaged in linear light). A malformed or
    out-of-range light, region or size is answered 400, a feature not implemented (upscaling,
    rotation, another quality or format) 501. No CORS header is sent: a viewer on another
    origin cannot read the store's images.

Only loopback addresses are served (:data:`LOOPBACK`), and requests whose ``Host`` header names
another machine are refused (DNS rebinding).

Each connection has its own daemon thread; a client that sends half a request and stays silent
frees its thread after :data:`REQUEST_TIMEOUT_S`, one that hangs up is forgotten without a word
(no traceback), and closing the server never waits for a request in flight, so Ctrl-C stops it
within the half second :meth:`~socketserver.BaseServer.serve_forever` polls at. Up to
:data:`BACKLOG` connections wait to be accepted (the standard library's 5 reset a burst of
requests).
"""

from __future__ import annotations

import io
import json
import os
import socket
import sys
import threading
import time
import warnings
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qs, unquote, urlsplit

import numpy as np
import xarray as xr

from ltmstore.core.dims import EXPECTED_ERROR, LTM, P, Plane, Q
from ltmstore.core.errors import LtmError, LtmWarning
from ltmstore.core.lights import FAR, light_kind
from ltmstore.core.store import open_store
from ltmstore.core.transfer import AUTO, CAPTURE, check_exposure, encode_images
from ltmstore.share import iiif
from ltmstore.share.relit_tiles import RelitTiles, Superseded, area_resample, region_values
from ltmstore.stages.by_light import by_light_name
from ltmstore.stages.relight import disk_light, relight

LOOPBACK = ("127.0.0.1", "localhost", "::1")
STATIC = {"/": ("index.html", "text/html; charset=utf-8"),
          "/viewer.js": ("viewer.js", "text/javascript; charset=utf-8"),
          "/viewer.css": ("viewer.css", "text/css; charset=utf-8")}
START_CHECK = 64  # ltm view's start relights a square of this side at the centre: fails early
DISK_EDGE = 0.98  # far-light stores: (lx, ly) kept inside this radius (a light above the horizon)
CACHED_BYTES = 32 * 2**20  # variables up to this size are held in memory
FAR_AREA_SAMPLES = 5  # directions per axis of a far-light area light's square grid
REQUEST_TIMEOUT_S = 10.0  # a client silent this long mid-request (or between two) is dropped
BACKLOG = 1024  # connections waiting to be accepted (the kernel caps it at net.core.somaxconn)
CLIENT_GONE = (ConnectionError, TimeoutError)  # BrokenPipe, ConnectionReset, ... : it left


def check_host(host: str) -> str:
    """``host`` when it is a loopback name or address, else a :class:`LtmError`."""
    if host not in LOOPBACK:
        raise LtmError(f"host {host!r} is not a loopback address; ltm view serves only "
                       f"{', '.join(LOOPBACK)}")
    return host


@dataclass(frozen=True)
class Light:
    """One request's light: the pointer ``(u, v)``, the light ``(r, s)`` it maps to, the area
    radius in store units (0: a point light) and the view ``(p, q)`` (6D stores)."""

    u: float
    v: float
    r: float
    s: float
    radius: float = 0.0
    view: tuple[float, float] | None = None

    def to_json(self) -> dict:
        return {"u": self.u, "v": self.v, "r": self.r, "s": self.s, "radius": self.radius,
                "view": None if self.view is None else list(self.view)}


class Viewer:
    """A store opened once for the page: maps the pointer to lights and renders PNGs.

    Parameters
    ----------
    store : path-like
        A reconstructed store (near or far lights, 4D or 6D).
    """

    def __init__(self, store: str | os.PathLike) -> None:
        self.path = Path(store)
        ds = open_store(store)
        if LTM not in ds:
            raise LtmError(f"store {str(store)!r} has no complete ltm; run `ltm reconstruct` "
                           "first")
        self.far = light_kind(ds.attrs.get("acquisition", {})) == FAR
        if by_light_name(LTM) not in ds and not self.far:  # a far store relights from frames
            warnings.warn(f"{store}: no light-major copy of ltm, so each new light reads every "
                          "pixel tile; `ltm compact STORE` adds it", LtmWarning, stacklevel=2)
        self.ds = in_memory(ds)
        acq = self.ds.attrs.get("acquisition", {})
        self.transfer = acq.get("transfer", "srgb")
        ltm = self.ds[LTM]
        r, s = ltm["r"].values, ltm["s"].values
        self.plane = (Plane.from_json(acq["plane"]) if "plane" in acq and not self.far else
                      Plane(r=(float(r[0]), float(r[-1])), s=(float(s[0]), float(s[-1])),
                            height=1.0))
        self.views = ({d: [float(ltm[d].values[0]), float(ltm[d].values[-1])] for d in (P, Q)}
                      if P in ltm.dims else None)
        if self.views and acq.get("view_plane"):
            self.views = {d: [float(v) for v in acq["view_plane"][d]] for d in (P, Q)}
        self._lock = threading.Lock()
        self._newest = 0  # the number of the newest /relight request
        self._ticket_lock = threading.Lock()
        self.tiles = RelitTiles(self.ds, self.transfer, self._lock)
        self.width, self.height = self.tiles.width, self.tiles.height
        w, h = min(START_CHECK, self.width), min(START_CHECK, self.height)
        centre = ((self.width - w) // 2, (self.height - h) // 2, w, h)
        self.render_linear(self.light_at(0.0, 0.0), centre)  # reads the store: fails early

    # -- the pointer and the light ---------------------------------------------------------

    def light_at(self, u: float, v: float, radius: float = 0.0,
                 view: tuple[float, float] | None = None) -> Light:
        """The light under the pointer ``(u, v)`` in ``[-1, 1]`` (right, up), ``radius`` in the
        same units."""
        u, v = float(np.clip(u, -1, 1)), float(np.clip(v, -1, 1))
        if self.far:
            norm = max(np.hypot(u, v) / DISK_EDGE, 1.0)
            r, s = u / norm, v / norm
            radius = float(np.clip(radius, 0, 1))
        else:
            (r0, r1), (s0, s1) = self.plane.r, self.plane.s
            r, s = r0 + (u + 1) / 2 * (r1 - r0), s0 + (v + 1) / 2 * (s1 - s0)
            radius = float(np.clip(radius, 0, 1)) * (r1 - r0) / 2
        if self.views is not None and view is None:
            view = tuple(float(np.mean(self.views[d])) for d in (P, Q))
        return Light(u, v, float(r), float(s), radius, view)

    def _far_area(self, light: Light) -> np.ndarray:
        """A far-light store's area light: directions ``(lx, ly)`` over a disk, inside the unit
        disk."""
        grid = np.linspace(-1, 1, FAR_AREA_SAMPLES)
        du, dv = np.meshgrid(grid, grid)
        keep = np.hypot(du, dv) <= 1
        pts = np.column_stack([light.r + light.radius * du[keep],
                               light.s + light.radius * dv[keep]])
        norm = np.maximum(np.hypot(pts[:, 0], pts[:, 1]) / DISK_EDGE, 1.0)
        return pts / norm[:, None]

    # -- images ----------------------------------------------------------------------------

    def ticket(self) -> int:
        """A number for a new request, the newest from now on (see :meth:`render_linear`)."""
        with self._ticket_lock:
            self._newest += 1
            return self._newest

    def render_linear(self, light: Light, region: tuple[int, int, int, int] | None = None,
                      size: tuple[int, int] | None = None, preview: bool = False,
                      ticket: int | None = None) -> tuple[np.ndarray, list[str], bool]:
        """The linear image ``(y, x[, color])`` under ``light``, the warnings it raised and
        whether it is a preview: of ``region (x, y, w, h)`` (default: the whole image) at
        ``size (w, h)`` (default: the region's), computed a band of rows at a time and
        area-averaged; with ``preview``, where the region holds at least twice the size's
        pixels along each axis, relit at every ``step``-th pixel only (point samples, about
        ``step**2`` times cheaper) and then averaged to ``size``. With a ``ticket``
        (:meth:`ticket`), :class:`~ltmstore.share.relit_tiles.Superseded` is raised between
        two bands once a newer ticket was taken."""
        x, y, w, h = region or (0, 0, self.width, self.height)
        size = size or (w, h)
        step = min(w // size[0], h // size[1]) if preview else 1
        ds = self.ds if step < 2 else self.ds.isel(x=slice(x + step // 2, x + w, step),
                                                   y=slice(y + step // 2, y + h, step))
        with self._lock, warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            if self.far and light.radius > 0:
                image = relight(ds, self._far_area(light)).mean("light")
            else:
                lights = ([(light.r, light.s)] if self.far or light.radius == 0 else
                          disk_light(ds[LTM], (light.r, light.s), light.radius))
                image = relight(ds, lights, view=light.view).sum("light")
            image = image.transpose("y", "x", ...)
            newer = None if ticket is None else (lambda: self._newest != ticket)
            values = (region_values(image, (x, y, w, h), size, newer) if step < 2 else
                      area_resample(image.values, width=size[0], height=size[1]))
        return values, sorted({str(w.message) for w in caught}), step > 1

    def render_png(self, light: Light, ev: float | None = 0.0,
                   region: tuple[int, int, int, int] | None = None,
                   size: tuple[int, int] | None = None, preview: bool = False,
                   ticket: int | None = None) -> tuple[bytes, list[str], bool]:
        """PNG bytes of ``light`` as ``ltm relight`` writes them: at the capture's exposure
        ``ev`` stops brighter (default 0: photometric), or with ``ev`` None scaled so that the
        image's brightest 0.5 % clip (``--exposure auto``); ``region``, ``size``, ``preview``
        and ``ticket`` as :meth:`render_linear` takes them; the warnings and whether it is a
        preview."""
        exposure, stops = check_exposure(AUTO if ev is None else CAPTURE,
                                         0.0 if ev is None else ev)
        values, notes, previewed = self.render_linear(light, region, size, preview, ticket)
        code = encode_images(values[None], self.transfer, exposure=exposure, ev=stops)[0]
        return png(code), notes, previewed

    def error_png(self) -> tuple[bytes, float]:
        """The ``expected_error`` map as an RGBA PNG (magma, 0 to its 99th percentile) and the
        value of the brightest colour."""
        from matplotlib import colormaps

        err = np.asarray(self.ds[EXPECTED_ERROR].values, dtype=float)
        finite = np.isfinite(err)
        top = float(np.percentile(err[finite], 99)) if finite.any() else 1.0
        top = top if top > 0 else 1.0
        rgba = colormaps["magma"](np.clip(np.nan_to_num(err) / top, 0, 1), bytes=True)
        rgba[..., 3] = np.where(finite, 255, 0)
        return png(rgba), top

    def iiif_answer(self, path: str, base: str) -> tuple[HTTPStatus, bytes, str, dict]:
        """The answer to ``/iiif/...`` (``path``): status, body, content type and headers;
        ``base`` is ``http://host:port`` as the client named it.

        Raises
        ------
        LtmError
            A malformed or out-of-range light, region or size (400).
        ltmstore.share.iiif.Unsupported
            A valid request for a feature not implemented (501).
        """
        raw = path[len(iiif.PREFIX):].split("/")
        params = [unquote(p) for p in raw]
        if len(params) == 1 and params[0]:
            return (HTTPStatus.SEE_OTHER, b"", "text/plain",
                    {"Location": f"{base}{iiif.PREFIX}{raw[0]}/info.json"})
        if len(params) == 2 and params[1] == "info.json":
            with self._lock:
                _, notes = self.tiles.image(iiif.parse_light(params[0]))  # checks the light
            body = iiif.info(f"{base}{iiif.PREFIX}{raw[0]}", self.tiles.width, self.tiles.height)
            return HTTPStatus.OK, json.dumps(body).encode(), "application/json", _noted(notes)
        if len(params) == 5:
            request = iiif.parse_request(params, self.tiles.width, self.tiles.height)
            body, notes = self.tiles.tile(request)
            return HTTPStatus.OK, body, iiif.FORMATS[request.fmt], _noted(notes)
        return HTTPStatus.NOT_FOUND, b"not found", "text/plain", {}

    def info(self) -> dict:
        """What the page needs to know about the store."""
        ltm = self.ds[LTM]
        return {
            "store": self.path.name, "far": self.far,
            "width": self.width, "height": self.height,
            "lattice": [int(ltm.sizes["r"]), int(ltm.sizes["s"])],
            "plane": {"r": list(self.plane.r), "s": list(self.plane.s),
                      "height": self.plane.height},
            "unit": "lx, ly (direction)" if self.far else self.ds.attrs.get(
                "acquisition", {}).get("plane", {}).get("unit", "m"),
            "views": self.views, "expected_error": EXPECTED_ERROR in self.ds,
        }


def _noted(notes: list[str]) -> dict:
    """The ``X-Ltm-Warning`` header of relight's first warning (none without one)."""
    return {"X-Ltm-Warning": notes[0].encode("ascii", "replace").decode()} if notes else {}


def in_memory(ds: xr.Dataset, limit: int = CACHED_BYTES) -> xr.Dataset:
    """``ds`` with its variables of at most ``limit`` bytes read into memory (poses, chroma,
    maps), so that each image reads only the large arrays' chunks it needs."""
    small = [name for name, var in ds.data_vars.items() if var.nbytes <= limit]
    return ds.assign({name: ds[name].load() for name in small})


def png(code: np.ndarray) -> bytes:
    """A fast (lightly compressed) PNG of 8-bit ``code`` (gray, RGB or RGBA)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(code)).save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def parse_query(viewer: Viewer, query: str) -> tuple[Light, float | None, tuple | None,
                                                      tuple | None, bool, bool]:
    """The light, exposure, region, size, preview and yield flags of a ``/relight`` query
    string."""
    q = {k: v[-1] for k, v in parse_qs(query).items()}
    u, = iiif.finite_numbers(q.get("u", "0"), "u", (1,))
    v, = iiif.finite_numbers(q.get("v", "0"), "v", (1,))
    radius, = iiif.finite_numbers(q.get("radius", "0"), "radius", (1,))
    view = iiif.finite_numbers(q["view"], "view", (2,)) if "view" in q and viewer.views else None
    ev = None if q.get("ev") == AUTO else iiif.finite_numbers(q.get("ev", "0"), "ev", (1,))[0]
    if ev is not None:
        check_exposure(CAPTURE, ev)  # a finite number of stops within EV_LIMIT, else a 400
    region = size = None
    if "region" in q:
        region = whole_numbers(q["region"], "region", 4)
        x, y, w, h = region
        if w < 1 or h < 1 or x + w > viewer.width or y + h > viewer.height:
            raise LtmError(f"region {q['region']!r} must lie in the {viewer.width}x"
                           f"{viewer.height} px image, at least 1 px wide and high")
    if "size" in q:
        size = whole_numbers(q["size"], "size", 2)
        w, h = region[2:] if region else (viewer.width, viewer.height)
        if not (1 <= size[0] <= w and 1 <= size[1] <= h):
            raise LtmError(f"size {q['size']!r} must be from 1x1 to the region's {w}x{h} px")
    for flag in ("preview", "yield"):
        if q.get(flag, "0") not in ("0", "1"):
            raise LtmError(f"{flag} {q[flag]!r} must be 0 or 1")
    return (viewer.light_at(u, v, radius, view), ev, region, size, q.get("preview") == "1",
            q.get("yield") == "1")


def whole_numbers(text: str, what: str, count: int) -> tuple[int, ...]:
    """``count`` comma-separated whole numbers, none negative, else a :class:`LtmError`."""
    values = iiif.finite_numbers(text, what, (count,))
    if not all(v == int(v) and v >= 0 for v in values):
        raise LtmError(f"{what} {text!r} must be {count} whole numbers, none negative")
    return tuple(int(v) for v in values)


class Handler(BaseHTTPRequestHandler):
    """The page's requests; ``server.viewer`` holds the open store."""

    server_version = "ltm-view"
    timeout = REQUEST_TIMEOUT_S  # a half-sent request frees its thread

    def log_message(self, format, *args) -> None:  # noqa: A002 - quiet: the page is the log
        pass

    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        url = urlsplit(self.path)
        if not self._host_ok():
            return self._send(HTTPStatus.FORBIDDEN, b"only local pages", "text/plain")
        viewer: Viewer = self.server.viewer
        try:
            if url.path in STATIC:
                name, kind = STATIC[url.path]
                return self._send(HTTPStatus.OK, static(name), kind)
            if url.path == "/info":
                return self._send(HTTPStatus.OK, json.dumps(viewer.info()).encode(),
                                  "application/json")
            if url.path == "/relight":
                light, ev, region, size, preview, yields = parse_query(viewer, url.query)
                ticket = viewer.ticket()
                start = time.perf_counter()
                body, notes, previewed = viewer.render_png(light, ev, region, size, preview,
                                                           ticket if yields else None)
                headers = {"X-Ltm-Light": json.dumps(light.to_json()),
                           "X-Ltm-Render-Ms": f"{1000 * (time.perf_counter() - start):.1f}",
                           "X-Ltm-Preview": "1" if previewed else "0"}
                headers.update(_noted(notes))
                return self._send(HTTPStatus.OK, body, "image/png", headers)
            if url.path.startswith(iiif.PREFIX):
                return self._send(*viewer.iiif_answer(url.path, f"http://{self.headers['Host']}"))
            if url.path == "/expected_error.png" and viewer.info()["expected_error"]:
                body, top = viewer.error_png()
                return self._send(HTTPStatus.OK, body, "image/png",
                                  {"X-Ltm-Error-Max": f"{top:.6g}"})
        except iiif.Unsupported as exc:
            return self._send(HTTPStatus.NOT_IMPLEMENTED, str(exc).encode(), "text/plain")
        except Superseded:
            return self._send(HTTPStatus.CONFLICT, b"superseded by a newer request",
                              "text/plain")
        except LtmError as exc:
            return self._send(HTTPStatus.BAD_REQUEST, str(exc).encode(), "text/plain")
        except ValueError as exc:  # a chunk that fails its checksum, found while reading
            return self._send(HTTPStatus.INTERNAL_SERVER_ERROR,
                              f"store {str(viewer.path)!r} cannot be read: {exc}".encode(),
                              "text/plain")
        self._send(HTTPStatus.NOT_FOUND, b"not found", "text/plain")

    def _host_ok(self) -> bool:
        host = (self.headers.get("Host") or "").rsplit(":", 1)[0].strip("[]")
        return host in LOOPBACK

    def _send(self, status: HTTPStatus, body: bytes, kind: str,
              headers: dict | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        for key, value in (headers or {}).items():
            self.send_header(key, value)
        self.end_headers()
        self.wfile.write(body)


def static(name: str) -> bytes:
    """A file of the page, shipped as package data in ``ltmstore/share/viewer/``."""
    return resources.files("ltmstore.share").joinpath("viewer", name).read_bytes()


class ViewServer(ThreadingHTTPServer):
    """The page's server, holding the :class:`Viewer`."""

    daemon_threads = True
    block_on_close = False  # server_close() never waits for a request (or a silent client)
    request_queue_size = BACKLOG

    def __init__(self, viewer: Viewer, host: str, port: int) -> None:
        self.viewer = viewer
        self.address_family = socket.AF_INET6 if host == "::1" else socket.AF_INET
        address = "127.0.0.1" if host == "localhost" else host
        super().__init__((address, port), Handler)

    @property
    def url(self) -> str:
        host, port = self.server_address[:2]
        return f"http://{'[::1]' if ':' in host else host}:{port}/"

    def handle_error(self, request, client_address) -> None:
        """Quiet about a client that left mid-request (a closed tab, a dropped connection);
        any other failure as one line on stderr, not a traceback."""
        exc = sys.exc_info()[1]
        if isinstance(exc, CLIENT_GONE):
            return
        text = " ".join(str(exc).split()) or type(exc).__name__
        print(f"ltm view: a request failed: {type(exc).__name__}: {text}", file=sys.stderr,
              flush=True)


def make_server(store: str | os.PathLike, *, host: str = "127.0.0.1",
                port: int = 0) -> ViewServer:
    """Open ``store`` and bind its page on a loopback ``host`` (``port`` 0: a free one).

    Raises
    ------
    LtmError
        A host that is not loopback, a store without a complete ``ltm``, a port in use.
    """
    check_host(host)
    if not 0 <= port <= 65535:
        raise LtmError(f"port {port} must lie in 0-65535 (0: a free port)")
    viewer = Viewer(store)
    try:
        return ViewServer(viewer, host, port)
    except OSError as exc:
        raise LtmError(f"cannot listen on {host} port {port}: {exc.strerror or exc}") from exc

"""``ltm view``: the real command serving the session store, driven in headless Chromium."""

from __future__ import annotations

import io
import signal
from urllib.parse import parse_qs

import numpy as np
import psutil
import pytest
from browser import Browser
from PIL import Image
from pipeline_helpers import served_view

from ltmstore.cli import main
from ltmstore.core.store import open_store
from ltmstore.core.transfer import encode_images
from ltmstore.stages.ingest import ingest
from ltmstore.stages.relight import relight

PIXELS_JS = """(() => {
  const img = document.getElementById("image");
  const c = document.createElement("canvas");
  c.width = img.naturalWidth; c.height = img.naturalHeight;
  const g = c.getContext("2d");
  g.drawImage(img, 0, 0);
  return {w: c.width, h: c.height,
          data: Array.from(g.getImageData(0, 0, c.width, c.height).data)};
})()"""

RECT_JS = "JSON.parse(JSON.stringify(document.getElementById('stage').getBoundingClientRect()))"


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(float) - b.astype(float)) ** 2)
    return float("inf") if mse == 0 else 10 * np.log10(255**2 / mse)


def cli_relight(store, light: tuple[float, float]) -> np.ndarray:
    """The 8-bit image ``ltm relight STORE --light R,S`` writes (its own steps)."""
    ds = open_store(store)
    images = relight(ds, [light]).sum("light").values[None]
    return encode_images(images, ds.attrs["acquisition"].get("transfer", "srgb"))[0]


def page_pixels(browser: Browser) -> np.ndarray:
    """The <img>'s pixels, RGB, read back through a canvas."""
    got = browser.evaluate(PIXELS_JS)
    return np.array(got["data"], dtype=np.uint8).reshape(got["h"], got["w"], 4)[..., :3]


def move_light(browser: Browser, u: float, v: float) -> dict:
    """Move the pointer to ``(u, v)`` over the image; wait for that image; its light."""
    rect = browser.evaluate(RECT_JS)
    browser.move_mouse(rect["left"] + (u + 1) / 2 * rect["width"],
                       rect["top"] + (1 - v) / 2 * rect["height"])
    return browser.wait_for(
        f"(() => {{ const l = window.ltmView.last; return !window.ltmView.inflight && l && "
        f"Math.abs(l.light.u - {u}) < 0.02 && Math.abs(l.light.v - {v}) < 0.02 && l.light; }})()")


def wheel_at_centre(browser: Browser, delta_y: float) -> tuple[dict, float, float]:
    """Turn the wheel by ``delta_y`` over the image's centre: the image's rect before, and
    that centre."""
    rect = browser.evaluate(RECT_JS)
    x, y = rect["left"] + rect["width"] / 2, rect["top"] + rect["height"] / 2
    browser.call("Input.dispatchMouseEvent", type="mouseWheel", x=x, y=y, deltaX=0,
                 deltaY=delta_y)
    return rect, x, y


@pytest.fixture(scope="module")
def served(small_store):
    """``ltm view small_store`` as a real process: yields (process, URL)."""
    with served_view(small_store) as served:
        yield served


def test_view_page_relights_as_ltm_relight_under_the_pointer(served, small_store):
    proc, url = served
    with Browser() as browser:
        browser.goto(url)
        browser.wait_for("window.ltmView.ready")
        first = page_pixels(browser)  # the light at the plane's centre
        light = move_light(browser, 0.5, -0.25)
        assert light["r"] == pytest.approx(0.1, abs=0.005)  # plane r in [-0.2, 0.2]
        assert light["s"] == pytest.approx(-0.05, abs=0.005)
        shown = page_pixels(browser)
        expected = cli_relight(small_store, (light["r"], light["s"]))
        assert shown.shape == expected.shape == (32, 32, 3)
        assert psnr(shown, expected) > 60  # measured: inf (the same 8-bit image)
        assert psnr(first, expected) < 30  # the light moved: measured 21.6 dB
        rect = browser.evaluate(RECT_JS)
        shot = np.asarray(Image.open(io.BytesIO(browser.screenshot(
            {k: rect[k] for k in ("x", "y", "width", "height")}))).convert("RGB"))
        rows = (np.arange(shot.shape[0]) * 32 // shot.shape[0])
        cols = (np.arange(shot.shape[1]) * 32 // shot.shape[1])
        assert psnr(shot, expected[rows][:, cols]) > 30  # measured: inf (21 px per pixel)
    listening = [c.laddr for c in psutil.Process(proc.pid).net_connections(kind="inet")
                 if c.status == psutil.CONN_LISTEN]
    assert listening and all(a.ip == "127.0.0.1" for a in listening), listening


def test_view_refuses_other_hosts_and_missing_stores(small_store, small_acquisition, tmp_path,
                                                     capsys):
    assert main(["view", str(small_store), "--host", "0.0.0.0"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "'0.0.0.0' is not a loopback" in err
    assert main(["view", str(tmp_path / "none.zarr")]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith("ltm: error:") and "none.zarr" in err
    ingest(small_acquisition, tmp_path / "ingested.zarr", progress=False)
    assert main(["view", str(tmp_path / "ingested.zarr")]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "has no complete ltm" in err


def test_expected_error_overlay_and_area_light_are_served(served):
    """The overlay PNG and an area light through the page's own requests."""
    _, url = served
    with Browser(600, 400) as browser:
        browser.goto(url)
        browser.wait_for("window.ltmView.ready")
        assert browser.evaluate("!document.getElementById('error-set').hidden")
        browser.evaluate("document.getElementById('error').click()")
        browser.wait_for("document.getElementById('overlay').complete && "
                         "document.getElementById('overlay').naturalWidth === 32")
        browser.evaluate("document.querySelector('input[value=area]').click()")
        light = browser.wait_for("(() => { const l = window.ltmView.last; return "
                                 "!window.ltmView.inflight && l.light.radius > 0 && l.light; })()")
        assert light["radius"] == pytest.approx(0.02)  # 0.1 of the plane's half width, 0.2 m


def test_zoom_and_pan_keep_the_light_under_the_pointer(served):
    """The wheel zooms about the pointer, a drag pans without moving the light, and the light
    is still the plane point under the pointer."""
    _, url = served
    with Browser(600, 400) as browser:
        browser.goto(url)
        browser.wait_for("window.ltmView.ready")
        before, x, y = wheel_at_centre(browser, -400)
        zoomed = browser.wait_for(f"(() => {{ const r = {RECT_JS}; "
                                  f"return r.width > {1.5 * before['width']} && r; }})()")
        assert zoomed["left"] + zoomed["width"] / 2 == pytest.approx(x, abs=1)
        sent = browser.evaluate("window.ltmView.last.light")
        for kind, dx in (("mousePressed", 0), ("mouseMoved", 40), ("mouseReleased", 40)):
            browser.call("Input.dispatchMouseEvent", type=kind, x=x + dx, y=y, button="left",
                         buttons=1 if kind != "mouseReleased" else 0, clickCount=1)
        panned = browser.wait_for(f"(() => {{ const r = {RECT_JS}; "
                                  f"return r.left > {zoomed['left'] + 39} && r; }})()")
        assert panned["left"] == pytest.approx(zoomed["left"] + 40, abs=1)
        # the drag moved no light (the page may ask again for what is now on the screen)
        assert browser.wait_for("!window.ltmView.inflight && window.ltmView.last.light") == sent
        light = move_light(browser, -0.2, 0.1)
        assert (light["r"], light["s"]) == pytest.approx((-0.04, 0.02), abs=0.002)


def test_zoomed_in_the_page_asks_for_what_is_on_the_screen(served, small_store):
    """Zoomed in, the page asks for the part of the image in the viewport only, and shows it
    where it lies: that region of ``ltm relight``'s image, pixel for pixel."""
    _, url = served
    with Browser(600, 400) as browser:
        browser.goto(url)
        browser.wait_for("window.ltmView.ready")
        rect, _, _ = wheel_at_centre(browser, -800)
        browser.wait_for(f"{RECT_JS}.width > {3 * rect['width']}")
        light = move_light(browser, 0.05, -0.05)
        region = browser.evaluate("window.ltmView.last.region")
        x0, y0, w, h = region
        assert 6 <= w <= 16 and 6 <= h <= 16 and x0 > 0 and y0 > 0, region  # 32 x 32 whole
        shown = page_pixels(browser)
        expected = cli_relight(small_store, (light["r"], light["s"]))[y0:y0 + h, x0:x0 + w]
        assert shown.shape == expected.shape and psnr(shown, expected) == float("inf")
        placed = browser.evaluate("JSON.parse(JSON.stringify(document.getElementById("
                                  "'image').getBoundingClientRect()))")
        stage = browser.evaluate(RECT_JS)
        scale = stage["width"] / 32
        assert placed["left"] == pytest.approx(stage["left"] + x0 * scale, abs=1)
        assert placed["width"] == pytest.approx(w * scale, abs=1)


def test_a_region_at_a_smaller_size_is_area_averaged_and_bad_ones_refused(served,
                                                                          small_store):
    """``region`` and ``size``: the region relit and area-averaged in linear light, then
    encoded; a region outside the image, an upscaling size or a fraction: 400, one line."""
    import urllib.error
    import urllib.request

    _, url = served

    def get(query: str) -> tuple[int, bytes]:
        try:
            with urllib.request.urlopen(f"{url}relight?{query}", timeout=60) as resp:
                return resp.status, resp.read()
        except urllib.error.HTTPError as exc:
            return exc.code, exc.read()

    status, body = get("u=0.5&v=-0.25&region=8,4,16,24&size=8,12")
    assert status == 200
    ds = open_store(small_store)
    linear = relight(ds, [(0.1, -0.05)]).sum("light").values[4:28, 8:24]
    averaged = linear.reshape(12, 2, 8, 2, -1).mean(axis=(1, 3))
    expected = encode_images(averaged[None], ds.attrs["acquisition"].get("transfer", "srgb"))[0]
    shown = np.asarray(Image.open(io.BytesIO(body)))
    assert shown.shape == (12, 8, 3) and np.abs(shown.astype(int) - expected).max() <= 1
    for query, words in (("region=30,0,4,4", "must lie in the 32x32 px image"),
                         ("region=0,0,0,4", "must lie in the 32x32 px image"),
                         ("region=0,0,4.5,4", "must be 4 whole numbers"),
                         ("region=0,0,8,8&size=16,16", "to the region's 8x8 px"),
                         ("preview=2", "preview '2' must be 0 or 1"),
                         ("size=0,4", "from 1x1 to the region's 32x32 px")):
        status, body = get(f"u=0&v=0&{query}")
        assert status == 400 and words in body.decode() and "\n" not in body.decode(), query


def test_zoomed_out_the_page_shows_a_preview_then_the_whole_picture(served, small_store):
    """A window so narrow that the 32 px store is drawn at under half size: the page's first
    image is a preview, the one after it the area-averaged picture at the screen's size."""
    _, url = served
    with Browser(290, 300) as browser:
        browser.goto(url)
        last = browser.wait_for("(() => { const v = window.ltmView; return v.ready && "
                                "!v.inflight && v.last; })()")
        assert browser.evaluate("window.ltmView.previews") == 1 and not last["preview"]
        w, h = (int(v) for v in parse_qs(last["query"])["size"][0].split(","))
        assert w <= 16 and h <= 16, (w, h)  # measured: 12 x 12
        assert page_pixels(browser).shape == (h, w, 3)


def test_a_preview_relights_every_nth_pixel_and_an_old_full_render_yields(served,
                                                                           small_store):
    """``preview=1`` where the size is a quarter of the region: the pixels at every 4th row and
    column of ``ltm relight``'s image, said in ``X-Ltm-Preview``; a render given a ticket stops
    (``Superseded``) once a newer ticket is taken, and answers while it is the newest."""
    import urllib.request

    from ltmstore.share.relit_tiles import Superseded
    from ltmstore.share.view import Viewer

    _, url = served
    for preview, expected_flag in (("&preview=1", "1"), ("", "0"), ("&yield=1", "0")):
        with urllib.request.urlopen(f"{url}relight?u=0.5&v=-0.25&region=0,0,32,32&size=8,8"
                                    f"{preview}", timeout=60) as resp:
            assert resp.headers["X-Ltm-Preview"] == expected_flag
            body = resp.read()
        if preview == "&preview=1":
            shown = np.asarray(Image.open(io.BytesIO(body)))
            expected = cli_relight(small_store, (0.1, -0.05))[2::4, 2::4]
            assert psnr(shown, expected) == float("inf")
    viewer = Viewer(small_store)
    old, new = viewer.ticket(), viewer.ticket()
    light = viewer.light_at(0.5, -0.25)
    with pytest.raises(Superseded):
        viewer.render_linear(light, ticket=old)
    image, _, _ = viewer.render_linear(light, ticket=new)
    assert image.shape == (32, 32, 3)


def test_view_stops_cleanly_on_ctrl_c(small_store):
    """A server of its own, after it has relit once (stopping the module's server made the
    other tests depend on running before this one)."""
    import urllib.request

    with served_view(small_store) as (proc, url):
        with urllib.request.urlopen(f"{url}relight?u=0.5&v=-0.25", timeout=60) as resp:
            assert resp.status == 200
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0
    assert err.strip().splitlines() == ["ltm view: stopped"]


def test_far_light_store_maps_the_pointer_to_a_direction(tmp_path):
    """A classic RTI capture: the image spans the unit disk of (lx, ly); the rim stays above
    the horizon; an area light is a cone of directions."""
    from ingest_helpers import write_capture

    from ltmstore.core.lights import elevation_azimuth
    from ltmstore.share.view import Viewer
    from ltmstore.stages.ingest_rti import ingest_rti
    from ltmstore.stages.reconstruct import reconstruct

    lights = elevation_azimuth(np.repeat([30, 50, 75], 6), np.tile(np.arange(0, 360, 60), 3))
    ingest_rti(write_capture(tmp_path / "cap", dirs=lights), tmp_path / "s.zarr", progress=False)
    reconstruct(tmp_path / "s.zarr", progress=False)
    viewer = Viewer(tmp_path / "s.zarr")
    light = viewer.light_at(0.3, -0.2)
    assert (light.r, light.s) == pytest.approx((0.3, -0.2))
    body, _, preview = viewer.render_png(light)
    assert not preview
    shown = np.asarray(Image.open(io.BytesIO(body)))
    assert psnr(shown, cli_relight(tmp_path / "s.zarr", (0.3, -0.2))) == float("inf")
    rim = viewer.light_at(1, 1)
    assert np.hypot(rim.r, rim.s) == pytest.approx(0.98)
    area, _, _ = viewer.render_linear(viewer.light_at(0.3, -0.2, radius=0.3))
    assert area.shape == (6, 5, 3)
    rng = np.random.default_rng(0)  # the mean over the cone, by random directions in it
    radius, angle = 0.3 * np.sqrt(rng.random(2000)), 2 * np.pi * rng.random(2000)
    cone = np.column_stack([0.3 + radius * np.cos(angle), -0.2 + radius * np.sin(angle)])
    sampled = relight(tmp_path / "s.zarr", cone).mean("light").values
    point = relight(tmp_path / "s.zarr", [(0.3, -0.2)]).values[0]
    assert np.abs(area - sampled).max() < 0.015 * sampled.mean()  # measured 0.79 %
    assert np.abs(area - point).max() > 0.03 * point.mean()  # not the point light: 5.6 %


def test_view_has_help(capsys):
    from ltmstore.cli import build_parser

    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["view", "--help"])
    out = capsys.readouterr().out
    assert exc.value.code == 0 and "usage: ltm view" in out and "--port" in out


def test_an_area_light_is_a_relit_disk_light_and_an_old_store_is_named(small_store, tmp_path):
    """The server's area light is :func:`disk_light` relit; a store without the light-major
    copy (written before it) is served with one warning that names the fix."""
    import shutil

    import zarr

    from ltmstore.core.errors import LtmWarning
    from ltmstore.share.view import Viewer
    from ltmstore.stages.by_light import by_light_name
    from ltmstore.stages.relight import disk_light

    old = shutil.copytree(small_store, tmp_path / "old.zarr")
    group = zarr.open_group(str(old), mode="r+")
    for name in [n for n in group if n.endswith("_by_light")]:
        del group[name]
    with pytest.warns(LtmWarning, match="ltm compact"):
        viewer = Viewer(old)
    assert by_light_name("ltm") not in viewer.ds
    light = viewer.light_at(0.2, -0.3, radius=0.3)
    image, _, _ = viewer.render_linear(light)
    ds = open_store(small_store)
    expected = relight(ds, disk_light(ds["ltm"], (light.r, light.s), light.radius)).sum("light")
    np.testing.assert_allclose(image, expected.values, rtol=1e-5, atol=1e-7)

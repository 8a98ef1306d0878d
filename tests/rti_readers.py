"""Readers of the RTI formats written from their specifications (not from the exporters'
helpers), and the store's own relighting to compare them with: shared by the export tests."""

from __future__ import annotations

import functools
import json
import struct
from math import pi, sqrt

import numpy as np
import xarray as xr
from PIL import Image

import ltmstore
from ltmstore.core.dims import rgb_from_ycbcr
from ltmstore.stages.relight import to_rgb


def directions(positions: np.ndarray, height: float) -> np.ndarray:
    """Unit vectors from the object centre to lights at plane ``positions`` (n, 2)."""
    d = np.column_stack([positions, np.full(len(positions), height)])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


# --- basis functions, from the specifications -------------------------------------------------

def ptm_weights(d: np.ndarray) -> np.ndarray:
    """PTM 1.2: L = a0 u^2 + a1 v^2 + a2 uv + a3 u + a4 v + a5."""
    u, v = d[:, 0], d[:, 1]
    return np.stack([u * u, v * v, u * v, u, v, np.ones_like(u)], axis=1)


def relight_ptm_weights(d: np.ndarray) -> np.ndarray:
    """OpenLIME PTM.lightWeights: [1, x, y, x*x, x*y, y*y]."""
    u, v = d[:, 0], d[:, 1]
    return np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=1)


def hsh_weights(d: np.ndarray, terms: int) -> np.ndarray:
    """RTIViewer getHSH(theta, phi) with theta = acos(z), phi = atan2(y, x)."""
    rows = []
    for x, y, z in d:
        theta, phi = np.arccos(z), np.arctan2(y, x)
        ct = np.cos(theta)
        ct2 = ct * ct
        h = [1 / sqrt(2 * pi), sqrt(6 / pi) * np.cos(phi) * sqrt(ct - ct2),
             sqrt(3 / (2 * pi)) * (-1 + 2 * ct), sqrt(6 / pi) * sqrt(ct - ct2) * np.sin(phi),
             sqrt(30 / pi) * np.cos(2 * phi) * (-ct + ct2),
             sqrt(30 / pi) * np.cos(phi) * (-1 + 2 * ct) * sqrt(ct - ct2),
             sqrt(5 / (2 * pi)) * (1 - 6 * ct + 6 * ct2),
             sqrt(30 / pi) * (-1 + 2 * ct) * sqrt(ct - ct2) * np.sin(phi),
             sqrt(30 / pi) * (-ct + ct2) * np.sin(2 * phi),
             2 * sqrt(35 / pi) * np.cos(3 * phi) * (ct - ct2) ** 1.5,
             sqrt(210 / pi) * np.cos(2 * phi) * (-1 + 2 * ct) * (-ct + ct2),
             2 * sqrt(21 / pi) * np.cos(phi) * sqrt(ct - ct2) * (1 - 5 * ct + 5 * ct2),
             sqrt(7 / (2 * pi)) * (-1 + 12 * ct - 30 * ct2 + 20 * ct2 * ct),
             2 * sqrt(21 / pi) * sqrt(ct - ct2) * (1 - 5 * ct + 5 * ct2) * np.sin(phi),
             sqrt(210 / pi) * (-1 + 2 * ct) * (-ct + ct2) * np.sin(2 * phi),
             2 * sqrt(35 / pi) * (ct - ct2) ** 1.5 * np.sin(3 * phi)]
        rows.append(h[:terms])
    return np.array(rows)


# --- readers, from the specifications: each returns coefficients (y, x, terms, 3) in display
# --- units [0, 1], rows top first, and the basis to evaluate them with ------------------------

def read_ptm(path):
    """PTM 1.2: 6 text lines, then bytes; a = (c - bias) * scale; rows bottom to top."""
    data = path.read_bytes()
    lines = data.split(b"\n", 6)
    version, fmt, width, height = (x.decode() for x in lines[:4])
    width, height = int(width), int(height)
    scale = np.array(lines[4].split(), float)
    bias = np.array(lines[5].split(), int)
    body = np.frombuffer(lines[6], np.uint8)
    assert version == "PTM_1.2"
    n = width * height
    if fmt == "PTM_FORMAT_RGB":
        assert body.size == 18 * n
        c = body.reshape(3, height, width, 6).transpose(1, 2, 3, 0)
        coef = (c - bias[:, None]) * scale[:, None] / 255
    else:
        assert fmt == "PTM_FORMAT_LRGB" and body.size == 9 * n
        lum = (body[:6 * n].reshape(height, width, 6) - bias) * scale / 255
        rgb = body[6 * n:].reshape(height, width, 3) / 255
        coef = lum[..., None] * rgb[:, :, None, :]  # rgb * L: linear in the coefficients
    return coef[::-1], ptm_weights


def read_rti(path):
    """#HSH1.2: comment lines, type, 'w h bands', 'terms type size', float32 scale[terms],
    bias[terms], then per row (top first) and pixel: terms bytes per band; a = c/255*scale+bias."""
    data = path.read_bytes()
    pos, fields = 0, []
    while len(fields) < 3:
        end = data.index(b"\n", pos)
        line = data[pos:end].decode().strip()
        pos = end + 1
        if not line.startswith("#"):
            fields.append([int(v) for v in line.split()])
    (kind,), (width, height, bands), (terms, _, size) = fields
    assert (kind, bands, size) == (3, 3, 1)
    scale = np.array(struct.unpack(f"<{terms}f", data[pos:pos + 4 * terms]))
    bias = np.array(struct.unpack(f"<{terms}f", data[pos + 4 * terms:pos + 8 * terms]))
    body = np.frombuffer(data[pos + 8 * terms:], np.uint8)
    assert body.size == width * height * 3 * terms
    c = body.reshape(height, width, 3, terms).transpose(0, 1, 3, 2)
    coef = c / 255 * scale[:, None] + bias[:, None]
    return coef, lambda d: hsh_weights(d, terms)


def bilinear_weights(info: dict, d: np.ndarray) -> np.ndarray:
    """OpenLIME ``ShaderRTI``: ``setLight`` (x, y to the unit disk, z = sqrt(1 - x^2 - y^2)),
    ``BLN.lightWeights`` (octahedral map turned 45 degrees, bilinear over the grid) and
    ``loadBasis`` (plane 0 byte / 255, plane p (byte - 127) / range[p - 1]): per light and
    channel, the weights of [1, coefficient_1, ..., coefficient_P], shape (lights, P + 1, 3)."""
    res, np1 = info["resolution"], info["nplanes"] + 1
    raw = np.asarray(info["basis"], float).reshape(np1, res * res, 3)
    rng = np.asarray(info["materials"][0]["range"], float)
    basis = np.concatenate([raw[:1] / 255, (raw[1:] - 127) / rng[:, None, None]])
    out = []
    for x, y, _ in d:
        r = sqrt(x * x + y * y)
        if r > 1:
            x, y = x / r, y / r
        z = sqrt(max(0.0, 1 - x * x - y * y))
        s = abs(x) + abs(y) + abs(z)
        u, v = ((x + y) / s + 1) / 2 * (res - 1), ((y - x) / s + 1) / 2 * (res - 1)
        sx, sy = min(res - 2, max(0, int(np.floor(u)))), min(res - 2, max(0, int(np.floor(v))))
        dx, dy = u - sx, v - sy
        node = lambda i, j: basis[:, i + j * res, :]  # noqa: E731
        out.append((1 - dx) * (1 - dy) * node(sx, sy) + dx * (1 - dy) * node(sx + 1, sy)
                   + (1 - dx) * dy * node(sx, sy + 1) + dx * dy * node(sx + 1, sy + 1))
    return np.stack(out)


def read_web(folder):
    """info.json + plane_<j>.jpg (channel k of plane j is plane 3j+k); (t - bias) * scale.
    Colour space ``rgb`` (a basis per channel) or ``mrgb`` with type ``bilinear`` (PCA
    coefficients shared by the channels, :func:`bilinear_weights`)."""
    info = json.loads((folder / "info.json").read_text())
    assert info["format"] == "jpg"
    if info["colorspace"] == "mrgb":
        assert info["type"] == "bilinear"
        scale = np.array(info["materials"][0]["scale"])
        bias = np.array(info["materials"][0]["bias"])
        planes = np.concatenate([np.asarray(Image.open(folder / f"plane_{j}.jpg").convert("RGB"))
                                 for j in range(info["nplanes"] // 3)], axis=2)
        assert planes.shape[:2] == (info["height"], info["width"])
        coef = (planes / 255 - bias) * scale  # (y, x, P), one per plane
        coef = np.concatenate([np.ones((*coef.shape[:2], 1)), coef], axis=2)
        return (np.repeat(coef[..., None], 3, axis=3),
                lambda d: bilinear_weights(info, np.asarray(d, float)))
    assert info["colorspace"] == "rgb"
    scale = np.array(info["materials"][0]["scale"]).reshape(-1, 3)
    bias = np.array(info["materials"][0]["bias"]).reshape(-1, 3)
    planes = np.stack([np.asarray(Image.open(folder / f"plane_{j}.jpg").convert("RGB"))
                       for j in range(info["nplanes"] // 3)], axis=2)
    assert planes.shape[:2] == (info["height"], info["width"])
    coef = (planes / 255 - bias) * scale
    basis = relight_ptm_weights if info["type"] == "ptm" else (lambda d: hsh_weights(d, 9))
    return coef, basis


def relit(coef: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """8-bit images (light, y, x, 3) from coefficients (y, x, terms, 3) and weights (light,
    terms), or (light, terms, 3) for weights per channel."""
    spec = "lbc,yxbc->lyxc" if weights.ndim == 3 else "lb,yxbc->lyxc"
    return np.clip(np.round(255 * np.einsum(spec, weights, coef)), 0, 255)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = [np.mean((x - y) ** 2) for x, y in zip(a, b, strict=True)]
    return float(np.mean([10 * np.log10(255 ** 2 / max(m, 1e-12)) for m in mse]))


@functools.cache
def reference(store: str):
    """Lights inside the plane, their directions, ``ltmstore.relight`` there (linear RGB), and
    the store's RGB at its cells (as relight computes it) with the cells' directions."""
    ds = ltmstore.open_store(store)
    plane = ds.attrs["acquisition"]["plane"]
    half = 0.85 * min(np.ptp(plane["r"]), np.ptp(plane["s"])) / 2
    lights = np.random.default_rng(7).uniform(-half, half, size=(10, 2)) + [
        np.mean(plane["r"]), np.mean(plane["s"])]
    cells = np.array([(r, s) for r in ds.r.values for s in ds.s.values])
    if "ltm_cb" in ds:  # a colour LTM
        rgb = xr.concat(rgb_from_ycbcr(ds.ltm.load(), ds.ltm_cb.load(), ds.ltm_cr.load()),
                        dim="color")
    else:  # chroma ratios
        rgb = to_rgb(ds.ltm.load(), ds.chroma.load())
    rgb = rgb.transpose("r", "s", "y", "x", "color")
    return (directions(lights, plane["height"]), ltmstore.relight(ds, lights).values,
            directions(cells, plane["height"]), rgb.values.reshape(len(cells), *rgb.shape[2:]))

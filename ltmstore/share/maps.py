"""``ltm maps``: the surface model of a far-light store as images, and relit with its material
changed.

A far-light store reconstructed with the surface model (:mod:`ltmstore.stages.surface`) holds a
normal, an albedo, a specular lobe and a roughness per pixel. :func:`write_maps` writes them as
PNG files the photometric-stereo and RTI world reads: ``normal.png`` (16-bit RGB, ``(n / 2 +
1 / 2) * 65535`` with R = x right, G = y up, B = z towards the camera: SynthRTI's encoding),
``albedo.png`` and ``specular.png`` (8-bit sRGB, each scaled so that its 99.5th percentile is
white) and ``roughness.png`` (8-bit grey, the lobe's alpha in ``[0, 1]``, GGX or Beckmann). A
near-light store whose tiles chose ``physical`` holds the same maps in luminance (no ``color``
dimension; NaN, written black, where a tile chose another method): its maps are written the same
way, grey.

:func:`render_material` relights the model alone (no residual: exactly what the maps say) with
the diffuse albedo and the lobe scaled, like the "specular enhancement" and "diffuse gain" modes
of RTI viewers: ``specular=0`` shows the diffuse shading only, ``specular=3`` exaggerates the
highlights that reveal the surface's relief and finish.

Where the photographs do not support a pixel's lobe (:func:`lobe_support`: no photograph lit
near its peak, or a lobe so rough that it is one more constant beside the ambient floor, as along
an object's outline, in its cast shadows), its strength and roughness are whatever the fit's
bounds left: saturated colours, roughness 1. The maps fade such a lobe out (specular towards 0,
roughness towards the median of the supported pixels), and the material images relight the
faded lobes (a highlight no photograph saw is not shown, nor enhanced).

With ``height``, :func:`maps` also integrates the normal map into a height map and meshes in
millimetres (:mod:`ltmstore.share.height`).

``depth`` (``ltm maps --depth``) sets the images' precision: 8 (default, as above), 16 (the
same maps and material images as 16-bit PNG: sRGB ``round(v * 65535)``, roughness
``round(alpha * 65535)``) or ``"float"`` (float32 TIFF, ``.tif``: the linear values behind the
8-bit images, unclipped and without a transfer: albedo, specular and material images at the
same exposure, the normal ``n`` itself in ``[-1, 1]``, roughness ``alpha``; NaN written 0).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ltmstore.core.dims import COLOR
from ltmstore.core.errors import LtmError
from ltmstore.core.imagefile import write_bytes_atomic, write_image
from ltmstore.core.transfer import FLOAT, check_depth, encode
from ltmstore.share.atomic import atomic_output, check_output
from ltmstore.solve import physical
from ltmstore.stages import surface as sf

WHITE_PERCENTILE = 99.5
MATERIAL = "material_{:03d}.png"
# lobe_support's ramps: below the first value a lobe has no support in the photographs, above
# the second full support. Distinctness: on loewenkopf the lobes at roughness 1 measure 0, the
# median pixel 0.64. Evidence: its lobes at roughness 0.02 between the lights measure below 0.01;
# test_maps' highlight, fitted from the tail of a lobe no light lit at its peak (and right), 0.05.
DISTINCT_EDGES = (0.1, 0.3)
EVIDENCE_EDGES = (0.01, 0.04)


def require_surface(ds, store: str | os.PathLike | None = None) -> None:
    """Refuse a store (an xarray Dataset; ``store``: its path, for the message) without the
    surface model's maps."""
    if any(name not in ds for name in sf.SURFACE):
        store = ds.encoding.get("source", "?") if store is None else store
        raise LtmError(f"store {str(store)!r} holds no surface maps (normal, albedo, specular, "
                       "roughness): reconstruct a far-light store (ltm ingest-rti) with `ltm "
                       "reconstruct --method physical` (or auto, where the model wins)")


def require_material(ds) -> None:
    """Refuse material images of a store whose maps are not a far-light store's colour maps."""
    require_surface(ds)
    if COLOR not in ds[sf.ALBEDO].dims:
        raise LtmError("material images need a far-light store's surface (ltm ingest-rti): a "
                       "near-light store's maps are luminance, fitted under its near light; "
                       "drop --direction to write its maps")


def check_material(directions: np.ndarray | None, diffuse: float, specular: float
                   ) -> np.ndarray | None:
    """The unit light directions ``(n, 3)`` (or None), refusing negative or non-finite scales
    and directions at or below the horizon."""
    for name, value in (("diffuse", diffuse), ("specular", specular)):
        if not (np.isfinite(value) and value >= 0):
            raise LtmError(f"--{name} {value!r} must be a finite scale >= 0")
    if directions is None:
        return None
    dirs = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    for d in dirs:
        if not (np.isfinite(d).all() and d[2] > 0):
            raise LtmError(f"light direction {','.join(f'{v:g}' for v in d)} must be finite "
                           "and above the horizon (lz > 0)")
    return dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


def _ramp(value: np.ndarray, edges: tuple[float, float]) -> np.ndarray:
    """0 below the first of ``edges``, 1 above the second, linear between."""
    lo, hi = edges
    return np.clip((value - lo) / (hi - lo), 0.0, 1.0)


def _block_support(normal: np.ndarray, roughness: np.ndarray, directions: np.ndarray,
                   distribution: str) -> np.ndarray:
    """:func:`lobe_support` of the pixels ``normal (n, 3)``, ``roughness (n,)`` (a lobe of the
    ``distribution``, one of ``physical.LOBES``)."""
    n = len(normal)
    lights = physical.far_lights(directions, n, distribution)
    zeros, ones = np.zeros(n), np.ones(n)

    def term(albedo: np.ndarray, specular: np.ndarray) -> np.ndarray:
        return physical.render(physical.Surface(normal, albedo, specular, roughness, zeros,
                                                zeros), lights).astype(np.float64)

    lobe, diffuse = term(zeros, ones), term(ones, zeros)
    alpha2 = roughness**2
    peak = 1 / (np.pi * alpha2) / (4 * normal[:, 2])  # D(1) / (4 n.v), GGX's or Beckmann's
    evidence = lobe.max(axis=1) / peak
    basis = np.stack([diffuse, np.ones_like(diffuse)], axis=-1)  # what the lobe must not be
    gram = np.einsum("nmi,nmj->nij", basis, basis) + 1e-12 * np.eye(2)
    coef = np.linalg.solve(gram, np.einsum("nmi,nm->ni", basis, lobe)[..., None])
    rest = lobe - (basis @ coef)[..., 0]
    distinct = np.linalg.norm(rest, axis=1) / np.maximum(np.linalg.norm(lobe, axis=1), 1e-30)
    return np.minimum(_ramp(evidence, EVIDENCE_EDGES), _ramp(distinct, DISTINCT_EDGES))


def lobe_support(ds) -> np.ndarray:
    """How far the photographs of a far-light store determine each pixel's specular lobe,
    ``(y, x)`` in ``[0, 1]``: the smaller of two measures, ramped over
    :data:`EVIDENCE_EDGES` and :data:`DISTINCT_EDGES`.

    * evidence: the lobe's largest value at a photographed light over its peak (1: a photograph
      lit the highlight's peak; near 0: every light missed a sharp lobe);
    * distinctness: the share of the lobe, at the photographed lights, that the diffuse term and
      the ambient floor do not explain (the relative norm of its least-squares residual; 0: a
      lobe as rough as ``alpha = 1`` is a constant, a second ambient floor).

    Parameters
    ----------
    ds : xarray.Dataset
        A store holding the surface model.

    Returns
    -------
    ndarray of float64, shape (y, x)
        Ones for a near-light store's luminance maps (its fit shares lobes over a tile
        instead, :mod:`ltmstore.solve.physical`).
    """
    require_surface(ds)
    shape = ds[sf.ROUGHNESS].shape
    if COLOR not in ds[sf.ALBEDO].dims:
        return np.ones(shape)
    from ltmstore.stages.reconstruct_far import train_directions

    directions = train_directions(ds)
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    normal = ds[sf.NORMAL].values.reshape(-1, 3).astype(np.float64)
    roughness = ds[sf.ROUGHNESS].values.ravel().astype(np.float64)
    distribution = sf.surface_lobe(ds)
    support = np.concatenate([
        _block_support(normal[i:i + sf.BLOCK], roughness[i:i + sf.BLOCK], directions,
                       distribution)
        for i in range(0, len(normal), sf.BLOCK)])
    return np.nan_to_num(support).reshape(shape)


def _white(linear: np.ndarray) -> float:
    """The :data:`WHITE_PERCENTILE` percentile of the finite values of ``linear`` (> 0)."""
    finite = linear[np.isfinite(linear)]
    return max(float(np.percentile(finite, WHITE_PERCENTILE)) if finite.size else 0.0, 1e-12)


def _display(linear: np.ndarray, depth: int | str = 8) -> np.ndarray:
    """sRGB of ``linear`` at ``depth`` (:func:`ltmstore.core.transfer.encode`; float: linear),
    scaled so that its 99.5th percentile is white (NaN: black)."""
    return encode(np.nan_to_num(linear / _white(linear)), "srgb", depth)


def _fraction(value: np.ndarray, depth: int | str) -> np.ndarray:
    """Values in ``[0, 1]`` as grey code values of ``depth`` (no transfer; float: as they
    are, float32)."""
    if depth == FLOAT:
        return value.astype(np.float32)
    top = 65535 if depth == 16 else 255
    return np.round(value * top).astype(np.uint16 if depth == 16 else np.uint8)


def _normal_image(normal: np.ndarray, depth: int | str) -> np.ndarray:
    """The normal map: 16-bit ``(n / 2 + 1 / 2) * 65535`` at depths 8 and 16, ``n`` as float32
    at ``"float"`` (NaN: 0 as float, mid-grey as 16-bit, as before)."""
    if depth == FLOAT:
        return np.nan_to_num(normal).astype(np.float32)
    return np.round(np.nan_to_num(normal * 0.5 + 0.5).clip(0, 1) * 65535).astype(np.uint16)


def _write(path: Path, image: np.ndarray) -> Path:
    """A map or material image: integer ones as PNG (:func:`_write_png`), float ones as a
    float32 TIFF beside it (``path`` with ``.tif``)."""
    if np.issubdtype(image.dtype, np.floating):
        return write_image(path.with_suffix(".tif"), image, what="map")
    return _write_png(path, image)


def _write_png(path: Path, rgb_or_grey: np.ndarray) -> Path:
    import cv2

    image = rgb_or_grey[..., ::-1] if rgb_or_grey.ndim == 3 else rgb_or_grey  # cv2 is BGR
    ok, data = cv2.imencode(".png", np.ascontiguousarray(image))
    if not ok:
        raise LtmError(f"cannot encode image {str(path)!r}")
    return write_bytes_atomic(path, data.tobytes())


def shown_specular(ds, support: np.ndarray | None = None) -> np.ndarray:
    """The store's lobe strength as the maps show it: faded by :func:`lobe_support`, and grey
    (each channel the luminance's strength) where a channel's strength sits at its bound 0
    while the lobe's luminance does not (the split of a broad lobe from the diffuse term per
    channel is then the fit's bound, not the photographs' colour)."""
    from ltmstore.core.dims import LUMA

    specular = ds[sf.SPECULAR].values.astype(np.float64)
    support = lobe_support(ds) if support is None else support
    if specular.ndim == 2:  # a near-light store's luminance
        return specular * support
    grey = specular @ np.asarray(LUMA, dtype=np.float64)
    bound = (specular.min(axis=-1) <= 0) & (grey > 0)
    return np.where(bound[..., None], grey[..., None], specular) * support[..., None]


def _faded_roughness(roughness: np.ndarray, support: np.ndarray) -> np.ndarray:
    """``roughness`` in ``[0, 1]`` faded by ``support`` towards the median of the supported
    pixels (those of support at least 0.5; NaN: 0)."""
    known = roughness[(support >= 0.5) & np.isfinite(roughness)]
    typical = float(np.median(known)) if known.size else 0.0
    return np.nan_to_num(support * roughness + (1 - support) * typical).clip(0, 1)


def write_maps(ds, out_dir: str | os.PathLike, *, support: np.ndarray | None = None,
               depth: int | str = 8) -> dict[str, Path]:
    """Write the surface maps of a store as PNG files in ``out_dir`` (created if missing).

    Parameters
    ----------
    ds : xarray.Dataset
        A store (:func:`ltmstore.core.store.open_store`) holding the surface model.
    out_dir : path-like
        Folder of the images.
    support : ndarray, optional
        :func:`lobe_support` of ``ds`` where it is already at hand.
    depth : {8, 16, "float"}
        The images' precision (see the module's note): 8 as described below, 16 every map
        16-bit PNG, ``"float"`` every map float32 TIFF (``.tif``).

    Returns
    -------
    dict
        The path of each map: ``normal`` (16-bit RGB), ``albedo``, ``specular`` (8-bit sRGB)
        and ``roughness`` (8-bit grey); specular and roughness faded where the photographs do
        not support the lobe (:func:`lobe_support`).
    """
    depth = check_depth(depth)
    require_surface(ds)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    normal = ds[sf.NORMAL].values.astype(np.float64)
    support = lobe_support(ds) if support is None else support
    images = {"normal": _normal_image(normal, depth),
              "albedo": _display(ds[sf.ALBEDO].values, depth),
              "specular": _display(shown_specular(ds, support), depth),
              "roughness": _fraction(_faded_roughness(ds[sf.ROUGHNESS].values, support),
                                     depth)}
    return {name: _write(out / f"{name}.png", image) for name, image in images.items()}


def render_material(ds, directions: np.ndarray | Sequence[Sequence[float]], *,
                    diffuse: float = 1.0, specular: float = 1.0,
                    support: np.ndarray | None = None) -> np.ndarray:
    """The surface model of a store relit at ``directions`` with its material changed.

    Parameters
    ----------
    ds : xarray.Dataset
        A store holding the surface model.
    directions : array_like, shape (n, 3)
        Directions towards the lights (``x`` right, ``y`` up, ``z`` towards the camera; ``lz >
        0``), normalised here.
    diffuse : float
        Scale of the diffuse albedo.
    specular : float
        Scale of the lobe's strength: 0 diffuse only, 1 as fitted, above 1 specular enhancement.
    support : ndarray, optional
        :func:`lobe_support` of ``ds`` where it is already at hand.

    Returns
    -------
    ndarray of float32, shape (n, y, x, 3)
        Linear RGB in the photographs' units (the ambient floor is kept), each lobe faded by
        its support in the photographs (:func:`lobe_support`), as in the maps: a lobe sharper
        than the lights' spacing that no photograph saw is no highlight to show or enhance.
    """
    require_material(ds)
    dirs = check_material(directions, diffuse, specular)
    theta = sf.read_surface(ds)
    h, w = theta.shape[:2]
    theta[..., 2] *= diffuse
    support = lobe_support(ds) if support is None else support
    theta[..., 3] *= specular * support[..., None]  # faded as in the maps
    flat = theta.reshape(-1, 3, 6)
    rgb = physical.render_colour(flat, physical.far_lights(dirs, len(flat),
                                                           sf.surface_lobe(ds)))  # (p, n, 3)
    return np.moveaxis(rgb, 1, 0).reshape(len(dirs), h, w, 3).clip(min=0).astype(np.float32)


def write_material(ds, out_dir: str | os.PathLike, directions: np.ndarray, *,
                   diffuse: float = 1.0, specular: float = 1.0,
                   support: np.ndarray | None = None, depth: int | str = 8) -> list[Path]:
    """Write :func:`render_material` images as 8-bit sRGB ``material_000.png``, ... in
    ``out_dir``, at one exposure: the albedo map's white (a surface facing the light with the
    99.5th-percentile albedo is white), so that scaling the material shows. ``depth`` 16:
    16-bit sRGB PNG; ``"float"``: float32 linear TIFF (``material_000.tif``, ...) at that
    exposure."""
    depth = check_depth(depth)
    images = render_material(ds, directions, diffuse=diffuse, specular=specular,
                             support=support)
    codes = encode(images / _white(ds[sf.ALBEDO].values), "srgb", depth)
    return [_write(Path(out_dir) / MATERIAL.format(i), c) for i, c in enumerate(codes)]


def maps(store: str | os.PathLike, out_dir: str | os.PathLike, *,
         directions: np.ndarray | None = None, diffuse: float = 1.0, specular: float = 1.0,
         overwrite: bool = False, height: bool = False, mesh: bool = False,
         integration: str = "poisson", pixel_mm: float | None = None,
         object_width_mm: float | None = None, mesh_step: int | None = None,
         depth: int | str = 8) -> dict:
    """``ltm maps``: the surface maps of ``store`` and, with ``directions``, its relit images
    with the material changed, in a new folder ``out_dir`` written atomically (never the
    store, a folder in it or one holding it: :func:`ltmstore.core.paths.check_output`).

    With ``height`` (or ``mesh``), also the normals integrated into a height map
    (:func:`ltmstore.share.height.write_height`: ``integration`` ``"poisson"`` or ``"fc"``),
    with ``mesh`` its PLY and OBJ meshes in mm, every ``mesh_step`` pixels: the scale is
    ``pixel_mm`` or ``object_width_mm`` (the store's width in mm). ``depth`` (8, 16 or
    ``"float"``) is the maps' and material images' precision (:func:`write_maps`).

    Returns
    -------
    dict
        ``path``, the ``files`` written (names), ``width`` and ``height``, and with a height
        map ``relief`` (what ``height.json`` holds).
    """
    from ltmstore.core.store import open_store
    from ltmstore.share import height as ht
    from ltmstore.solve.height import INTEGRATIONS

    check_material(directions, diffuse, specular)
    depth = check_depth(depth)
    height = height or mesh
    if not height and (pixel_mm, object_width_mm, mesh_step) != (None, None, None):
        raise LtmError("--pixel-size, --object-width and --mesh-step scale the height map: "
                       "add --height or --mesh")
    if integration not in INTEGRATIONS:
        raise LtmError(f"--integration {integration!r} must be one of "
                       f"{', '.join(INTEGRATIONS)}")
    ht.pixel_size(1, pixel_mm, object_width_mm)
    if mesh and pixel_mm is None and object_width_mm is None:
        raise LtmError("--mesh writes millimetres: give the scale with --pixel-size MM or "
                       "--object-width MM")
    ht.mesh_step((1, 1), mesh_step)
    check_output(out_dir, overwrite, inputs=(store,))
    ds = open_store(store)
    require_surface(ds, store)
    if directions is not None:
        require_material(ds)
    with atomic_output(out_dir, overwrite=overwrite, folder=True, inputs=(store,)) as tmp:
        support = lobe_support(ds)  # once for the maps and the material images
        files = list(write_maps(ds, tmp, support=support, depth=depth).values())
        if directions is not None:
            files += write_material(ds, tmp, directions, diffuse=diffuse, specular=specular,
                                    support=support, depth=depth)
        relief = None
        if height:
            written, relief = ht.write_height(
                ds[sf.NORMAL].values, tmp, method=integration, mesh=mesh, step=mesh_step,
                pixel_mm=ht.pixel_size(ds.sizes["x"], pixel_mm, object_width_mm))
            files += list(written.values())
    return {"path": os.fspath(out_dir), "files": [f.name for f in files],
            "width": ds.sizes["x"], "height": ds.sizes["y"], "relief": relief}

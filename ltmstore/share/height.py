"""The surface as a surface: a normal map integrated into a height map
(:mod:`ltmstore.solve.height`), written as a 16-bit image and as PLY and OBJ meshes in
millimetres (``ltm maps --height``, ``--mesh``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.solve.height import DEFAULT_INTEGRATION, integrate

MESH_VERTICES = 1_000_000  # the default mesh step keeps at most about this many vertices


def height_png(height: np.ndarray) -> np.ndarray:
    """``height`` as 16-bit grey: lowest 0, highest 65535 (all 0 for a flat map)."""
    span = float(height.max() - height.min())
    scaled = (height - height.min()) / span if span > 0 else np.zeros_like(height)
    return np.round(scaled * 65535).astype(np.uint16)


def mesh_step(shape: tuple[int, int], step: int | None = None) -> int:
    """The grid step of the mesh: ``step``, or the smallest keeping at most
    :data:`MESH_VERTICES` vertices."""
    if step is None:
        return max(1, int(np.ceil(np.sqrt(shape[0] * shape[1] / MESH_VERTICES))))
    if isinstance(step, bool) or int(step) != step or step < 1:
        raise LtmError(f"--mesh-step {step!r} must be a whole number of pixels >= 1")
    return int(step)


def grid_mesh(height: np.ndarray, pixel_mm: float, step: int = 1
              ) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(n, 3)`` float32 in mm and triangles ``(m, 3)`` int32 of the height map
    sampled every ``step`` pixels: x right and y up from the image centre, z the height
    (``height`` in pixels times ``pixel_mm``); two triangles per grid cell, counter-clockwise
    seen from the camera (+z)."""
    h, w = height.shape
    rows, cols = np.arange(0, h, step), np.arange(0, w, step)
    r, c = np.meshgrid(rows, cols, indexing="ij")
    vertices = np.column_stack([((c + 0.5 - w / 2) * pixel_mm).ravel(),
                                ((h / 2 - r - 0.5) * pixel_mm).ravel(),
                                (height[r, c] * pixel_mm).ravel()]).astype(np.float32)
    nr, nc = len(rows), len(cols)
    idx = np.arange(nr * nc, dtype=np.int32).reshape(nr, nc)
    a, b, c_, d = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    faces = np.concatenate([np.stack([a, b, c_], -1).reshape(-1, 3),
                            np.stack([c_, b, d], -1).reshape(-1, 3)])
    return vertices, faces


def ply_bytes(vertices: np.ndarray, faces: np.ndarray, comment: str = "") -> bytes:
    """A binary little-endian PLY: float32 ``x y z`` vertices, triangles as a uchar count and
    int32 indices."""
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {line}" for line in comment.splitlines() if line]
    header += [f"element vertex {len(vertices)}", "property float x", "property float y",
               "property float z", f"element face {len(faces)}",
               "property list uchar int vertex_indices", "end_header"]
    face = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"], face["i"] = 3, faces
    return ("\n".join(header) + "\n").encode() + \
        np.ascontiguousarray(vertices, dtype="<f4").tobytes() + face.tobytes()


def obj_bytes(vertices: np.ndarray, faces: np.ndarray, comment: str = "") -> bytes:
    """A Wavefront OBJ: ``v x y z`` lines (mm, 4 decimals) and ``f`` lines (1-based)."""
    head = "".join(f"# {line}\n" for line in comment.splitlines() if line)
    vlines = "\n".join(f"v {x:.4f} {y:.4f} {z:.4f}" for x, y, z in vertices.tolist())
    flines = "\n".join(f"f {a} {b} {c}" for a, b, c in (faces + 1).tolist())
    return (head + vlines + "\n" + flines + "\n").encode()


def pixel_size(width_px: int, pixel_mm: float | None, object_width_mm: float | None
               ) -> float | None:
    """The pixel size in mm from ``--pixel-size`` or ``--object-width`` (at most one)."""
    if pixel_mm is not None and object_width_mm is not None:
        raise LtmError("give --pixel-size or --object-width, not both")
    for name, value in (("--pixel-size", pixel_mm), ("--object-width", object_width_mm)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise LtmError(f"{name} {value!r} must be a length in mm > 0")
    if object_width_mm is not None:
        return float(object_width_mm) / width_px
    return None if pixel_mm is None else float(pixel_mm)


def write_height(normal: np.ndarray, out_dir: str | os.PathLike, *,
                 method: str = DEFAULT_INTEGRATION, pixel_mm: float | None = None,
                 mesh: bool = False, step: int | None = None) -> tuple[dict[str, Path], dict]:
    """Integrate ``normal`` and write ``height.png`` (16-bit, lowest 0, highest 65535) and
    ``height.json`` (its range in pixels and, with ``pixel_mm``, in mm), and with ``mesh``
    ``height.ply`` and ``height.obj`` in mm (needs ``pixel_mm``) into ``out_dir``.

    Returns
    -------
    files : dict
        The path of each file written, by kind.
    info : dict
        What ``height.json`` holds: the integration, the range in pixels (and mm), the mesh's
        step and size.
    """
    import json

    from ltmstore.core.imagefile import write_bytes_atomic, write_image

    if mesh and pixel_mm is None:
        raise LtmError("--mesh writes millimetres: give the scale with --pixel-size MM or "
                       "--object-width MM")
    step = mesh_step(normal.shape[:2], step)
    height = integrate(normal, method)
    out = Path(out_dir)
    files = {"height": write_image(out / "height.png", height_png(height), what="height map")}
    info = {"integration": method, "range_px": float(height.max()),
            "png": "0 at the lowest point, 65535 at the highest, linear"}
    if pixel_mm is not None:
        info.update(pixel_mm=pixel_mm, range_mm=float(height.max()) * pixel_mm)
    if mesh:
        vertices, faces = grid_mesh(height, pixel_mm, step)
        note = (f"ltm maps height ({method}), mm, every {step} px, x right y up z height\n")
        files["ply"] = write_bytes_atomic(out / "height.ply", ply_bytes(vertices, faces, note),
                                          what="mesh")
        files["obj"] = write_bytes_atomic(out / "height.obj", obj_bytes(vertices, faces, note),
                                          what="mesh")
        info.update(mesh_step_px=step, vertices=len(vertices), triangles=len(faces))
    files["json"] = write_bytes_atomic(out / "height.json",
                                       (json.dumps(info, indent=1) + "\n").encode(),
                                       what="height info")
    return files, info

"""A normal map integrated into a height map, in pixels: what the surface's cast shadows
(:mod:`ltmstore.solve.shadows`), ``ltm maps --height`` and its meshes
(:mod:`ltmstore.share.height`) stand on.

A unit normal ``n`` (x right, y up, z towards the camera) is the gradient of the height ``z``:
``dz/dx = -nx / nz`` along a row, ``dz/drow = ny / nz`` down a column (rows grow with -y), in
pixels per pixel. Two well-kept integrations of that gradient field:

* ``"fc"``: Frankot and Chellappa (1988): the integrable surface nearest the gradients in the
  Fourier domain, on the field mirrored to twice its size (an even extension, so that the
  periodic transform sees no jump at the borders);
* ``"poisson"`` (the default): the least-squares height of the forward differences (the
  discrete Poisson equation with Neumann borders), solved exactly with the DCT (Simchony,
  Chellappa and Shao 1990);
* ``"bilateral"``: bilateral normal integration (Cao, Ishikawa and Matsushita 2022, the
  orthographic case): each pixel's height difference to its left and right (upper and lower)
  neighbour is weighted by which of the two is smoother, so that a step (a relief's occluding
  edge) is not spread over its neighbours as least squares spreads it; iteratively reweighted
  least squares from the ``poisson`` height, each step a conjugate-gradient solve.

Both leave one unknown, the height's offset: the maps put the lowest point at 0. Normals that
are not finite (a tile that chose another method) count as facing the camera; ``nz`` is kept at
least :data:`MIN_NZ` (slopes at most 20 pixels per pixel).
"""

from __future__ import annotations

import numpy as np
from scipy import fft

from ltmstore.core.errors import LtmError

INTEGRATIONS = ("poisson", "fc", "bilateral")
DEFAULT_INTEGRATION = "poisson"
MIN_NZ = 0.05


def gradients(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(dz/dcol, dz/drow)`` of unit normals ``(H, W, 3)``, each ``(H, W)`` float64, in pixels
    per pixel; non-finite normals face the camera."""
    n = np.asarray(normal, dtype=np.float64)
    if n.ndim != 3 or n.shape[-1] != 3:
        raise LtmError(f"normal map of shape {n.shape}; expected (height, width, 3)")
    n = np.where(np.isfinite(n).all(axis=-1, keepdims=True), n, [0.0, 0.0, 1.0])
    nz = np.maximum(n[..., 2], MIN_NZ)
    return -n[..., 0] / nz, n[..., 1] / nz


def frankot_chellappa(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """The height ``(H, W)`` whose gradient (``gx`` along columns, ``gy`` along rows) is
    nearest ``(gx, gy)`` among integrable fields, in the Fourier domain, on the gradients
    mirrored to ``(2H, 2W)`` (Frankot and Chellappa 1988). Mean zero."""
    h, w = gx.shape
    wx = (2 * np.pi * fft.rfftfreq(2 * w))[None, :]
    wy = (2 * np.pi * fft.fftfreq(2 * h))[:, None]
    # single precision, real transforms: a 12 MP map mirrored is 48 M values
    ex = np.block([[gx, -gx[:, ::-1]], [gx[::-1], -gx[::-1, ::-1]]]).astype(np.float32)
    z = fft.rfft2(ex, workers=-1) * (-1j * wx).astype(np.complex64)
    del ex
    ey = np.block([[gy, gy[:, ::-1]], [-gy[::-1], -gy[::-1, ::-1]]]).astype(np.float32)
    z += fft.rfft2(ey, workers=-1) * (-1j * wy).astype(np.complex64)
    del ey
    denom = (wx**2 + wy**2).astype(np.float32)
    denom[0, 0] = 1.0
    z /= denom
    z[0, 0] = 0.0
    height = fft.irfft2(z, s=(2 * h, 2 * w), workers=-1)[:h, :w].astype(np.float64)
    return height - height.mean()


def poisson(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """The least-squares height ``(H, W)`` of the forward differences: ``z[r, c+1] - z[r, c]``
    nearest the mean of ``gx`` at both pixels, likewise down the rows; the normal equations
    (a Neumann Laplacian) solved exactly with the DCT-II. Mean zero."""
    h, w = gx.shape
    ex = np.zeros((h, w + 1))
    ex[:, 1:w] = 0.5 * (gx[:, 1:] + gx[:, :-1])
    ey = np.zeros((h + 1, w))
    ey[1:h] = 0.5 * (gy[1:] + gy[:-1])
    rhs = (ex[:, :-1] - ex[:, 1:]) + (ey[:-1] - ey[1:])  # D^T g
    z = fft.dctn(rhs, type=2, norm="ortho") / _neumann_eigenvalues((h, w))
    z[0, 0] = 0.0
    return fft.idctn(z, type=2, norm="ortho")


# Bilateral integration: the sigmoid's sharpness (the paper's k = 2), the iterations and the
# relative change of the energy at which they stop, and the conjugate gradient's tolerance.
BILATERAL_K = 2.0
BILATERAL_ITERATIONS = 20
BILATERAL_TOL = 1e-4
BILATERAL_CG_TOL = 1e-3


def _one_sided(shape: tuple[int, int], nz: np.ndarray):
    """The four one-sided differences ``nz (z[next] - z)`` as sparse ``(N, N)`` operators on
    the flattened ``(H, W)`` grid: right, left, down, up (a row of zeros where the neighbour
    lies outside the image)."""
    from scipy import sparse

    h, w = shape
    index = np.arange(h * w).reshape(h, w)
    weight = nz.ravel()
    ops = []
    for axis, step in ((1, 1), (1, -1), (0, 1), (0, -1)):
        has = np.zeros((h, w), bool)
        inner = [slice(None), slice(None)]
        inner[axis] = slice(0, -1) if step > 0 else slice(1, None)
        has[tuple(inner)] = True
        here = index[has]
        there = here + step * (w if axis == 0 else 1)
        sign = float(step)  # left and up: z - z[previous]
        rows = np.concatenate([here, here])
        cols = np.concatenate([there, here])
        vals = np.concatenate([sign * weight[here], -sign * weight[here]])
        ops.append(sparse.csr_matrix((vals, (rows, cols)), shape=(h * w, h * w)))
    return ops


def _neumann_eigenvalues(shape: tuple[int, int]) -> np.ndarray:
    """The eigenvalues ``(H, W)`` of the grid's Neumann Laplacian on the DCT-II basis, the
    constant's set to 1 (it is left as it is)."""
    h, w = shape
    eig = (2 - 2 * np.cos(np.pi * np.arange(h) / h))[:, None] + \
        (2 - 2 * np.cos(np.pi * np.arange(w) / w))[None, :]
    eig[0, 0] = 1.0
    return eig


def _neumann_inverse(shape: tuple[int, int]):
    """The inverse of the grid's Neumann Laplacian (constants kept as they are), applied to a
    flattened ``(H, W)`` field by the DCT: the preconditioner of the weighted Laplacians that
    :func:`bilateral` solves (the same operator with weights between 0 and 1)."""
    h, w = shape
    eig = _neumann_eigenvalues(shape)

    def apply(r: np.ndarray) -> np.ndarray:
        return fft.idctn(fft.dctn(r.reshape(h, w), type=2, norm="ortho") / eig, type=2,
                         norm="ortho").ravel()
    return apply


def bilateral(gx: np.ndarray, gy: np.ndarray, nz: np.ndarray) -> np.ndarray:
    """The bilateral normal integration (see the module docstring) of the gradients ``gx``
    (along columns) and ``gy`` (down rows) of normals whose ``z`` component is ``nz``. Mean
    zero."""
    from scipy import sparse
    from scipy.sparse.linalg import LinearOperator, cg

    right, left, down, up = _one_sided(gx.shape, nz)
    inverse = _neumann_inverse(gx.shape)
    a = sparse.vstack([right, left, down, up]).tocsr()
    bu, bv = (nz * gx).ravel(), (nz * gy).ravel()
    b = np.concatenate([bu, bu, bv, bv])
    z = poisson(gx, gy).ravel()
    weights = np.full(len(b), 0.5)

    def energy(z: np.ndarray) -> float:
        r = a @ z - b
        return float(weights @ (r * r))

    def sigmoid(x: np.ndarray) -> np.ndarray:
        return 0.5 * (1 + np.tanh(0.5 * BILATERAL_K * x))

    rows, cols = np.indices(gx.shape)
    last_col, last_row = (cols == gx.shape[1] - 1).ravel(), (rows == gx.shape[0] - 1).ravel()
    first_col, first_row = (cols == 0).ravel(), (rows == 0).ravel()
    previous = energy(z)
    for _ in range(BILATERAL_ITERATIONS):
        du, dv = right @ z, down @ z
        wu = sigmoid((left @ z) ** 2 - du**2)  # the smoother side weighs more
        wv = sigmoid((up @ z) ** 2 - dv**2)
        wu[last_col], wu[first_col] = 0.0, 1.0  # at the border, the one neighbour there is
        wv[last_row], wv[first_row] = 0.0, 1.0
        weights = np.concatenate([wu, 1 - wu, wv, 1 - wv])
        normal = (a.T @ sparse.diags(weights) @ a).tocsr()
        rhs = a.T @ (weights * b)
        z, _ = cg(normal, rhs, x0=z, rtol=BILATERAL_CG_TOL,
                  M=LinearOperator(normal.shape, matvec=inverse, dtype=np.float64))
        current = energy(z)
        if abs(previous - current) <= BILATERAL_TOL * max(previous, 1e-30):
            break
        previous = current
    height = z.reshape(gx.shape)
    return height - height.mean()


def integrate(normal: np.ndarray, method: str = DEFAULT_INTEGRATION) -> np.ndarray:
    """The height map of unit normals ``(H, W, 3)``, in pixels, lowest point 0.

    Parameters
    ----------
    normal : ndarray, shape (H, W, 3)
        Unit normals, x right, y up, z towards the camera.
    method : {"poisson", "fc", "bilateral"}
        Least squares with the DCT, Frankot-Chellappa with mirror padding, or bilateral normal
        integration.

    Returns
    -------
    ndarray of float64, shape (H, W)
    """
    if method not in INTEGRATIONS:
        raise LtmError(f"integration {method!r} must be one of {', '.join(INTEGRATIONS)}")
    gx, gy = gradients(normal)
    if method == "bilateral":
        n = np.asarray(normal, dtype=np.float64)
        nz = np.where(np.isfinite(n).all(axis=-1), np.maximum(n[..., 2], MIN_NZ), 1.0)
        height = bilateral(gx, gy, nz)
    else:
        height = (poisson if method == "poisson" else frankot_chellappa)(gx, gy)
    return height - height.min()


def normals_of(height: np.ndarray) -> np.ndarray:
    """Unit normals ``(H, W, 3)`` of a height map in pixels (central differences): the
    inverse of :func:`integrate`, to check an integration against the normals it came from."""
    gy, gx = np.gradient(np.asarray(height, dtype=np.float64))
    n = np.stack([-gx, gy, np.ones_like(gx)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)

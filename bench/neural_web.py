"""What OpenLIME's neural layer could carry of a store: its network trained on the store.

OpenLIME's ``LayerNeuralRTI`` (``ShaderNeural``) draws a pixel from 9 codes (three 8-bit
textures) and the light's ``(x, y)`` through one network shared by every pixel: 11 inputs, two
hidden layers of ``--hidden`` ELU units, 3 outputs (display values). This bench fits that
network to the store as the neural RTI papers do, with an encoder from each pixel's values at a
grid of light directions to its 9 codes, trained by Adam on the store relit at the grid's nodes
and at random directions (a subsample of pixels, as the bilinear export samples them), then
scores the decoded images at the held-out lights against the photographs, beside ``ltm
relight`` and the bilinear export. No file is written for a viewer: the question is whether the
format can hold the model at all.

    python bench/neural_web.py loewenkopf=loew.zarr synthrti=S.zarr --steps 20000
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ltmstore.core.lights import disk_to_direction  # noqa: E402
from ltmstore.share import fidelity, pca_web  # noqa: E402
from ltmstore.share.light_grid import grid_directions  # noqa: E402

CODES = 9  # OpenLIME's neural layer: three RGB textures


def elu(p: np.ndarray) -> np.ndarray:
    return np.where(p > 0, p, np.expm1(np.minimum(p, 0)))


def elu_slope(p: np.ndarray, a: np.ndarray) -> np.ndarray:
    return np.where(p > 0, 1.0, a + 1.0).astype(np.float32)


class Network:
    """Encoder (values at the grid -> codes) and OpenLIME's decoder (codes, light -> RGB)."""

    def __init__(self, inputs: int, hidden: int, rng: np.random.Generator) -> None:
        def layer(i: int, o: int) -> list[np.ndarray]:
            return [(rng.standard_normal((i, o)) * np.sqrt(2 / i)).astype(np.float32),
                    np.zeros(o, np.float32)]
        self.w = [*layer(inputs, hidden), *layer(hidden, hidden), *layer(hidden, CODES),
                  *layer(CODES, hidden), layer(2, hidden)[0], *layer(hidden, hidden),
                  *layer(hidden, 3)]
        self.m = [np.zeros_like(q) for q in self.w]
        self.v = [np.zeros_like(q) for q in self.w]
        self.t = 0

    def encode(self, x: np.ndarray) -> tuple[np.ndarray, tuple]:
        e1, b1, e2, b2, e3, b3 = self.w[:6]
        p1 = x @ e1 + b1
        h1 = elu(p1)
        p2 = h1 @ e2 + b2
        h2 = elu(p2)
        return h2 @ e3 + b3, (x, p1, h1, p2, h2)

    def decode(self, z: np.ndarray, light: np.ndarray) -> tuple[np.ndarray, tuple]:
        """RGB ``(pixels, lights, 3)`` of codes ``(pixels, 9)`` at lights ``(lights, 2)``."""
        v1z, c1, v1l, v2, c2, v3, c3 = self.w[6:]
        q1 = (z @ v1z)[:, None, :] + (light @ v1l)[None] + c1
        a1 = elu(q1)
        q2 = a1 @ v2 + c2
        a2 = elu(q2)
        return a2 @ v3 + c3, (q1, a1, q2, a2)

    def step(self, x: np.ndarray, light: np.ndarray, target: np.ndarray, lr: float) -> float:
        """One Adam step on the mean squared error; returns it."""
        z, (x, p1, h1, p2, h2) = self.encode(x)
        y, (q1, a1, q2, a2) = self.decode(z, light)
        dy = (2.0 / y.size) * (y - target)
        e1, b1, e2, b2, e3, b3, v1z, c1, v1l, v2, c2, v3, c3 = self.w
        n = v2.shape[0]
        dq2 = (dy @ v3.T) * elu_slope(q2, a2)
        dq1 = (dq2 @ v2.T) * elu_slope(q1, a1)
        per_pixel = dq1.sum(1)
        dz = per_pixel @ v1z.T
        dp2 = (dz @ e3.T) * elu_slope(p2, h2)
        dp1 = (dp2 @ e2.T) * elu_slope(p1, h1)
        grads = [x.T @ dp1, dp1.sum(0), h1.T @ dp2, dp2.sum(0), h2.T @ dz, dz.sum(0),
                 z.T @ per_pixel, dq1.sum((0, 1)), light.T @ dq1.sum(0),
                 a1.reshape(-1, n).T @ dq2.reshape(-1, n), dq2.sum((0, 1)),
                 a2.reshape(-1, n).T @ dy.reshape(-1, 3), dy.sum((0, 1))]
        self.t += 1
        for q, g, m, v in zip(self.w, grads, self.m, self.v, strict=True):
            m *= 0.9
            m += 0.1 * g
            v *= 0.999
            v += 0.001 * g * g
            q -= lr * (m / (1 - 0.9 ** self.t)) / (np.sqrt(v / (1 - 0.999 ** self.t)) + 1e-8)
        return float(np.mean((y - target) ** 2))


def trial(store: str, steps: int, hidden: int, resolution: int, seed: int = 0) -> dict:
    """Train the network on ``store`` and score it at the held-out lights."""
    rng = np.random.default_rng(seed)
    render = pca_web._Renderer(store)
    nodes = grid_directions(resolution)
    radius = np.sqrt(rng.uniform(0, 1, 512)) * 0.999
    angle = rng.uniform(0, 2 * np.pi, 512)
    extra = disk_to_direction(radius * np.cos(angle), radius * np.sin(angle))
    grid = render.sample(nodes)
    pixels = len(grid)
    target = np.concatenate([grid.reshape(pixels, -1, 3),
                             render.sample(extra).reshape(pixels, -1, 3)], axis=1)
    lights = np.concatenate([nodes[:, :2], extra[:, :2]]).astype(np.float32)
    net = Network(grid.shape[1], hidden, rng)
    start, lr, losses = time.perf_counter(), 1e-3, []
    for i in range(steps):
        if i in (int(steps * 0.6), int(steps * 0.85)):
            lr *= 0.3
        p = rng.choice(pixels, 64, replace=False)
        li = rng.choice(len(lights), 128, replace=False)
        losses.append(net.step(grid[p], lights[li], target[p][:, li], lr))
    seconds = time.perf_counter() - start
    check = fidelity.checkpoints(store)
    s = render.strided
    photos, relit = check.photos[:, s, s], check.store[:, s, s]
    codes, _ = net.encode(grid)
    lo, hi = codes.min(0), codes.max(0)
    codes = np.round((codes - lo) / (hi - lo) * 255) / 255 * (hi - lo) + lo  # 8-bit textures
    y, _ = net.decode(codes, check.directions[:, :2].astype(np.float32))
    images = fidelity.display_images(y.transpose(1, 0, 2).reshape(photos.shape))
    return {"pixels": pixels, "grid": resolution, "hidden": hidden, "steps": steps,
            "train_s": round(seconds, 1), "final_mse": round(float(np.mean(losses[-500:])), 6),
            "neural_db_vs_photos": round(fidelity.psnr(images, photos), 2),
            "store_db_vs_photos": round(fidelity.psnr(relit, photos), 2),
            "neural_db_vs_store": round(fidelity.psnr(images, relit), 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("stores", nargs="+", help="NAME=STORE (reconstructed, held-out lights)")
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--hidden", type=int, default=48, help="units a hidden layer (OpenLIME's "
                    "uniforms hold about 52)")
    ap.add_argument("--resolution", type=int, default=16, help="encoder's grid, nodes a side")
    ap.add_argument("--out", default="bench/results")
    args = ap.parse_args()
    results = {}
    for item in args.stores:
        name, store = item.split("=", 1)
        results[name] = trial(store, args.steps, args.hidden, args.resolution)
        print(name, results[name], flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "neural_web.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()

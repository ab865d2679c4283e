#!/usr/bin/env python3
"""Independent reference for `compend metrics` (docs/architecture.md, "Models"), used to make the fixtures
in tests/fixtures/metrics and the expected numbers in tests/metrics.rs.

It shares no code with compend: images are read with Pillow, filtering is SciPy's
`ndimage.correlate1d` with mode="nearest" (replicate padding), in float64.

Conventions: values = 8-bit / 255; MSE pooled over all pixels, channels and images;
PSNR = 10 log10(1 / MSE); RMSE = sqrt(3 MSE); SSIM per channel with an 11-tap Gaussian
(sigma 1.5, normalised), C1 = 0.01^2, C2 = 0.03^2, mean of the full-size map over pixels,
channels, then images.

Usage: metrics_ref.py make DIR      # writes DIR/a/img_000{1,2,3}.png and DIR/b/... (seeded)
       metrics_ref.py score A B     # A, B: two PNGs or two folders of same-named PNGs
"""
import json
import os
import sys

import numpy as np
from PIL import Image
from scipy.ndimage import correlate1d


def load(path):
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64) / 255.0


def gauss(sigma=1.5, radius=5):
    d = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-(d * d) / (2 * sigma * sigma))
    return k / k.sum()


def blur(x, k):
    return correlate1d(correlate1d(x, k, axis=1, mode="nearest"), k, axis=0, mode="nearest")


def ssim(a, b):
    k = gauss()
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    vals = []
    for c in range(3):
        x, y = a[..., c], b[..., c]
        mx, my = blur(x, k), blur(y, k)
        vx = blur(x * x, k) - mx * mx
        vy = blur(y * y, k) - my * my
        cxy = blur(x * y, k) - mx * my
        m = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
        vals.append(m.mean())
    return float(np.mean(vals))


def score(pairs):
    se, n_val, ss = 0.0, 0, []
    for pa, pb in pairs:
        a, b = load(pa), load(pb)
        se += float(((a - b) ** 2).sum())
        n_val += a.size
        ss.append(ssim(a, b))
    mse = se / n_val
    return {"psnr": 10 * np.log10(1 / mse), "rmse": float(np.sqrt(3 * mse)), "ssim": float(np.mean(ss)), "n": len(pairs)}


def make(root):
    rng = np.random.default_rng(20261122)
    h, w = 40, 48
    yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w]).reshape(2, 1, 1)
    for i in range(1, 4):
        base = np.stack([np.sin(6 * xx * i + c) * 0.4 + 0.5 + 0.1 * np.cos(9 * yy + c) for c in range(3)], -1)
        base += rng.normal(0, 0.05, base.shape)
        other = base * (0.8 + 0.1 * i) + 0.05 * i + rng.normal(0, 0.03 * i, base.shape)
        other[5:15, 10:30] = rng.uniform(0, 1, (10, 20, 3))  # a patch of unrelated content
        for sub, img in (("a", base), ("b", other)):
            os.makedirs(os.path.join(root, sub), exist_ok=True)
            q = np.clip(np.rint(np.clip(img, 0, 1) * 255), 0, 255).astype(np.uint8)
            Image.fromarray(q, "RGB").save(os.path.join(root, sub, "img_%04d.png" % i))


if __name__ == "__main__":
    if sys.argv[1] == "make":
        make(sys.argv[2])
    else:
        a, b = sys.argv[2], sys.argv[3]
        if os.path.isdir(a):
            names = sorted(n for n in os.listdir(a) if n.lower().endswith(".png"))
            pairs = [(os.path.join(a, n), os.path.join(b, n)) for n in names]
        else:
            pairs = [(a, b)]
        print(json.dumps(score(pairs)))

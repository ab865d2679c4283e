#!/usr/bin/env python3
"""The CompenNet++ training step of `compend bench-train`, in PyTorch, for the framework ratio.

`compend bench-train --torch PYTHON` runs this script in the same run as its own measurement and
reports candle's ms per sample against PyTorch's. It builds the same network (docs/architecture.md, "Models":
WarpingNet with affine + TPS + refinement, CompenNet at base width W), the same loss
(L1 + 1 - SSIM, 11-tap Gaussian window, replicate padding) and the same optimiser (Adam, L2 weight
decay 1e-4 on the gradient), on random data of the same sizes, and times `steps` training steps
after one untimed step. Prints one JSON object on stdout.

Needs PyTorch (CPU build is enough): python3 -m pip install torch
"""

import argparse
import json
import math
import time

import torch
import torch.nn as nn
import torch.nn.functional as F


class WarpingNet(nn.Module):
    """Affine + TPS grid (network side S, TPS basis precomputed as in compend) and the refinement
    CNN on the 2-channel grid."""

    def __init__(self, side, refine=True):
        super().__init__()
        self.theta = nn.Parameter(torch.tensor([[0.8, 0.0, 0.0], [0.0, 0.8, 0.0]]))
        self.tps = nn.Parameter(torch.randn(2, 38) * 1e-3)
        ys, xs = torch.meshgrid(
            torch.linspace(-1, 1, side), torch.linspace(-1, 1, side), indexing="ij"
        )
        self.register_buffer("base", torch.stack([xs, ys], -1).reshape(-1, 2))
        # Same shape and cost as compend's TPS basis (H*W, 38); values do not matter for timing.
        self.register_buffer("basis", torch.randn(side * side, 38) * 1e-2)
        self.side = side
        self.refine = None
        if refine:
            self.refine = nn.Sequential(
                nn.Conv2d(2, 32, 3, 2, 1), nn.ReLU(),
                nn.Conv2d(32, 64, 3, 2, 1), nn.ReLU(),
                nn.ConvTranspose2d(64, 32, 2, 2), nn.ReLU(),
                nn.ConvTranspose2d(32, 2, 2, 2), nn.LeakyReLU(0.1),
            )
            for m in self.refine:
                if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
                    nn.init.normal_(m.weight, 0.0, 1e-4)
                    nn.init.zeros_(m.bias)

    def grid(self):
        t = self.base + 2.0 * self.basis @ self.tps.t()
        g = torch.cat([t, torch.ones_like(t[:, :1])], 1) @ self.theta.t()
        g = g.reshape(1, self.side, self.side, 2)
        if self.refine is not None:
            gc = g.permute(0, 3, 1, 2)
            g = (gc + self.refine(gc)).clamp(-1, 1).permute(0, 2, 3, 1)
        return g


class CompenNet(nn.Module):
    def __init__(self, w):
        super().__init__()
        c = lambda i, o, k, s, p: nn.Conv2d(i, o, k, s, p)
        self.conv1_s, self.conv2_s = c(3, w, 3, 2, 1), c(w, 2 * w, 3, 2, 1)
        self.conv3_s, self.conv4_s = c(2 * w, 4 * w, 3, 1, 1), c(4 * w, 8 * w, 3, 1, 1)
        self.skip1 = nn.ModuleList([c(3, 3, 3, 1, 1) for _ in range(3)])
        self.conv1, self.skip2 = c(3, w, 3, 2, 1), c(w, 2 * w, 1, 1, 0)
        self.conv2, self.skip3 = c(w, 2 * w, 3, 2, 1), c(2 * w, 4 * w, 1, 1, 0)
        self.conv3, self.conv4 = c(2 * w, 4 * w, 3, 1, 1), c(4 * w, 8 * w, 3, 1, 1)
        self.conv5 = c(8 * w, 4 * w, 3, 1, 1)
        self.tconv1 = nn.ConvTranspose2d(4 * w, 2 * w, 2, 2)
        self.tconv2 = nn.ConvTranspose2d(2 * w, w, 2, 2)
        self.conv6 = c(w, 3, 3, 1, 1)
        for m in self.modules():
            if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
                nn.init.kaiming_normal_(m.weight)
                nn.init.zeros_(m.bias)

    def surface(self, s):
        s1 = F.relu(self.conv1_s(s))
        s2 = F.relu(self.conv2_s(s1))
        s3 = F.relu(self.conv3_s(s2))
        s4 = F.relu(self.conv4_s(s3))
        return s1, s2, s3, s4

    def forward(self, x, s):
        s1, s2, s3, s4 = s
        res1 = x
        for m in self.skip1:
            res1 = F.relu(m(res1))
        a1 = F.relu(self.conv1(x) + s1)
        res2 = self.skip2(a1)
        a2 = F.relu(self.conv2(a1) + s2)
        res3 = self.skip3(a2)
        a3 = F.relu(self.conv3(a2) + s3)
        a4 = F.relu(self.conv4(a3) + s4)
        a5 = F.relu(self.conv5(a4) + res3)
        a6 = F.relu(self.tconv1(a5) + res2)
        a7 = F.relu(self.tconv2(a6))
        return torch.clamp(F.relu(self.conv6(a7) + res1), max=1.0)


def ssim(x, y):
    r, sigma = 5, 1.5
    g = torch.exp(-((torch.arange(2 * r + 1) - r) ** 2) / (2 * sigma * sigma))
    g = (g / g.sum()).to(x.dtype)
    n, c, h, w = x.shape
    kx, ky = g.view(1, 1, 1, -1), g.view(1, 1, -1, 1)

    def blur(t):
        t = t.reshape(n * c, 1, h, w)
        t = F.conv2d(F.pad(t, (r, r, 0, 0), mode="replicate"), kx)
        t = F.conv2d(F.pad(t, (0, 0, r, r), mode="replicate"), ky)
        return t.reshape(n, c, h, w)

    c1, c2 = 0.01 ** 2, 0.03 ** 2
    mx, my = blur(x), blur(y)
    vx, vy, cxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return s.mean()


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--network", type=int, default=256)
    p.add_argument("--width", type=int, default=32)
    p.add_argument("--camera", default="640x480")
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--steps", type=int, default=3)
    p.add_argument("--threads", type=int, default=0, help="0 = PyTorch's default")
    a = p.parse_args()
    if a.threads > 0:
        torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    cw, ch = (int(v) for v in a.camera.split("x"))
    warp, compen = WarpingNet(a.network), CompenNet(a.width)
    params = list(warp.parameters()) + list(compen.parameters())
    opt = torch.optim.Adam(params, lr=1e-3, weight_decay=1e-4)
    caps = torch.rand(a.batch, 3, ch, cw)
    surf = torch.rand(1, 3, ch, cw)
    tgt = torch.rand(a.batch, 3, a.network, a.network)
    marks = []
    for _ in range(a.steps + 1):
        opt.zero_grad(set_to_none=True)
        g = warp.grid()
        sw = F.grid_sample(surf, g, mode="bilinear", padding_mode="zeros", align_corners=True)
        feats = compen.surface(sw)
        xw = F.grid_sample(caps, g.expand(a.batch, -1, -1, -1), mode="bilinear",
                           padding_mode="zeros", align_corners=True)
        out = compen(xw, feats)
        loss = (out - tgt).abs().mean() + (1 - ssim(out, tgt))
        loss.backward()
        opt.step()
        marks.append(time.perf_counter())
    ms = 1e3 * (marks[-1] - marks[0]) / (a.steps * a.batch)
    step_ms = [1e3 * (b - a_) for a_, b in zip(marks, marks[1:])]
    print(json.dumps({
        "framework": "pytorch " + torch.__version__,
        "threads": torch.get_num_threads(),
        "network": a.network, "width": a.width, "batch": a.batch, "steps": a.steps,
        "train_ms_per_sample": ms,
        "step_ms": step_ms,
        "loss": float(loss.detach()),
        "ok": math.isfinite(float(loss.detach())),
    }))


if __name__ == "__main__":
    main()

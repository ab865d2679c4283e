#!/usr/bin/env python3
"""Recorded real captures from "Efficient Full Projector Compensation using Natural Images"
(github.com/kylin-leo/FullProjectorCompensation, folder `dataset/`) in compend's dataset layout
(docs/architecture.md, "Dataset layout"), for `compend train`, `eval` and `bench` on real data.

What the source holds (one setup per capture folder, e.g. `captured_1`, a floral-print fabric):
  projected/seq{i}.jpg   projector inputs, 800×600 sRGB-encoded; seq0 is full white
  CAPTURES/img{i}.tiff   camera captures of seq{i} (1024×768 for captured_1); img0 the surface
                         under full white
There is no black and no gray reference capture. This script writes:
  ROOT/train/, ROOT/test/   the projector inputs resized to SIZE×SIZE network pixels (area
                            average of the 8-bit values, as the paper protocol's 256² images),
                            the first NTRAIN usable pairs for training, the rest for test
  SETUP/cam/raw/train/, test/   the captures, unchanged (lossless TIFF → PNG)
  SETUP/cam/raw/ref/img_0125.png   white: img0
  SETUP/cam/raw/ref/img_0126.png   the surface image s̃: img0 as well (the paper's s̃ is the
                            surface under a gray image; only white was captured)
  SETUP/cam/raw/ref/img_0001.png   black: not captured. A uniform image at the camera's dark
                            level, the per-channel median of the pixels outside the projector's
                            footprint (where img0 is below THRESH) over every paired capture.
                            It lacks the projector's own black level inside the footprint; the
                            linear rungs fit their offset from the pairs, the black reference
                            only bounds the field of view.
  SETUP/import.json         the source, the pairing, what was left out and why, the dark level
A capture whose footprint comes less than 5 % of the way from the dark level to the white
capture, and less than a quarter of the way its input's mean linear value would take it, is a
failed capture: left out, and reported. An index with an input or a capture alone is too.
Each capture is also checked against every projector input: the capture divided by the white
capture (which takes out most of the surface's texture), in the footprint's bounding box at
64×48, correlated with each input's linear values (8-bit / 255, to the power 2.2). A capture
that shows another input clearly better than its own (correlation higher by MARGIN) is paired
with that one if that input has no capture of its own left, otherwise left out; both are
reported (in captured_1, img70 shows seq69, whose own capture failed).

Needs Pillow and NumPy (python3 -m pip install pillow numpy).
Usage: import_fpc.py --src FullProjectorCompensation/dataset --captures captured_1 --out ROOT
       [--setup floral] [--ntrain 54] [--size 256]
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

# Of the white capture's 8-bit values (mean of the channels), what counts as inside the
# projector's footprint, to estimate the dark level outside it.
THRESH = 40.0
# A capture whose footprint comes less than this fraction of the way from the dark level to the
# white capture, and less than a quarter of what its input predicts, failed.
MIN_LIGHT = 0.05
# How much better another input must match a capture than its own to re-pair it.
MARGIN = 0.2


def fail(msg, code=2):
    print(f"import_fpc: {msg}", file=sys.stderr)
    sys.exit(code)


def load_rgb(path):
    try:
        with Image.open(path) as im:
            if im.mode not in ("RGB", "RGBA", "L"):
                fail(f"{path}: mode {im.mode}, expected 8-bit RGB")
            return np.asarray(im.convert("RGB"))
    except (OSError, ValueError) as e:
        fail(f"{path}: not a readable image ({e})")


def save_png(arr, path):
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(arr).save(path)


def shown_inputs(caps, prjs, white, footprint):
    """For each capture index: the correlation of what it shows with every input index."""
    ys, xs = np.nonzero(footprint)
    h, w = ys.max() - ys.min(), xs.max() - xs.min()
    box = (xs.min() + w // 30, ys.min() + h // 30, xs.max() - w // 30, ys.max() - h // 30)

    def small(arr, crop=None):
        im = Image.fromarray(arr)
        if crop:
            im = im.crop(crop)
        return np.asarray(im.resize((64, 48), Image.Resampling.BOX)).astype(np.float64)

    def unit(v):
        v = v.ravel() - v.mean()
        return v / (np.linalg.norm(v) + 1e-9)

    base = small(white, box) + 1.0
    inputs = {j: unit((small(p) / 255.0) ** 2.2) for j, p in prjs.items()}
    return {
        i: {j: float(unit(small(c, box) / base) @ v) for j, v in inputs.items()}
        for i, c in caps.items()
    }


def indices(folder, prefix, suffix):
    """The indices i of the files PREFIX{i}SUFFIX in `folder`."""
    out = set()
    for f in folder.iterdir():
        n = f.name
        if n.startswith(prefix) and n.endswith(suffix) and n[len(prefix) : -len(suffix)].isdigit():
            out.add(int(n[len(prefix) : -len(suffix)]))
    return out


def channel_medians(images, mask):
    """Each channel's median over the pixels of `images` (8-bit) where `mask` holds."""
    hist = np.zeros((3, 256), dtype=np.int64)
    for img in images:
        px = img[mask]
        for ch in range(3):
            hist[ch] += np.bincount(px[:, ch], minlength=256)
    cum = hist.cumsum(axis=1)
    return np.array([float(np.searchsorted(cum[ch], (cum[ch, -1] + 1) // 2)) for ch in range(3)])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--src", required=True, type=Path, help="the repository's dataset/ folder")
    ap.add_argument("--captures", default="captured_1", help="capture folder under --src")
    ap.add_argument("--out", required=True, type=Path, help="data root to create")
    ap.add_argument("--setup", default="floral", help="setup folder under the data root")
    ap.add_argument("--ntrain", type=int, default=54, help="usable pairs for training")
    ap.add_argument("--size", type=int, default=256, help="network side, pixels")
    a = ap.parse_args()

    if a.ntrain < 1:
        fail(f"--ntrain {a.ntrain}: expected at least 1")
    if not 8 <= a.size <= 4096:
        fail(f"--size {a.size}: expected a network side of 8 to 4096 pixels")
    prj_dir, cap_dir = a.src / "projected", a.src / a.captures
    for d in (prj_dir, cap_dir):
        if not d.is_dir():
            fail(f"{d}: not a folder (expected the repository's dataset/{d.name})")
    if a.out.exists() and (not a.out.is_dir() or any(a.out.iterdir())):
        fail(f"{a.out}: exists and is not an empty folder; give a new one")

    white = load_rgb(cap_dir / "img0.tiff")
    cam_h, cam_w, _ = white.shape
    footprint = white.astype(np.float64).mean(axis=2) >= THRESH
    if footprint.mean() < 0.01:
        fail(f"{cap_dir / 'img0.tiff'}: no projector footprint (expected the surface under white)")

    # The pairs: seq{i} with img{i}, every i ≥ 1 that has both; an index with one alone is
    # reported.
    seqs, imgs = indices(prj_dir, "seq", ".jpg") - {0}, indices(cap_dir, "img", ".tiff") - {0}
    pairs = sorted(seqs & imgs)
    unmatched = [f"projected/seq{i}.jpg" for i in sorted(seqs - imgs)]
    unmatched += [f"{a.captures}/img{i}.tiff" for i in sorted(imgs - seqs)]
    if not pairs:
        fail(f"{cap_dir}: no pairs img{{i}}.tiff / ../projected/seq{{i}}.jpg")
    if unmatched:
        print(f"import_fpc: no partner, left out: {', '.join(unmatched)}", file=sys.stderr)

    caps, prjs = {}, {}
    for i in pairs:
        c = load_rgb(cap_dir / f"img{i}.tiff")
        if c.shape != white.shape:
            fail(f"{cap_dir / f'img{i}.tiff'}: {c.shape[1]}x{c.shape[0]}, expected {cam_w}x{cam_h}")
        caps[i] = c
        prjs[i] = load_rgb(prj_dir / f"seq{i}.jpg")

    # Failed captures: the footprint comes less than MIN_LIGHT of the way from the dark level
    # to white, and less than a quarter of the way its input's linear values would take it.
    dark = channel_medians(caps.values(), ~footprint)
    span = white[footprint].astype(np.float64).mean(axis=0) - dark
    left_out, lit_ok = [], []
    for i in pairs:
        lit = (caps[i][footprint].astype(np.float64).mean(axis=0) - dark) / np.maximum(span, 1.0)
        expected = ((prjs[i].astype(np.float64) / 255.0) ** 2.2).mean()
        if lit.mean() < MIN_LIGHT and lit.mean() < 0.25 * expected:
            left_out.append({"capture": i, "why": f"failed capture: footprint at {lit.mean():.3f} "
                             f"of the way from the dark level to white, its input's linear mean "
                             f"{expected:.3f}"})
        else:
            lit_ok.append(i)
    # Captures that clearly show another input than their own: paired with it when that input
    # has no capture of its own left, otherwise left out (capture index -> input index).
    shows = shown_inputs({i: caps[i] for i in lit_ok}, prjs, white, footprint)
    input_of, repaired, usable = {}, [], []
    for i in lit_ok:
        j = max(shows[i], key=shows[i].get)
        if j == i or shows[i][j] <= shows[i][i] + MARGIN:
            input_of[i] = i
            usable.append(i)
            continue
        found = {"capture": i, "input": j, "correlation": round(shows[i][j], 3),
                 "with_own_input": round(shows[i][i], 3)}
        if j in lit_ok:
            left_out.append({**found, "why": f"shows seq{j}, which has its own capture"})
        else:
            repaired.append(found)
            input_of[i] = j
            usable.append(i)
    if len(usable) <= a.ntrain:
        fail(f"{len(usable)} usable pairs, --ntrain {a.ntrain} leaves none for test")

    # Written to a sibling folder first, renamed into place when complete.
    tmp = a.out.with_name(a.out.name + ".importing")
    if tmp.exists():
        fail(f"{tmp}: exists (an interrupted import?); remove it first")
    setup = tmp / a.setup
    split = {"train": usable[: a.ntrain], "test": usable[a.ntrain :]}
    for name, idx in split.items():
        for n, i in enumerate(idx, 1):
            p = Image.fromarray(prjs[input_of[i]]).resize((a.size, a.size), Image.Resampling.BOX)
            save_png(np.asarray(p), tmp / name / f"img_{n:04d}.png")
            save_png(caps[i], setup / "cam" / "raw" / name / f"img_{n:04d}.png")
    ref = setup / "cam" / "raw" / "ref"
    black = np.broadcast_to(np.round(dark).astype(np.uint8), white.shape).copy()
    save_png(black, ref / "img_0001.png")
    save_png(white, ref / "img_0125.png")
    save_png(white, ref / "img_0126.png")
    record = {
        "source": str(a.src.resolve()),
        "captures": a.captures,
        "pairing": "projected/seq{i}.jpg with CAPTURES/img{i}.tiff",
        "train": [[i, input_of[i]] for i in split["train"]],
        "test": [[i, input_of[i]] for i in split["test"]],
        "pairs_as": "[capture index, projector input index], in file order",
        "unmatched": unmatched,
        "left_out": left_out,
        "repaired": repaired,
        "correlation_with_own_input": {str(i): round(shows[i][i], 3) for i in lit_ok},
        "camera_size": [cam_w, cam_h],
        "network_size": [a.size, a.size],
        "dark_level_8bit": [float(v) for v in dark],
        "references": {
            "img_0001": "uniform dark level (estimated; not captured)",
            "img_0125": "img0 (white)",
            "img_0126": "img0 (white; no gray capture exists)",
        },
    }
    (setup / "import.json").write_text(json.dumps(record, indent=1) + "\n")
    if a.out.exists():
        # The empty folder given stays; what was written moves into it.
        for child in tmp.iterdir():
            child.rename(a.out / child.name)
        tmp.rmdir()
    else:
        tmp.rename(a.out)
    print(json.dumps({k: record[k] for k in ("left_out", "repaired", "dark_level_8bit")}))
    counts = f"{len(split['train'])} training and {len(split['test'])} test pairs"
    print(f"{counts} in {a.out / a.setup}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Trains the CompenNet++ authors' public PyTorch implementation on a compend setup, for the
side-by-side comparison of docs/bench/ladder.md ("Against the authors' implementation").

compend reads and writes the dataset layout of the CompenNet++ benchmark, so the authors' own
data loading, model, training loop and evaluation run unchanged on a `compend sim export` setup.
This script only drives them: it imports the modules of a checkout of their repository (not
shipped with compend), and

- gives their `visdom` import a stand-in (their code asserts a Visdom server at import time) and
  makes their two plotting helpers no-ops;
- runs their 2018 code on today's PyTorch with `grid_sample` and `affine_grid` defaulting to
  `align_corners=True`, the behaviour of the PyTorch 0.4 they wrote it for (the default changed
  in 1.3);
- starts their CompenNet from PyTorch's default initialisation (their pre-trained initial weights
  are not in the repository, and their fallback needs a folder of surface images that compend's
  layout has not; `--photometric-init none` is the matching compend setting), or with
  `--photometric-init FILE` from compend's pre-trained CompenNet (weights/*.safetensors, width
  32), its tensors renamed to theirs, as compend's CompenNet++ variants start by default;
- trains their 'CompenNet++' model (WarpingNet with refinement, affine initialised from the FOV
  mask's corners as their main.py does) with their `trainModel` at the iterations, batch size and
  step-decay schedule given here, and scores it with their `evaluate` on the setup's test pairs
  (paper protocol: projector input predicted from the capture, 256x256, PSNR/RMSE/SSIM);
- compensates the setup's desired test images as their main.py does and writes them to
  SETUP/prj/cmp/test/NAME, where `compend sim score` scores them in closed loop beside compend's.

Recorded data (e.g. `scripts/import_fpc.py`'s) has no desired test images and only the three
reference captures compend needs (black, white, gray, by name), while their loader reads the
references by position in a full listing of 126 and the desired images unconditionally. For
such a setup the script shows their loader the references in a scratch folder, named in order
(positions it does not read point at the black capture), and a missing `cam/desire/test` as the
test captures; it then skips the compensation images and the uncompensated row (`null`).

Usage (PyTorch, OpenCV and scikit-image from PyPI: python3 -m pip install torch
opencv-python-headless scikit-image):

    python3 scripts/authors_compennet.py --repo PATH/CompenNet-plusplus --data ROOT \
        --setup NAME --iters 200 --batch 8 [--name authors-compennet++]

Prints one JSON object on stdout (metrics, seconds per sample, where the images went).
"""

import argparse
import json
import os
import sys
import tempfile
import time
import types


def stub_visdom():
    """A `visdom` module whose Visdom accepts every call and draws nothing."""
    mod = types.ModuleType("visdom")

    class Visdom:
        def __init__(self, *a, **k):
            pass

        def check_connection(self, *a, **k):
            return True

        def __getattr__(self, name):
            return lambda *a, **k: None

    mod.Visdom = Visdom
    sys.modules["visdom"] = mod


def torch04_sampling(F):
    """grid_sample/affine_grid with align_corners=True unless a caller says otherwise."""
    grid_sample, affine_grid = F.grid_sample, F.affine_grid

    def gs(*a, **k):
        k.setdefault("align_corners", True)
        return grid_sample(*a, **k)

    def ag(*a, **k):
        k.setdefault("align_corners", True)
        return affine_grid(*a, **k)

    F.grid_sample, F.affine_grid = gs, ag


def load_compend_weights(compen, path, torch):
    """Loads a compend CompenNet weight file into the authors' CompenNet (same layers and
    tensor layouts, other names)."""
    from safetensors.torch import load_file

    tensors = load_file(path)
    rename = {
        "skip1.0": "skipConv1.0",
        "skip1.1": "skipConv1.2",
        "skip1.2": "skipConv1.4",
        "skip2": "skipConv2",
        "skip3": "skipConv3",
        "tconv1": "transConv1",
        "tconv2": "transConv2",
    }
    state = {}
    for name, t in tensors.items():
        layer, kind = name.rsplit(".", 1)
        layer = layer.removeprefix("compen.backbone.").removeprefix("compen.surface.")
        state[f"{rename.get(layer, layer)}.{kind}"] = t
    missing, unexpected = compen.load_state_dict(state, strict=False)
    if missing or unexpected:
        sys.exit(f"{path}: does not fit their CompenNet (missing {missing}, unexpected {unexpected})")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repo", required=True, help="a checkout of the authors' CompenNet-plusplus")
    p.add_argument("--data", required=True, help="the data root (holding train/, test/)")
    p.add_argument("--setup", required=True, help="the setup folder under the data root")
    p.add_argument("--iters", type=int, default=200)
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--ntrain", type=int, default=None, help="training pairs (default: all)")
    p.add_argument("--name", default="authors-compennet++")
    p.add_argument("--threads", type=int, default=None)
    p.add_argument(
        "--photometric-init",
        default=None,
        help="a compend CompenNet weight file (e.g. weights/compennet-pretrain-w32.safetensors)",
    )
    a = p.parse_args()

    src = os.path.join(os.path.abspath(a.repo), "src", "python")
    if not os.path.isfile(os.path.join(src, "CompenNetPlusplusModel.py")):
        sys.exit(f"--repo {a.repo}: no src/python/CompenNetPlusplusModel.py there")
    data = os.path.abspath(a.data)
    setup = os.path.join(data, a.setup)
    for need in ("train", "test"):
        if not os.path.isdir(os.path.join(data, need)):
            sys.exit(f"--data {a.data}: no {need}/ folder")
    if not os.path.isdir(os.path.join(setup, "cam", "raw", "ref")):
        sys.exit(f"--setup {a.setup}: no cam/raw/ref under {setup}")

    stub_visdom()
    sys.path.insert(0, src)
    import numpy as np
    import torch
    import torch.nn.functional as F

    torch04_sampling(F)
    # Subnormal floats (compend's pre-trained weights hold some) make PyTorch's CPU kernels
    # more than ten times slower; flushing them changes no result that matters.
    torch.set_flush_denormal(True)
    if a.threads:
        torch.set_num_threads(a.threads)
    # Their training loop saves a checkpoint to ../../checkpoint: keep it in a scratch folder.
    scratch = tempfile.mkdtemp(prefix="authors-compennet-")
    os.makedirs(os.path.join(scratch, "a", "b"))
    os.chdir(os.path.join(scratch, "a", "b"))

    import cv2 as cv
    import CompenNetPlusplusModel as models
    import trainNetwork as tn

    # Recorded data: references by name, no desired test images (see the module's doc).
    ref_dir = os.path.join(setup, "cam", "raw", "ref")
    desire_dir = os.path.join(setup, "cam", "desire", "test")
    has_desired = os.path.isdir(desire_dir)
    redirect = {}
    if not os.path.isfile(os.path.join(ref_dir, "img_0002.png")):
        for name, what in (("img_0001.png", "black"), ("img_0125.png", "white"),
                           ("img_0126.png", "gray surface")):
            if not os.path.isfile(os.path.join(ref_dir, name)):
                sys.exit(f"{os.path.join(ref_dir, name)}: missing (the {what} reference capture)")
        refs = os.path.join(scratch, "ref")
        os.makedirs(refs)
        for i in range(1, 127):
            name = f"img_{i:04d}.png"
            own = os.path.join(ref_dir, name)
            target = own if os.path.isfile(own) else os.path.join(ref_dir, "img_0001.png")
            os.symlink(target, os.path.join(refs, name))
        redirect[os.path.normpath(ref_dir)] = refs
    if not has_desired:
        redirect[os.path.normpath(desire_dir)] = os.path.join(setup, "cam", "raw", "test")
    read_imgs = tn.readImgsMT

    def read_redirected(img_dir, *args, **kwargs):
        return read_imgs(redirect.get(os.path.normpath(img_dir), img_dir), *args, **kwargs)

    tn.readImgsMT = read_redirected

    # Plotting is off in effect: their montage uses an scikit-image argument that no longer
    # exists, and the stand-in would draw nothing anyway.
    tn.plotMontage = lambda *a, **k: None
    tn.appendDataPoint = lambda *a, **k: None
    device = torch.device("cpu")
    cam_surf, cam_train, cam_valid, cam_raw_valid, cam_desire_valid, prj_train, prj_valid, corners = (
        tn.loadData(data, a.setup, None)
    )
    ntrain = a.ntrain or cam_train.shape[0]
    train = dict(
        cam_surf=cam_surf.expand_as(cam_train)[:ntrain],
        cam_train=cam_train[:ntrain],
        prj_train=prj_train[:ntrain],
    )
    valid = dict(cam_surf=cam_surf.expand_as(cam_valid), cam_valid=cam_valid, prj_valid=prj_valid)

    tn.resetRNGseed(0)
    compen = models.CompenNet()
    if a.photometric_init:
        load_compend_weights(compen, a.photometric_init, torch)
    warping = models.WarpingNet(with_refine=True)
    src_pts = np.array([[-1, -1], [1, -1], [1, 1]]).astype(np.float32)
    dst_pts = np.array(corners[0][0:3]).astype(np.float32)
    warping.set_affine(cv.getAffineTransform(src_pts, dst_pts).flatten())
    # Their CompenNetPlusplus copies the `.module` of DataParallel-wrapped nets (on the CPU the
    # wrapper only forwards).
    import torch.nn as nn

    model = models.CompenNetPlusplus(nn.DataParallel(warping), nn.DataParallel(compen))
    # Their schedules drop the rate by 0.2 at two thirds (1000 of 1500) or four fifths (400 of
    # 500) of the iterations; two thirds here.
    option = {
        "data_name": a.setup.replace("/", "_"),
        "model_name": "CompenNet++",
        "num_train": ntrain,
        "max_iters": a.iters,
        "batch_size": a.batch,
        "lr": 1e-3,
        "lr_drop_ratio": 0.2,
        "lr_drop_rate": max(1, (2 * a.iters) // 3),
        "loss": "l1+ssim",
        "l2_reg": 1e-4,
        "device": device,
        # Their loop names its checkpoint from the plot title, which exists only with plotting
        # on (plots are no-ops here).
        "plot_on": True,
        "train_plot_rate": 50,
        "valid_rate": a.iters,
    }
    start = time.time()
    model, psnr, rmse, ssim = tn.trainModel(model, train, valid, option)
    seconds = time.time() - start

    # Compensation of the desired test images, as their main.py does.
    out, uncmp = None, None
    if has_desired:
        desire = tn.readImgsMT(desire_dir).to(device)
        surf = cam_surf.expand_as(desire).to(device)
        with torch.no_grad():
            model.simplify(surf[0, ...].unsqueeze(0))
            model.eval()
            cmp = model(desire, surf).detach()
        out = os.path.join(setup, "prj", "cmp", "test", a.name)
        os.makedirs(out, exist_ok=True)
        tn.saveImgs(cmp, out)
        m = tn.computeMetrics(cam_raw_valid, cam_desire_valid)
        uncmp = {"psnr": m[0], "rmse": m[1], "ssim": m[2]}
    print(
        json.dumps(
            {
                "implementation": "authors (PyTorch)",
                "torch": torch.__version__,
                "threads": torch.get_num_threads(),
                "ntrain": ntrain,
                "iters": a.iters,
                "batch": a.batch,
                "train_seconds": seconds,
                "ms_per_sample": 1e3 * seconds / (a.iters * a.batch),
                "paper": {"psnr": psnr, "rmse": rmse, "ssim": ssim},
                "uncompensated_paper": uncmp,
                "compensation_images": out,
            }
        )
    )


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Calibration on the virtual rig, timed and checked against `sim score` (issue 16's targets).

For each SCENE:SEED it runs `compend calibrate --rig virtual:SCENE` with the given
projector-to-camera latency and camera rate, then exports the same scene and seed as that
calibration captured it (`sim export --as-calibrated`: the exposure and display range the model
records), compensates the export's desired images with the installed model and scores them
closed loop with `sim score` on the same test images the verification projected, each capture
the mean of as many frames as the calibration averaged. It prints the
phase times, the verification figures and the `sim score` figures, one row per run.

    python3 scripts/bench_calibrate.py [--bin target/release/compend] [--out DIR]
        [--latency-ms 100,250] [--fps 30] [--method linear] [--verify 5] [--average 3]
        [--loop-images N] [--ntrain N|auto] [--json FILE] SCENE:SEED ...
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import time


# Written into each run's folder: only folders holding it are replaced by a later run.
MARKER = ".bench_calibrate"


def run(cmd, capture=True):
    """Runs `cmd`; its stdout when `capture`. Exits with the command's code on failure."""
    p = subprocess.run(cmd, stdout=subprocess.PIPE if capture else None, stderr=subprocess.PIPE, text=True)
    if p.returncode != 0:
        sys.stderr.write(p.stderr)
        sys.exit(f"bench_calibrate: {' '.join(cmd)} exited {p.returncode}")
    return p.stdout


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", metavar="SCENE:SEED")
    ap.add_argument("--bin", default=os.path.join(os.environ.get("CARGO_TARGET_DIR", "target"), "release", "compend"))
    ap.add_argument("--out", default="bench-calibrate",
                    help="working folder; OUT/SCENE-SEED is replaced per run, if this script made it")
    ap.add_argument("--latency-ms", default="100,250", help="latencies to cycle through, ms")
    ap.add_argument("--fps", default="30", help="virtual camera rate, Hz")
    ap.add_argument("--method", default="linear")
    ap.add_argument("--verify", type=int, default=5, help="verification images (also scored by sim score)")
    ap.add_argument("--average", type=int, default=3, help="frames averaged per capture (calibrate and sim score)")
    ap.add_argument("--loop-images", type=int, default=None,
                    help="closed-loop pairs (calibrate --loop-images; default: calibrate's, as many as sampling pairs)")
    ap.add_argument("--ntrain", default=None,
                    help="sampling images, or auto (calibrate --ntrain; default: calibrate's, 48)")
    ap.add_argument("--json", default=None, metavar="FILE",
                    help="also write the rows to FILE as JSON (a list of objects)")
    a = ap.parse_args()
    if not os.access(a.bin, os.X_OK):
        sys.exit(f"bench_calibrate: {a.bin} is not an executable (cargo build --release first)")
    latencies = [x.strip() for x in a.latency_ms.split(",") if x.strip()]
    rows = []
    for k, spec in enumerate(a.runs):
        scene, _, seed = spec.partition(":")
        if not seed.isdigit():
            sys.exit(f"bench_calibrate: {spec!r}: expected SCENE:SEED, e.g. curved:88")
        latency = latencies[k % len(latencies)]
        work = os.path.join(a.out, f"{scene}-{seed}")
        marker = os.path.join(work, MARKER)
        if os.path.exists(work):
            if not os.path.isfile(marker):
                sys.exit(f"bench_calibrate: {work} exists and was not made by this script; "
                         "choose another --out or move it")
            shutil.rmtree(work)
        os.makedirs(work)
        open(marker, "w").close()
        data, model = os.path.join(work, "calibration"), os.path.join(work, "model")
        t = time.monotonic()
        rec = json.loads(run([a.bin, "calibrate", "--rig", f"virtual:{scene}", "--seed", seed,
                              "--data", data, "--out", model, "--method", a.method,
                              "--verify", str(a.verify), "--rig-latency-ms", latency,
                              "--rig-fps", a.fps, "--average", str(a.average), "--json"]
                             + ([] if a.loop_images is None else ["--loop-images", str(a.loop_images)])
                             + ([] if a.ntrain is None else ["--ntrain", a.ntrain])))
        wall = time.monotonic() - t
        c = rec
        root = os.path.join(work, "score")
        run([a.bin, "sim", "export", "--scene", scene, "--seed", seed, "--out", root,
             "--ntrain", "4", "--ntest", str(a.verify), "--as-calibrated", model])
        setup = os.path.join(root, scene)
        run([a.bin, "compensate", "--model", model, "--input", os.path.join(setup, "cam/desire/test"),
             "--out", os.path.join(setup, "prj/cmp/test/calibrated")])
        score = json.loads(run([a.bin, "sim", "score", "--setup", setup, "--ntest", str(a.verify),
                                "--model", "calibrated", "--average", str(a.average), "--json"]))
        by = {r["name"]: r for r in score["rows"]}
        v = c["verification"]
        rows.append({
            "run": f"{scene}:{seed}", "latency_ms": int(latency), "measured_frames": max(c["latency"]["trials"]),
            "seconds": c["seconds"], "wall": wall, "verification": v["psnr"], "ssim": v["ssim"],
            "uncompensated": v["uncompensated_psnr"], "sim_score": by["calibrated"]["psnr"],
            "oracle": by["oracle"]["psnr"], "installed": v["passed"],
            "floor": c.get("capture_floor") or {},
            "pairs": (c.get("sampling") or {}).get("chosen") or (a.ntrain or 48),
            "loops": c.get("loop_pairs", 0),
        })
        r = rows[-1]
        print(f"{r['run']}: latency {latency} ms, total {r['seconds']['total']:.1f} s, verification "
              f"{r['verification']:.2f} dB, sim score {r['sim_score']:.2f} dB", file=sys.stderr)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)
    print("| run | sampling + closed-loop pairs | latency ms (frames) | latency s | exposure s | patterns s | captures s | training s "
          "| verification s | total s | capture floor s | total / floor | verification dB / SSIM | "
          "uncompensated dB | sim score dB | difference dB | oracle dB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        s = r["seconds"]
        f = r["floor"]
        floor = f["frames"] / f["fps"] if f.get("fps") else float("nan")
        print(f"| {r['run']} | {r['pairs']} + {r['loops']} | {r['latency_ms']} ({r['measured_frames']}) | {s['latency']:.1f} | "
              f"{s.get('exposure', 0):.1f} | {s['patterns']:.1f} | {s['captures']:.1f} | "
              f"{s['training']:.1f} | {s['verification']:.1f} | {s['total']:.1f} | "
              f"{floor:.1f} | {s['total'] / floor:.2f} | "
              f"{r['verification']:.2f} / {r['ssim']:.3f} | {r['uncompensated']:.2f} | "
              f"{r['sim_score']:.2f} | {r['verification'] - r['sim_score']:+.2f} | {r['oracle']:.2f} |")


if __name__ == "__main__":
    main()

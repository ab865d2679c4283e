#!/usr/bin/env python3
"""Time to an installed model against its closed-loop accuracy, over sampling-pair counts and
closed-loop pairs (issue 47, item 5).

For every NTRAIN (sampling pairs, or `auto`) and LOOPS setting (`0`: no closed-loop pairs; `on`:
calibrate's default, as many as sampling pairs) it runs scripts/bench_calibrate.py on every
SCENE:SEED: `compend calibrate --rig virtual:SCENE` on the wall clock, then `sim score` of the
installed model on the verification's test images beside the scene's physical ceiling (the
oracle). The time is the calibration's total (from nothing to an installed, verified model);
the accuracy is the gap to the ceiling, oracle dB − closed-loop dB (lower is better). Writes
OUT/time-accuracy.md (a table, one row per run) and OUT/time-accuracy.svg (the chart), and each
setting's rows as OUT/NTRAIN-LOOPS.json.

    python3 scripts/bench_time_accuracy.py [--bin target/release/compend] [--out DIR]
        [--latency-ms 67] [--ntrain 8,16,24,48,auto] [--loops 0,on] SCENE:SEED ...
"""

import argparse
import json
import math
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))

# Marker per scene (in order of first appearance) and colour per sampling-pair setting.
SHAPES = ["circle", "square", "triangle", "diamond", "cross"]
COLOURS = ["#1b9e77", "#d95f02", "#7570b3", "#e7298a", "#66a61e", "#e6ab02", "#a6761d"]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", metavar="SCENE:SEED")
    ap.add_argument("--bin", default=os.path.join(os.environ.get("CARGO_TARGET_DIR", "target"), "release", "compend"))
    ap.add_argument("--out", default="bench-time-accuracy")
    ap.add_argument("--latency-ms", default="67")
    ap.add_argument("--ntrain", default="8,16,24,48,auto")
    ap.add_argument("--loops", default="0,on", help="closed-loop pair settings: 0 and/or on")
    ap.add_argument("--chart-only", action="store_true",
                    help="draw from the JSON files a previous run left in OUT")
    a = ap.parse_args()
    counts = [x.strip() for x in a.ntrain.split(",") if x.strip()]
    loops = [x.strip() for x in a.loops.split(",") if x.strip()]
    for n in counts:
        if n != "auto" and not n.isdigit():
            refuse(f"--ntrain {n!r}: expected a count or auto")
    for l in loops:
        if l not in ("0", "on"):
            refuse(f"--loops {l!r}: expected 0 or on")
    os.makedirs(a.out, exist_ok=True)
    results = []
    for n in counts:
        for l in loops:
            path = os.path.join(a.out, f"{n}-{l}.json")
            if not a.chart_only:
                cmd = [sys.executable, os.path.join(HERE, "bench_calibrate.py"), "--bin", a.bin,
                       "--out", os.path.join(a.out, f"runs-{n}-{l}"), "--latency-ms", a.latency_ms,
                       "--ntrain", n, "--json", path] + (["--loop-images", "0"] if l == "0" else []) + a.runs
                print(f"bench_time_accuracy: ntrain {n}, closed-loop pairs {l}", file=sys.stderr)
                if subprocess.run(cmd, stdout=subprocess.DEVNULL).returncode != 0:
                    sys.exit(f"bench_time_accuracy: {' '.join(cmd)} failed")
            if not os.path.isfile(path):
                refuse(f"{path} is missing (run without --chart-only first)")
            with open(path) as f:
                for r in json.load(f):
                    results.append({"ntrain": n, "loops": l, "run": r["run"], "time": r["seconds"]["total"],
                                    "gap": r["oracle"] - r["sim_score"], "pairs": r["pairs"],
                                    "loop_pairs": r["loops"], "closed_loop": r["sim_score"],
                                    "oracle": r["oracle"], "installed": r["installed"]})
    write_table(results, os.path.join(a.out, "time-accuracy.md"))
    write_chart(results, counts, os.path.join(a.out, "time-accuracy.svg"))


def refuse(why):
    """Bad input: says why and exits 2."""
    print(f"bench_time_accuracy: {why}", file=sys.stderr)
    sys.exit(2)


def write_table(results, path):
    with open(path, "w") as f:
        f.write("| run | sampling pairs asked (chosen) | closed-loop pairs | time to installed model s "
                "| closed loop dB | ceiling dB | gap dB |\n|---|---|---|---|---|---|---|\n")
        for r in sorted(results, key=lambda r: (r["run"], r["loops"], order(r["ntrain"]))):
            f.write(f"| {r['run']} | {r['ntrain']} ({r['pairs']}) | {r['loop_pairs']} | {r['time']:.1f} | "
                    f"{r['closed_loop']:.2f} | {r['oracle']:.2f} | {r['gap']:.2f} |\n")


def order(n):
    return 10_000 if n == "auto" else int(n)


def write_chart(results, counts, path):
    """A scatter of gap (dB) against time (s): colour = sampling pairs asked, shape = scene,
    filled = with closed-loop pairs, hollow = without; each scene's fixed counts joined in order."""
    W, H, L, R, T, B = 900, 560, 70, 230, 40, 60
    xs = [r["time"] for r in results]
    ys = [r["gap"] for r in results]
    xstep, ystep = nice_step(max(xs) / 8), nice_step((max(ys) - min(0.0, min(ys))) / 8)
    x1 = xstep * math.ceil(max(xs) * 1.02 / xstep)
    y0, y1 = ystep * math.floor(min(0.0, min(ys)) / ystep), ystep * math.ceil(max(ys) * 1.02 / ystep)
    px = lambda x: L + (W - L - R) * x / x1
    py = lambda y: T + (H - T - B) * (1 - (y - y0) / (y1 - y0))
    scenes = []
    for r in results:
        scene = r["run"]
        if scene not in scenes:
            scenes.append(scene)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="12">',
           f'<rect width="{W}" height="{H}" fill="white"/>',
           f'<text x="{L}" y="22" font-size="14">Calibration on the virtual rig: time to an installed model '
           f'against the closed-loop gap to the physical ceiling</text>']
    # Axes and grid.
    for k in range(0, round(x1 / xstep) + 1):
        x = xstep * k
        out.append(f'<line x1="{px(x):.1f}" y1="{T}" x2="{px(x):.1f}" y2="{H - B}" stroke="#eee"/>')
        out.append(f'<text x="{px(x):.1f}" y="{H - B + 16}" text-anchor="middle">{x:g}</text>')
    for k in range(0, round((y1 - y0) / ystep) + 1):
        y = y0 + ystep * k
        out.append(f'<line x1="{L}" y1="{py(y):.1f}" x2="{W - R}" y2="{py(y):.1f}" stroke="#eee"/>')
        out.append(f'<text x="{L - 6}" y="{py(y) + 4:.1f}" text-anchor="end">{y:g}</text>')
    out.append(f'<rect x="{L}" y="{T}" width="{W - L - R}" height="{H - T - B}" fill="none" stroke="#444"/>')
    out.append(f'<text x="{(L + W - R) / 2}" y="{H - 20}" text-anchor="middle">time from nothing to an installed, '
               f'verified model (s, wall clock, 2 cores)</text>')
    out.append(f'<text transform="translate(18,{(T + H - B) / 2}) rotate(-90)" text-anchor="middle">'
               f'gap to the physical ceiling (dB, lower is better)</text>')
    # Each scene's fixed counts joined, per closed-loop setting.
    for scene in scenes:
        for l in ("0", "on"):
            pts = sorted((r for r in results if r["run"] == scene and r["loops"] == l and r["ntrain"] != "auto"),
                         key=lambda r: order(r["ntrain"]))
            if len(pts) > 1:
                d = " ".join(f"{px(r['time']):.1f},{py(r['gap']):.1f}" for r in pts)
                dash = "" if l == "on" else ' stroke-dasharray="4 3"'
                out.append(f'<polyline points="{d}" fill="none" stroke="#999"{dash}/>')
    for r in results:
        colour = COLOURS[counts.index(r["ntrain"]) % len(COLOURS)]
        shape = SHAPES[scenes.index(r["run"]) % len(SHAPES)]
        out.append(marker(shape, px(r["time"]), py(r["gap"]), colour, r["loops"] == "on"))
    # Legend.
    lx, ly = W - R + 20, T + 10
    out.append(f'<text x="{lx}" y="{ly}">sampling pairs asked</text>')
    for k, n in enumerate(counts):
        out.append(marker("circle", lx + 6, ly + 18 + 18 * k, COLOURS[k % len(COLOURS)], True))
        out.append(f'<text x="{lx + 18}" y="{ly + 22 + 18 * k}">{n}</text>')
    ly += 30 + 18 * len(counts)
    out.append(f'<text x="{lx}" y="{ly}">scene:seed</text>')
    for k, s in enumerate(scenes):
        out.append(marker(SHAPES[k % len(SHAPES)], lx + 6, ly + 18 + 18 * k, "#444", True))
        out.append(f'<text x="{lx + 18}" y="{ly + 22 + 18 * k}">{s}</text>')
    ly += 30 + 18 * len(scenes)
    out.append(marker("circle", lx + 6, ly, "#444", True))
    out.append(f'<text x="{lx + 18}" y="{ly + 4}">closed-loop pairs on</text>')
    out.append(marker("circle", lx + 6, ly + 18, "#444", False))
    out.append(f'<text x="{lx + 18}" y="{ly + 22}">closed-loop pairs 0</text>')
    out.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")


def nice_step(raw):
    """The step of 1, 2 or 5 times a power of ten at or above `raw`."""
    power = 10 ** math.floor(math.log10(raw)) if raw > 0 else 1
    return next(m * power for m in (1, 2, 5, 10) if m * power >= raw)


def marker(shape, x, y, colour, filled):
    fill = colour if filled else "white"
    style = f'fill="{fill}" stroke="{colour}" stroke-width="1.6"'
    s = 5
    if shape == "circle":
        return f'<circle cx="{x:.1f}" cy="{y:.1f}" r="{s}" {style}/>'
    if shape == "square":
        return f'<rect x="{x - s:.1f}" y="{y - s:.1f}" width="{2 * s}" height="{2 * s}" {style}/>'
    if shape == "triangle":
        return f'<polygon points="{x:.1f},{y - s - 1:.1f} {x - s - 1:.1f},{y + s:.1f} {x + s + 1:.1f},{y + s:.1f}" {style}/>'
    if shape == "diamond":
        return f'<polygon points="{x:.1f},{y - s - 1:.1f} {x + s + 1:.1f},{y:.1f} {x:.1f},{y + s + 1:.1f} {x - s - 1:.1f},{y:.1f}" {style}/>'
    return (f'<path d="M{x - s:.1f},{y - s:.1f} L{x + s:.1f},{y + s:.1f} M{x - s:.1f},{y + s:.1f} '
            f'L{x + s:.1f},{y - s:.1f}" stroke="{colour}" stroke-width="2"/>')


if __name__ == "__main__":
    main()

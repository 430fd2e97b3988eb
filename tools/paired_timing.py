"""Paired wall times of two or more `alp` binaries on the same scenes, in one sitting.

The shared machines this project runs on change speed by up to a factor of two from one sitting to
the next, and by tens of percent within one: a wall time means something only beside another
measured alongside it. This runs `alp estimate` (default quality unless `--quality`, 2 threads, seed 0) with each
binary on each scene in turn, alternating the order from scene to scene (A B, then B A) so that a
drift of the machine's speed falls on both, and prints per scene each binary's wall time, its final
phase's time and its PSNR; then each binary's median and mean, and each binary's ratio to the first
(median and geometric mean of the per-scene ratios) and per phase of `report.json`. Binaries that
should give the same maps can be checked with `cmp` on the `env.exr` files it leaves in
OUT/BINARY_NAME/SCENE. Python 3 standard library only.

    python3 tools/paired_timing.py --bins /tmp/alp_before /tmp/alp_after --scenes /tmp/alp_eval/scenes \
        --out /tmp/paired [--only s1000,s1511] [--known] [--quality fast]

`--known` gives each run the scene's true pose (`--pose`): the lighting phases alone. Binaries with
the same file name need separate folders (their outputs go to OUT/NAME).
"""

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time


def run(binary, scene_dir, out, known, quality):
    with open(os.path.join(scene_dir, "probe.txt")) as f:
        probe = f.read().strip()
    cmd = [binary, "estimate", "--image", "image.exr", "--mask", "mask.png", "--camera", "camera.json",
           "--probe", probe, "--out", out, "--quality", quality, "--threads", "2", "--seed", "0"]
    if known:
        cmd += ["--pose", "pose.json"]
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=scene_dir, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        sys.exit("%s on %s failed: %s" % (binary, scene_dir, done.stderr.strip()[-400:]))
    with open(os.path.join(out, "report.json")) as f:
        report = json.load(f)
    phases = {}
    for p in report["phases"]:
        phases[p["name"]] = phases.get(p["name"], 0.0) + p["wall_s"]
    return {"wall_s": wall, "phases": phases, "psnr_db": report["psnr_db"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bins", nargs="+", required=True, help="alp binaries; ratios are to the first")
    ap.add_argument("--scenes", required=True, help="folder of scene folders (FORMATS.md)")
    ap.add_argument("--out", required=True, help="where the estimates go, OUT/BINARY_NAME/SCENE")
    ap.add_argument("--only", default="", help="keep only scenes whose name contains one of these (comma-separated)")
    ap.add_argument("--known", action="store_true", help="give each run the scene's true pose")
    ap.add_argument("--quality", default="default", choices=["fast", "default", "best"], help="alp estimate --quality")
    args = ap.parse_args()
    names = [os.path.basename(b) for b in args.bins]
    if len(set(names)) != len(names):
        sys.exit("--bins: binaries need different file names (their outputs go to OUT/NAME)")
    if len(args.bins) < 2:
        sys.exit("--bins: give at least two binaries to compare")
    scenes = sorted(n for n in os.listdir(args.scenes)
                    if not n.startswith(".") and os.path.isfile(os.path.join(args.scenes, n, "probe.txt")))
    if args.only:
        scenes = [n for n in scenes if any(w in n for w in args.only.split(",") if w)]
    if not scenes:
        sys.exit("no scene folders (with probe.txt) in %s" % args.scenes)
    results = {name: {} for name in names}
    for i, scene in enumerate(scenes):
        order = list(zip(args.bins, names))
        if i % 2:
            order.reverse()
        for binary, name in order:
            r = run(os.path.abspath(binary), os.path.join(args.scenes, scene),
                    os.path.join(os.path.abspath(args.out), name, scene), args.known, args.quality)
            results[name][scene] = r
            print("%-42s %-14s %7.2f s  final %6.2f s  psnr %.2f dB" % (
                scene, name, r["wall_s"], r["phases"].get("lighting_final", 0.0), r["psnr_db"]), flush=True)
    for name in names:
        walls = [results[name][s]["wall_s"] for s in scenes]
        print("%-14s wall median %.2f s, mean %.2f s" % (name, statistics.median(walls), statistics.mean(walls)))
    base = names[0]
    for name in names[1:]:
        ratios = [results[name][s]["wall_s"] / results[base][s]["wall_s"] for s in scenes]
        print("%s / %s: wall ratio median %.3f, geometric mean %.3f" % (
            name, base, statistics.median(ratios), statistics.geometric_mean(ratios)))
        for phase in sorted({p for s in scenes for p in results[base][s]["phases"]}):
            a = sum(results[base][s]["phases"].get(phase, 0.0) for s in scenes)
            b = sum(results[name][s]["phases"].get(phase, 0.0) for s in scenes)
            print("  %-20s %8.2f s against %8.2f s summed (%.3f)" % (phase, b, a, b / a if a > 0 else float("nan")))
    with open(os.path.join(args.out, "paired.json"), "w") as f:
        json.dump({"bins": args.bins, "scenes": scenes, "results": results}, f)


if __name__ == "__main__":
    main()

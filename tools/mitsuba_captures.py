"""Mitsuba twin of a capture folder (`alp synth captures`): every view's photo path-traced by
Mitsuba 3 (real self-occlusion and inter-reflections, the BRDF ours as in mitsuba_scenes.py),
its mask the film's coverage (alpha > 0.5), so that a probe's acquisition is judged on images
its own renderer did not make. The scan (`mesh.obj`), `lighting.exr`, `true_pose.json` and
`true_probe/` are kept; each view's `camera.json` too. The probe's textures come from the probe the capture was
made of (`--probe`: a probe folder, or a procedural name made with `--alp`).

    python3 mitsuba_captures.py --capture /work/cap/can --probe can --alp ../target/release/alp \\
        --out /work/cap_mi/can [--spp 256] [--noise 0.01] [--background env]

Not a CI dependency (see README.md for the Mitsuba install).
"""

import argparse
import os
import shutil
import subprocess
import sys
import time

import numpy as np

import alp_mitsuba as am
import mitsuba_scenes as ms

KEPT = ("mesh.obj", "lighting.exr", "true_pose.json")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", required=True, help="a capture folder written by `alp synth captures`")
    ap.add_argument("--probe", required=True, help="the probe it was made of: a folder, or can / cap / sphere")
    ap.add_argument("--alp", default="", help="our `alp` binary (writes a procedural probe)")
    ap.add_argument("--out", required=True, help="the twin capture folder (written whole or not at all)")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--max-depth", type=int, default=4,
                    help="Mitsuba path length: 2 = direct light with shadow rays, 4 = up to three bounces")
    ap.add_argument("--noise", type=float, default=0.0, help="relative sd of multiplicative Gaussian noise")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--variant", default="llvm_ad_rgb", choices=["scalar_rgb", "llvm_ad_rgb"])
    ap.add_argument("--background", default="black", choices=["black", "env"],
                    help="behind the probe: nothing, or the lighting as the camera sees it")
    args = ap.parse_args()
    for f in KEPT:
        if not os.path.isfile(os.path.join(args.capture, f)):
            sys.exit("%s: missing %s (a capture of `alp synth captures`)" % (args.capture, f))
    views_dir = os.path.join(args.capture, "views")
    views = sorted(v for v in os.listdir(views_dir) if os.path.isfile(os.path.join(views_dir, v, "camera.json")))
    if not views:
        sys.exit("%s: no views/<name>/camera.json" % views_dir)
    folder = args.probe
    if not os.path.isfile(os.path.join(folder, "probe.json")):
        if not args.alp:
            sys.exit("%s: no probe.json; a procedural probe needs --alp" % folder)
        folder = os.path.join(args.out + ".probe")
        subprocess.run([args.alp, "probe", "make", args.probe, "--out", folder], check=True)
    mi = am.setup_variant(args.variant)
    probe = am.load_probe(folder)
    probe["mesh"] = os.path.join(args.capture, "mesh.obj")  # the scan: the probe's uvs, another frame
    pose = am.load_pose(os.path.join(args.capture, "true_pose.json"))
    env = am.read_exr(os.path.join(args.capture, "lighting.exr"))
    tmp = args.out + ".tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(os.path.join(tmp, "views"))
    for f in KEPT:
        shutil.copy(os.path.join(args.capture, f), tmp)
    # The truth an acquisition is judged against (`alp acquire` reads it).
    if os.path.isdir(os.path.join(args.capture, "true_probe")):
        shutil.copytree(os.path.join(args.capture, "true_probe"), os.path.join(tmp, "true_probe"))
    for k, name in enumerate(views):
        t0 = time.time()
        src, dst = os.path.join(views_dir, name), os.path.join(tmp, "views", name)
        os.makedirs(dst)
        cam = am.load_camera(os.path.join(src, "camera.json"))
        seed = args.seed * 1000 + k
        image, alpha = ms.render(mi, probe, pose, cam, env, args.spp, args.max_depth, seed)
        if args.background == "env":
            image = image + (1.0 - alpha[..., None]) * ms.env_background(cam, env)
        image = ms.sensor(image, args.noise, None, seed)
        am.write_exr(os.path.join(dst, "image.exr"), image)
        am.write_png(os.path.join(dst, "mask.png"), np.where(alpha > 0.5, 255, 0).astype(np.uint8))
        shutil.copy(os.path.join(src, "camera.json"), dst)
        print("%-12s %6.1f s" % (name, time.time() - t0), flush=True)
    shutil.rmtree(args.out, ignore_errors=True)
    os.rename(tmp, args.out)


if __name__ == "__main__":
    main()

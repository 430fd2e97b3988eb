#!/usr/bin/env python3
"""An outside method for `alp study speed-accuracy`: Mitsuba 3's differentiable path tracer
optimizing the environment map by Adam at the scene's TRUE pose (what differentiable-rendering
inverse lighting does; the paper's own recipe, on another renderer).

    python3 mitsuba_lighting.py --scene DIR --out ENV.exr --alp ALP [--iters 200] [--spp 4]
        [--env-height 32] [--lr 0.02] [--variant llvm_ad_rgb]

The probe is Mitsuba's `principled` metal with our textures (as `mitsuba_scenes.py` renders its
twins), integrator `prb` (max depth 3: one bounce of inter-reflection), the film cropped to the
probe. The map, Mitsuba's own `envmap` bitmap (2 x `--env-height` + 1 rows, 2 x `--env-height`
columns: our rows in its convention), starts at the
photo's mean level and follows Adam on the mean squared error over the mask's pixels, relative
to the photo's mean level; then it is resampled to our convention (FORMATS.md) at 256x128 and
written to ENV.exr. Prints one JSON line: {"wall_s", "iters", "loss"}.

`python3 mitsuba_lighting.py --check` exits 0 when Mitsuba 3 and the variant load (the study
asks this first, and skips the method with a note otherwise). Not a CI dependency.
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import time

import numpy as np

import alp_mitsuba as am
from mitsuba_scenes import principled_dict


def probe_folder(scene, alp, work):
    """The probe folder probe.txt names (a procedural probe is written by `alp probe make`)."""
    kind = open(os.path.join(scene, "probe.txt")).read().strip()
    folder = os.path.normpath(os.path.join(scene, kind))
    if os.path.isfile(os.path.join(folder, "probe.json")):
        return folder
    folder = os.path.join(work, "probe")
    subprocess.run([alp, "probe", "make", kind, "--out", folder], check=True, stdout=subprocess.DEVNULL)
    return folder


def ours_from_mitsuba(data, out_h):
    """Mitsuba's envmap rows sit at v = k / (H' - 1), interpolated linearly; ours at
    v = (i + 0.5) / H (FORMATS.md). Columns agree. Resampled to out_h rows, 2 out_h columns."""
    hm, wm = data.shape[:2]
    v = (np.arange(out_h) + 0.5) / out_h
    c = v * (hm - 1)
    i0 = np.floor(c).astype(int)
    i1 = np.minimum(i0 + 1, hm - 1)
    f = (c - i0)[:, None, None]
    rows = (1 - f) * data[i0] + f * data[i1]
    u = (np.arange(2 * out_h) + 0.5) / (2 * out_h)
    x = u * wm - 0.5
    j0 = np.floor(x).astype(int)
    fx = (x - j0)[None, :, None]
    return (1 - fx) * rows[:, j0 % wm] + fx * rows[:, (j0 + 1) % wm]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene")
    ap.add_argument("--out")
    ap.add_argument("--alp", help="our `alp` binary (writes a procedural probe)")
    ap.add_argument("--iters", type=int, default=200)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--env-height", type=int, default=32)
    ap.add_argument("--lr", type=float, default=0.02, help="Adam's rate over the photo's mean level")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--check", action="store_true")
    args = ap.parse_args()
    mi = am.setup_variant(args.variant)
    if args.check:
        return
    if not (args.scene and args.out and args.alp):
        sys.exit("--scene, --out and --alp are needed")
    import drjit as dr
    started = time.time()
    work = args.out + ".work"
    os.makedirs(work, exist_ok=True)
    probe = am.load_probe(probe_folder(args.scene, args.alp, work))
    cam = am.load_camera(os.path.join(args.scene, "camera.json"))
    pose = am.load_pose(os.path.join(args.scene, "pose.json"))
    photo = am.read_exr(os.path.join(args.scene, "image.exr")).astype(np.float64)
    mask = am.read_mask(os.path.join(args.scene, "mask.png"))
    x0, y0, x1, y1 = am.probe_bbox(cam, probe, pose)
    target, inside = photo[y0:y1, x0:x1], mask[y0:y1, x0:x1]
    level = float(target[inside].mean())
    h = args.env_height
    start = np.full((h, 2 * h, 3), level, dtype=np.float32)
    scene = am.scene_dict(mi, probe, pose, cam, start, args.spp,
                          {"type": "prb", "max_depth": 3, "hide_emitters": True}, (x0, y0, x1, y1))
    scene["probe"]["bsdf"] = principled_dict(mi, probe)
    scene = mi.load_dict(scene)
    params = mi.traverse(scene)
    key = "env.data"
    opt = mi.ad.Adam(lr=args.lr * level)
    opt[key] = params[key]
    params.update(opt)
    weight = mi.TensorXf(np.repeat(inside[:, :, None], 3, axis=2).astype(np.float32) / max(inside.sum(), 1))
    reference = mi.TensorXf(target.astype(np.float32))
    loss_value = float("nan")
    for it in range(args.iters):
        image = mi.render(scene, params, spp=args.spp, seed=it)
        loss = dr.sum(weight * dr.square(image[:, :, :3] - reference)) / (level * level)
        dr.backward(loss)
        opt.step()
        # Non-negative, and the bitmap's wrap columns (Mitsuba pads one on
        # each side, copies of the far ends) kept equal to their twins.
        data = np.maximum(np.array(opt[key]), 0.0)
        data[:, 0], data[:, -1] = data[:, -2], data[:, 1]
        opt[key] = mi.TensorXf(data)
        params.update(opt)
        loss_value = float(loss.array[0]) if hasattr(loss, "array") else float(loss)
    data = np.array(params[key], dtype=np.float64)[:, 1:-1, :3]
    env = ours_from_mitsuba(data, 128)
    tmp = args.out + ".partial.exr"
    am.write_exr(tmp, env)
    os.replace(tmp, args.out)
    shutil.rmtree(work, ignore_errors=True)
    print(json.dumps({"wall_s": round(time.time() - started, 3), "iters": args.iters, "loss": loss_value}))


if __name__ == "__main__":
    main()

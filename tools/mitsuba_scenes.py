"""Mitsuba twins of evaluation scenes: the same probe, pose, camera, lighting, mask, sensor noise
and exposure clip, but the photo rendered by Mitsuba 3's `path` integrator, which traces what
our forward model leaves out: the probe's real self-occlusion (shadow rays, not the visibility
texture) and its inter-reflections (up to `--max-depth` bounces). The BRDF is ours: Mitsuba's
`principled` with metallic = 1 is GGX (alpha = r^2, visible-normal sampling, separable Smith G)
with Schlick's Fresnel on F0 = the albedo texture.

A scene's `probe.txt` may name a procedural probe (made with `alp probe make`) or a probe folder,
relative to the scene folder (FORMATS.md); the twin's `probe.txt` then reaches the same folder.

`tools/eval_suite.py --work DIR` reuses scenes whose `scene.json` matches: put the twins in
`DIR/scenes` and it evaluates `alp estimate` on them unchanged. Usage:

    python3 mitsuba_scenes.py --scenes /work/eval/scenes --out /work/eval_mi/scenes --alp ../target/release/alp

Not a CI dependency (see README.md for the Mitsuba install).
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

FILES_KEPT = ("camera.json", "pose.json", "gt_env.exr", "mask.png", "probe.txt")


def principled_dict(mi, probe):
    """Our metal (GGX, Schlick with F0 = albedo) as Mitsuba's principled BSDF; the visibility
    texture is left out: the path tracer's shadow rays stand in for it."""
    rough = probe["roughness"]
    if isinstance(rough, np.ndarray):
        rough = np.maximum(rough[:, :, :1], 1e-2)
    else:
        rough = max(float(rough), 1e-2)
    return {"type": "principled", "metallic": 1.0, "specular": 0.5, "spec_tint": 0.0,
            "base_color": am._texture(mi, probe["albedo"], 3),
            "roughness": am._texture(mi, rough, 1)}


def render(mi, probe, pose, cam, env, spp, max_depth, seed, pass_samples=1 << 22, rfilter="box"):
    """The photo (H x W x 3, black background) by Mitsuba's path tracer, averaged over passes of
    bounded memory, and the probe's coverage of each pixel (H x W, the film's alpha)."""
    crop = am.probe_bbox(cam, probe, pose)
    x0, y0, x1, y1 = crop
    per_pass = max(1, min(spp, pass_samples // max((x1 - x0) * (y1 - y0), 1)))
    scene = am.scene_dict(mi, probe, pose, cam, env, per_pass,
                          {"type": "path", "max_depth": max_depth, "hide_emitters": True}, crop,
                          rfilter=rfilter)
    scene["probe"]["bsdf"] = principled_dict(mi, probe)
    scene = mi.load_dict(scene)
    total, done, k = 0.0, 0, 0
    while done < spp:
        n = min(per_pass, spp - done)
        img = np.array(mi.render(scene, seed=seed * 7919 + k, spp=n), dtype=np.float64)
        total = total + img[:, :, :4] * n
        done += n
        k += 1
    out = np.zeros((cam["height"], cam["width"], 4))
    out[y0:y1, x0:x1] = total / spp
    return out[:, :, :3], out[:, :, 3]


def env_background(cam, env, per_side=4):
    """The env map as the camera sees it behind the probe: each pixel the mean of per_side^2
    stratified rays (the box filter's pixel mean)."""
    h, w = cam["height"], cam["width"]
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    total = np.zeros((h, w, 3))
    for k in range(per_side * per_side):
        dx, dy = ((k % per_side) + 0.5) / per_side, ((k // per_side) + 0.5) / per_side
        total += am.env_lookup(env, am.camera_rays(cam, cols + dx, rows + dy))
    return total / (per_side * per_side)


def sensor(image, noise, clip, seed):
    """Our synth's sensor: multiplicative Gaussian noise x (1 + noise g) floored at 0, then the
    exposure clip."""
    if noise:
        g = np.random.default_rng(seed).standard_normal(image.shape)
        image = image * np.maximum(1.0 + noise * g, 0.0)
    if clip:
        image = np.minimum(image, clip)
    return image


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", required=True, help="folder of scene folders (alp synth / eval_suite.py)")
    ap.add_argument("--out", required=True, help="where the twins go (one folder per scene)")
    ap.add_argument("--alp", required=True, help="our `alp` binary (writes the procedural probes)")
    ap.add_argument("--spp", type=int, default=512)
    ap.add_argument("--max-depth", type=int, default=4,
                    help="Mitsuba path length: 2 = direct light with shadow rays, 4 = up to three bounces")
    ap.add_argument("--variant", default="llvm_ad_rgb", choices=["scalar_rgb", "llvm_ad_rgb"])
    ap.add_argument("--only", default="", help="comma-separated substrings of scene names")
    ap.add_argument("--rfilter", default="box", choices=["box", "gaussian"],
                    help="the film's reconstruction filter: ours is a box (the pixel's mean); Mitsuba's "
                         "default, a Gaussian (stddev 0.5 px), blurs the photo past the pixel")
    ap.add_argument("--background", default="black", choices=["black", "env"],
                    help="what lies behind the probe: nothing, or the env map as the camera sees it "
                         "(composited by the film's alpha; a photo's edges then have a background "
                         "to stand against)")
    args = ap.parse_args()
    mi = am.setup_variant(args.variant)
    os.makedirs(args.out, exist_ok=True)
    probes = {}
    names = sorted(n for n in os.listdir(args.scenes) if os.path.isfile(os.path.join(args.scenes, n, "scene.json")))
    if args.only:
        names = [n for n in names if any(s in n for s in args.only.split(","))]
    if not names:
        sys.exit("no scene folders (with scene.json) in %s" % args.scenes)
    for name in names:
        src, dst = os.path.join(args.scenes, name), os.path.join(args.out, name)
        meta = am.read_json(os.path.join(src, "scene.json"))
        kind = open(os.path.join(src, "probe.txt")).read().strip()
        # probe.txt names a procedural probe, or a probe folder relative to
        # its scene folder (FORMATS.md): a folder is read where it is, and
        # the twin's probe.txt is rewritten to reach it from the twin's folder.
        given = os.path.normpath(os.path.join(src, kind))
        is_folder = os.path.isfile(os.path.join(given, "probe.json"))
        key = given if is_folder else kind
        if key not in probes:
            folder = given if is_folder else os.path.join(args.out, ".probes", kind)
            if not os.path.isfile(os.path.join(folder, "probe.json")):
                subprocess.run([args.alp, "probe", "make", kind, "--out", folder], check=True)
            probes[key] = am.load_probe(folder)
        t0 = time.time()
        cam = am.load_camera(os.path.join(src, "camera.json"))
        pose = am.load_pose(os.path.join(src, "pose.json"))
        env = am.read_exr(os.path.join(src, "gt_env.exr"))
        image, alpha = render(mi, probes[key], pose, cam, env, args.spp, args.max_depth, meta["seed"],
                              rfilter=args.rfilter)
        if args.background == "env":
            image = image + (1.0 - alpha[..., None]) * env_background(cam, env)
        image = sensor(image, meta.get("noise") or 0.0, meta.get("exposure_clip"), meta["seed"])
        tmp = dst + ".tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        os.makedirs(tmp)
        for f in FILES_KEPT:
            shutil.copy(os.path.join(src, f), tmp)
        if is_folder:
            with open(os.path.join(tmp, "probe.txt"), "w") as f:
                f.write(os.path.relpath(given, dst) + "\n")
        am.write_exr(os.path.join(tmp, "image.exr"), image)
        meta.update({"renderer": "mitsuba path, max_depth %d, %s filter, %s background"
                                 % (args.max_depth, args.rfilter, args.background),
                     "mitsuba_spp": args.spp,
                     "mitsuba_s": round(time.time() - t0, 2)})
        with open(os.path.join(tmp, "scene.json"), "w") as f:
            json.dump(meta, f, indent=1)
        shutil.rmtree(dst, ignore_errors=True)
        os.rename(tmp, dst)
        print("%-45s %6.1f s" % (name, time.time() - t0), flush=True)


if __name__ == "__main__":
    main()

"""Harder variants of evaluation scenes, to find where the estimate fails: the probe cut by a side of
the photo, or far away (a small mask). Each variant keeps its scene's probe, pose, env map and
truth; only the camera changes, and the photo and mask are rendered anew by our renderer
(`alp render`, 256 spp).

    python3 tools/hard_scenes.py --alp target/release/alp --scenes /tmp/alp_eval/scenes --out DIR \
        --cut courtyard_can_upright_s1000:right:0.3 --far studio_cap_tilted_s1031:3

`--cut SCENE:SIDE:FRACTION` turns the camera (about its up, or its right for top and bottom) until
FRACTION of the probe's extent across that side lies beyond it (SIDE: left, right, top, bottom);
`--far SCENE:FACTOR` moves the camera back along its view, FACTOR times as far from the probe
(the mask shrinks by about FACTOR^2). Output folders are named SCENE_SIDE<percent> and
SCENE_far<FACTOR>, in the scene-folder layout of FORMATS.md. With `--estimate`, each variant is
then estimated (`alp estimate`, default quality, 2 threads, into OUT/runs/VARIANT) and evaluated
(`alp eval` with the pose): one JSON line each, then the means.

Needs numpy and Mitsuba 3 (for reading masks only; see README.md).
"""

import argparse
import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np

import alp_mitsuba as am

KEPT = ("pose.json", "gt_env.exr", "probe.txt", "scene.json")
SPP = 256


def turned(v, axis, angle):
    """v turned by angle (radians) about the unit axis (Rodrigues)."""
    axis = axis / np.linalg.norm(axis)
    c, s = math.cos(angle), math.sin(angle)
    return v * c + np.cross(axis, v) * s + axis * axis.dot(v) * (1 - c)


def probe_arg(scene):
    kind = open(os.path.join(scene, "probe.txt")).read().strip()
    folder = os.path.join(scene, kind)
    return folder if os.path.isdir(folder) else kind


def render(alp, scene, camera, spp, out_dir, stem=""):
    """Our render of the scene's probe through `camera` into out_dir: STEMcamera.json,
    STEMimage.exr (and its preview STEMimage.png), STEMmask.png; returns the mask."""
    paths = [os.path.join(out_dir, stem + f) for f in ("camera.json", "image.exr", "mask.png")]
    with open(paths[0], "w") as f:
        json.dump(camera, f, indent=1)
    subprocess.run([alp, "render", "--probe", probe_arg(scene), "--pose", os.path.join(scene, "pose.json"),
                    "--camera", paths[0], "--env", os.path.join(scene, "gt_env.exr"),
                    "--out", paths[1], "--spp", str(spp), "--mask-out", paths[2]], check=True, capture_output=True)
    return am.read_mask(paths[2])


def focal_px(cam):
    return 0.5 * cam["height"] / math.tan(math.radians(cam["fov_y_deg"]) / 2)


def whole_extent(alp, scene, cam, out_dir):
    """The probe's extent in `cam`'s pixels (x0, x1, y0, y1, pixel edges), beyond the frame too:
    rendered on a canvas three times as large with the same focal length."""
    wide = dict(cam, width=3 * cam["width"], height=3 * cam["height"])
    wide["fov_y_deg"] = math.degrees(2 * math.atan(1.5 * cam["height"] / focal_px(cam)))
    m = render(alp, scene, wide, 4, out_dir, "wide_")
    for f in ("camera.json", "image.exr", "image.png", "mask.png"):
        os.remove(os.path.join(out_dir, "wide_" + f))
    ys, xs = np.nonzero(m)
    if len(xs) == 0:
        sys.exit("%s: the probe is not in view" % scene)
    return xs.min() - cam["width"], xs.max() + 1 - cam["width"], ys.min() - cam["height"], ys.max() + 1 - cam["height"]


def cut_camera(alp, scene, side, fraction, out_dir):
    """The scene's camera turned until `fraction` of the probe's extent lies beyond `side`."""
    cam = am.read_json(os.path.join(scene, "camera.json"))
    w, h, f = cam["width"], cam["height"], focal_px(cam)
    origin, up = np.array(cam["origin"], float), np.array(cam["up"], float)
    for _ in range(6):
        x0, x1, y0, y1 = whole_extent(alp, scene, cam, out_dir)
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        tx, ty = {
            "right": (w - (0.5 - fraction) * (x1 - x0), cy),
            "left": ((0.5 - fraction) * (x1 - x0), cy),
            "bottom": (cx, h - (0.5 - fraction) * (y1 - y0)),
            "top": (cx, (0.5 - fraction) * (y1 - y0)),
        }[side]
        if abs(tx - cx) + abs(ty - cy) < 1.0:
            break
        # Perspective moves the extent as the view turns: a few turns settle it.
        pan = math.atan((cx - w / 2) / f) - math.atan((tx - w / 2) / f)
        tilt = math.atan((cy - h / 2) / f) - math.atan((ty - h / 2) / f)
        view = turned(np.array(cam["target"], float) - origin, up, -pan)
        view = turned(view, np.cross(view, up), -tilt)
        cam["target"] = list(origin + view)
    return cam


def far_camera(scene, factor):
    """The scene's camera moved back along its view, `factor` times as far from the probe."""
    cam = am.read_json(os.path.join(scene, "camera.json"))
    centre = np.array(am.read_json(os.path.join(scene, "pose.json"))["to_world"], float)[:3, 3]
    origin, target = np.array(cam["origin"], float), np.array(cam["target"], float)
    moved = centre + (origin - centre) * factor
    cam["origin"], cam["target"] = list(moved), list(target + (moved - origin))
    return cam


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--alp", required=True, help="our `alp` binary")
    ap.add_argument("--scenes", required=True, help="folder of scene folders")
    ap.add_argument("--out", required=True, help="where the variants go")
    ap.add_argument("--cut", action="append", default=[], help="SCENE:SIDE:FRACTION")
    ap.add_argument("--far", action="append", default=[], help="SCENE:FACTOR")
    ap.add_argument("--estimate", action="store_true", help="estimate and evaluate each variant")
    args = ap.parse_args()
    am.setup_variant("scalar_rgb")
    jobs = []
    for spec in args.cut:
        try:
            name, side, fraction = spec.split(":")
            fraction = float(fraction)
        except ValueError:
            sys.exit("--cut %s: expected SCENE:SIDE:FRACTION" % spec)
        if side not in ("left", "right", "top", "bottom") or not 0.0 < fraction < 0.5:
            sys.exit("--cut %s: SIDE is left, right, top or bottom, FRACTION in (0, 0.5)" % spec)
        jobs.append((name, "%s_%s%d" % (name, side, round(100 * fraction)), ("cut", side, fraction)))
    for spec in args.far:
        try:
            name, factor = spec.split(":")
            factor = float(factor)
        except ValueError:
            sys.exit("--far %s: expected SCENE:FACTOR" % spec)
        if factor <= 0.0:
            sys.exit("--far %s: FACTOR must be positive" % spec)
        jobs.append((name, "%s_far%g" % (name, factor), ("far", factor)))
    if not jobs:
        sys.exit("nothing to make: give --cut or --far")
    for name, variant, how in jobs:
        scene = os.path.join(args.scenes, name)
        if not os.path.isfile(os.path.join(scene, "scene.json")):
            sys.exit("%s is not a scene folder (no scene.json)" % scene)
        dst = os.path.join(args.out, variant)
        tmp = dst + ".tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        os.makedirs(tmp)
        cam = cut_camera(args.alp, scene, how[1], how[2], tmp) if how[0] == "cut" else far_camera(scene, how[1])
        mask = render(args.alp, scene, cam, SPP, tmp)
        for f in KEPT:
            shutil.copy(os.path.join(scene, f), tmp)
        kind = open(os.path.join(scene, "probe.txt")).read().strip()
        if os.path.isdir(os.path.join(scene, kind)):
            shutil.copytree(os.path.join(scene, kind), os.path.join(tmp, kind))
        shutil.rmtree(dst, ignore_errors=True)
        os.rename(tmp, dst)
        border = mask[0].sum() + mask[-1].sum() + mask[:, 0].sum() + mask[:, -1].sum()
        print("%-50s mask %6d px, %4d on the border" % (variant, mask.sum(), border), flush=True)
    if args.estimate:
        estimate_all(args.alp, args.out, [variant for _, variant, _ in jobs])


def estimate_all(alp, out, variants):
    """`alp estimate` and `alp eval` on each variant: one JSON line each, then the means."""
    rows = []
    for variant in variants:
        scene, run = os.path.join(out, variant), os.path.join(out, "runs", variant)
        subprocess.run([alp, "estimate", "--image", os.path.join(scene, "image.exr"),
                        "--mask", os.path.join(scene, "mask.png"), "--camera", os.path.join(scene, "camera.json"),
                        "--probe", probe_arg(scene), "--out", run, "--threads", "2"], check=True,
                       capture_output=True)
        line = subprocess.run([alp, "eval", "--scene", scene, "--env", os.path.join(run, "env.exr"),
                               "--pose", os.path.join(run, "pose.json")], check=True, capture_output=True,
                              text=True).stdout.strip()
        print(line, flush=True)
        rows.append(json.loads(line))
    mean = lambda f: sum(f(r) for r in rows) / len(rows)
    print("mean angular error %.2f / %.2f / %.2f deg (mirror / shiny / diffuse); axis error over 5 deg "
          "in %d of %d" % (mean(lambda r: r["mirror"]["angular_deg"]), mean(lambda r: r["shiny"]["angular_deg"]),
                           mean(lambda r: r["diffuse"]["angular_deg"]), sum(r["axis_deg"] > 5 for r in rows),
                           len(rows)))


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Write a UV-sphere probe folder (FORMATS.md: mesh.obj with vt and vn, constant albedo and
roughness in probe.json), a pose and a camera, and an ANALYTIC render of the mirror sphere
computed in numpy from the env map with FORMATS.md's mapping (independent of Mitsuba and of our
renderer): per pixel an n x n grid of sub-pixel rays, exact ray-sphere intersection, mirror
reflection, bilinear env lookup (wrapping in u, clamped in v), black background, average.

    python3 mirror_sphere_reference.py --env ../assets/envmaps/courtyard.exr --out-dir /tmp/ms

writes out-dir/{probe/, pose.json, camera.json, analytic.exr, analytic_mask.png}; then
    python3 mitsuba_compare.py --probe out-dir/probe --pose out-dir/pose.json \
        --camera out-dir/camera.json --env ... --spp 64 --ours out-dir/analytic.exr \
        --mask out-dir/analytic_mask.png
checks Mitsuba against it (and `--alp-bin` checks ours against Mitsuba).
"""

import argparse
import json
import os

import numpy as np

import alp_mitsuba as am


def write_uv_sphere(path, radius, n_phi, n_theta):
    """UV sphere centred at the origin: vt u = phi / 2 pi, v = 1 - theta / pi (theta from +Y),
    vn = the exact sphere normal. A seam column is duplicated (u = 0 and u = 1)."""
    lines = ["# UV sphere r=%g, %d x %d" % (radius, n_phi, n_theta)]
    idx = {}
    k = 0
    for i in range(n_theta + 1):
        th = np.pi * i / n_theta
        for j in range(n_phi + 1):
            ph = 2 * np.pi * j / n_phi
            n = np.array([np.sin(th) * np.sin(ph), np.cos(th), np.sin(th) * np.cos(ph)])
            lines.append("v %.9f %.9f %.9f" % tuple(radius * n))
            lines.append("vt %.9f %.9f" % (j / n_phi, 1 - i / n_theta))
            lines.append("vn %.9f %.9f %.9f" % tuple(n))
            k += 1
            idx[i, j] = k
    for i in range(n_theta):
        for j in range(n_phi):
            a, b, c, d = idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]
            tris = []
            if i > 0:
                tris.append((a, b, d))
            if i < n_theta - 1:
                tris.append((b, c, d))
            for t in tris:
                lines.append("f " + " ".join("%d/%d/%d" % (x, x, x) for x in t))
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def analytic_mirror(cam, env, centre, radius, n):
    w, h = cam["width"], cam["height"]
    o = np.array(cam["origin"], float)
    img = np.zeros((h, w, 3))
    hits = np.zeros((h, w))
    offs = (np.arange(n) + 0.5) / n
    rows = np.arange(h)
    cols = np.arange(w)
    for oy in offs:
        for ox in offs:
            py, px = np.meshgrid(rows + oy, cols + ox, indexing="ij")
            d = am.camera_rays(cam, px, py)
            oc = o - centre
            b = d @ oc
            disc = b * b - (oc @ oc - radius * radius)
            hit = disc > 0
            t = -b - np.sqrt(np.maximum(disc, 0))
            hit &= t > 0
            p = o + t[..., None] * d
            nrm = (p - centre) / radius
            r = d - 2 * np.sum(d * nrm, -1, keepdims=True) * nrm
            r /= np.linalg.norm(r, axis=-1, keepdims=True)
            img += np.where(hit[..., None], am.env_lookup(env, r), 0.0)
            hits += hit
    return (img / (n * n)).astype(np.float32), hits / (n * n)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env", required=True)
    ap.add_argument("--out-dir", required=True)
    ap.add_argument("--radius", type=float, default=0.05)
    ap.add_argument("--centre", type=float, nargs=3, default=[0.0, 0.06, 0.0])
    ap.add_argument("--segments", type=int, nargs=2, default=[256, 128], help="phi theta")
    ap.add_argument("--roughness", type=float, default=0.0,
                    help="written to probe.json (the analytic image is the mirror only)")
    ap.add_argument("--albedo", type=float, nargs=3, default=[1.0, 1.0, 1.0])
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--sub", type=int, default=8, help="n x n sub-pixel rays of the analytic render")
    ap.add_argument("--no-analytic", action="store_true")
    a = ap.parse_args()
    am.setup_variant("scalar_rgb")  # for EXR/PNG I/O only

    os.makedirs(os.path.join(a.out_dir, "probe"), exist_ok=True)
    write_uv_sphere(os.path.join(a.out_dir, "probe", "mesh.obj"), a.radius, *a.segments)
    with open(os.path.join(a.out_dir, "probe", "probe.json"), "w") as f:
        json.dump({"name": "uv_sphere", "mesh": "mesh.obj", "albedo": a.albedo,
                   "roughness": a.roughness}, f)
    pose = np.eye(4)
    pose[:3, 3] = a.centre
    with open(os.path.join(a.out_dir, "pose.json"), "w") as f:
        json.dump({"to_world": pose.tolist()}, f)
    cam = {"width": a.width, "height": a.height, "fov_y_deg": 40.0,
           "origin": [0.0, 0.1, 0.5], "target": a.centre, "up": [0.0, 1.0, 0.0]}
    with open(os.path.join(a.out_dir, "camera.json"), "w") as f:
        json.dump(cam, f)
    if a.no_analytic:
        return
    env = am.read_exr(a.env)
    img, cov = analytic_mirror(cam, env, np.array(a.centre), a.radius, a.sub)
    img *= np.array(a.albedo, np.float32)
    am.write_exr(os.path.join(a.out_dir, "analytic.exr"), img)
    am.write_png(os.path.join(a.out_dir, "analytic_mask.png"), np.where(cov >= 1.0, 255, 0).astype(np.uint8))
    print(json.dumps({"analytic": os.path.join(a.out_dir, "analytic.exr"),
                      "full_coverage_pixels": int((cov >= 1).sum())}))


if __name__ == "__main__":
    main()

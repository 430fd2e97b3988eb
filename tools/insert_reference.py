"""The reference of `alp insert`'s test (alp/tests/insert.rs), path traced by Mitsuba 3: a
diffuse sphere resting on a diffuse ground plane under one of the bundled maps, seen by a small
camera; `photo.exr` is the scene without the sphere (the ground and the map behind it),
`reference.exr` with it. The map's lower half is the ground's radiance (`with_ground`). Full
global illumination (the sphere lights the ground and sees it),
which `alp insert` leaves out: the test's tolerances state what that costs.

Writes into --out: env.exr (the map, downsampled), camera.json, pose.json (the procedural
`sphere` probe, radius 0.03, scaled and placed as the sphere), photo.exr, reference.exr
(half-float EXRs, to keep the fixture small).

Needs `pip install mitsuba==3.9.1 drjit==1.5.0`; not a CI dependency (the fixture is committed).
    python3 tools/insert_reference.py --env assets/envmaps/sunset.exr --out alp/tests/data/insert
"""

import argparse
import json
import os

import numpy as np

import alp_mitsuba as am

RADIUS = 0.05          # the sphere's radius, metres
PROBE_RADIUS = 0.03    # the procedural `sphere` probe's radius
ALBEDO = 0.8           # the sphere's diffuse albedo
GROUND_ALBEDO = 0.5    # the ground's (the ratio `alp insert` applies does not depend on it)


def downsample(env, height):
    """Box-filter our map to `height` rows (its height a multiple of `height`)."""
    h, w = env.shape[:2]
    f = h // height
    return env[:height * f, :2 * height * f].reshape(height, f, 2 * height, f, 3).mean(axis=(1, 3))


def with_ground(env):
    """The map a probe standing on the ground sees: the lower half replaced by the ground's
    radiance under the upper half (albedo / pi x the irradiance on an upward plane), as an
    estimate from a photo would have it."""
    h, w = env.shape[:2]
    theta = (np.arange(h) + 0.5) / h * np.pi
    solid = (2 * np.pi / w) * (np.pi / h) * np.sin(theta)
    cos_up = np.maximum(np.cos(theta), 0.0)
    irradiance = (env * (solid * cos_up)[:, None, None]).sum(axis=(0, 1))
    out = env.copy()
    out[h // 2:] = GROUND_ALBEDO / np.pi * irradiance
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--env-height", type=int, default=32)
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, default=96)
    ap.add_argument("--spp", type=int, default=4096)
    ap.add_argument("--variant", default="llvm_ad_rgb", choices=["scalar_rgb", "llvm_ad_rgb"])
    args = ap.parse_args()
    mi = am.setup_variant(args.variant)
    os.makedirs(args.out, exist_ok=True)

    env = with_ground(downsample(am.read_exr(args.env), args.env_height)).astype(np.float32)
    cam = {"width": args.width, "height": args.height, "fov_y_deg": 40.0,
           "origin": [0.1, 0.16, 0.3], "target": [0.0, 0.035, 0.0], "up": [0.0, 1.0, 0.0]}
    s = RADIUS / PROBE_RADIUS
    pose = [[s, 0, 0, 0], [0, s, 0, RADIUS], [0, 0, s, 0], [0, 0, 0, 1]]

    def scene(with_sphere):
        d = {"type": "scene",
             "integrator": {"type": "path", "max_depth": 6},
             "sensor": am.sensor_dict(mi, cam, args.spp),
             "env": {"type": "envmap",
                     "bitmap": mi.Bitmap(am.env_to_mitsuba(env), mi.Bitmap.PixelFormat.RGB)},
             # The rectangle spans [-1, 1]^2 in xy facing +z: turned to face +y, 40 m wide.
             "ground": {"type": "rectangle",
                        "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(20.0),
                        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [GROUND_ALBEDO] * 3}}}}
        if with_sphere:
            d["sphere"] = {"type": "sphere", "center": [0.0, RADIUS, 0.0], "radius": RADIUS,
                           "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [ALBEDO] * 3}}}
        return mi.load_dict(d)

    def render(with_sphere):
        img = np.array(mi.render(scene(with_sphere), spp=args.spp), dtype=np.float32)[:, :, :3]
        return np.ascontiguousarray(img)

    def write_half(path, rgb):
        b = mi.Bitmap(np.ascontiguousarray(rgb, dtype=np.float32), mi.Bitmap.PixelFormat.RGB)
        b.convert(component_format=mi.Struct.Type.Float16).write(path)

    write_half(os.path.join(args.out, "photo.exr"), render(False))
    write_half(os.path.join(args.out, "reference.exr"), render(True))
    am.write_exr(os.path.join(args.out, "env.exr"), env)
    with open(os.path.join(args.out, "camera.json"), "w") as f:
        json.dump(cam, f, indent=1)
    with open(os.path.join(args.out, "pose.json"), "w") as f:
        json.dump({"to_world": pose}, f)
    print("wrote", args.out)


if __name__ == "__main__":
    main()

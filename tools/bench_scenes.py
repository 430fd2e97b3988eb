"""The development benchmark: a **train** and a **test** split of scene folders (shared/FORMATS.md),
drawn from fixed seeds and path-traced by Mitsuba 3, for `tools/benchmark.py` to run `alp
estimate` on. Constants and choices of the estimate are tuned on train only; test is reported.

    python3 tools/bench_scenes.py --out DIR --alp target/release/alp [--train 48] [--test 48] [--spp 512]

makes DIR/train/NNN_<family>_<pose>_<lighting>/ and DIR/test/..., each holding image.exr,
mask.png, camera.json, pose.json, gt_env.exr, probe.txt ("probe"), the probe folder probe/ and
scene.json (everything drawn, for the reports). Existing scenes whose scene.json matches the
draw version (VERSION) and spp are kept, so an interrupted run resumes. About 4 s per scene
on 2 cores (both splits: 6.6 min).

Each scene draws, from its own seed:
- a probe (tools/bench_probes.py): can 35 %, cap 25 %, bottle 15 %, sphere 10 %, ring 15 %;
  5k to 40k triangles, roughness 0.03 to 0.4 across its regions;
- its pose: upright (axis within 5 deg of vertical), tilted (15 to 65 deg) or lying (80 to 100
  deg) in 2 : 1 : 1, any turn about the axis;
- lighting (tools/bench_lighting.py), by scene index: a real map 60 % (each split has seven,
  `REAL`: the bundled three and eleven Poly Haven maps fetched by tools/real_maps.py, each in
  one split, taking turns), a `sunsky` sky 20 %, a room 20 %;
- a camera: 640 x 480, vertical fov 30 to 55 deg, elevation -5 to 40 deg, the probe 60 to 300
  px tall somewhere in the frame;
- the sensor: no noise (30 %) or multiplicative Gaussian noise of 0.5 to 3 %, and a clip at
  the 98th to 99.5th percentile of the probe's brightest channel in 20 % of the scenes.

Beside the exact photo and mask, each scene holds the inputs people have of it, drawn from the
scene's seed by `alp synth inputs` (alp/src/study/inputs.rs): a mask traced by hand
(mask_traced.png: the outline 2 px out to 2 px in, varying along it), a segmenter's mask
(mask_segmenter.png: a pixel wider, corners rounded), the photo blurred by 0.5 to 2 px
(image_blur.exr), written as an 8-bit sRGB JPEG (image.jpg: quality 80 to 95, exposed so 0.5 to 3 %
of the probe clips), and a box round the probe (box.txt, 2 to 10 px margins); inputs.json says
what was drawn. `tools/benchmark.py --inputs` runs on them.

The photo is Mitsuba's `path` integrator (max depth 4: shadows and inter-reflections) with our
BRDF (tools/mitsuba_scenes.py), the environment behind the probe composited by the coverage of
that render (emitters hidden: the film's alpha is the probe's coverage of each pixel, from all
`--spp` samples); the mask is coverage >= 0.5.

Needs Mitsuba 3 and numpy (tools/README.md).
"""

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time

import numpy as np

import alp_mitsuba as am
import bench_lighting as bl
import bench_probes as bp
import mitsuba_scenes as ms
import real_maps as rm

SEED = 20261203
VERSION = 3  # of the draw: scenes of another version are made anew
SPLITS = {"train": 1, "test": 2}
# The real maps of each split (a map in one split only): the bundled three (assets/envmaps) and
# the eleven of tools/real_maps.py, outdoor and indoor in both.
REAL = {"train": ("courtyard", "studio", "bridge", "esplanade", "hall", "lab", "warehouse"),
        "test": ("sunset", "dawn", "sky", "venice", "apartment", "lobby", "workshop")}
BUNDLED_NAMES = ("courtyard", "studio", "sunset")
# Lighting by scene index, so that each split is 60 % real maps, each map taking its turn.
LIGHT_ROTA = ("real", "sky", "real", "room", "real")
FAMILY_WEIGHTS = {"can": 0.35, "cap": 0.25, "bottle": 0.15, "sphere": 0.10, "ring": 0.15}
POSE_WEIGHTS = {"upright": 0.5, "tilted": 0.25, "lying": 0.25}
WIDTH, HEIGHT = 640, 480
MAX_DEPTH = 4


def _choice(rng, weights):
    keys = list(weights)
    return keys[int(rng.choice(len(keys), p=np.array([weights[k] for k in keys]) / sum(weights.values())))]


def _rotation(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def draw_pose(rng, kind, centre):
    """to_world (4 x 4) putting the probe's centre at the origin, its +Y axis tilted by the
    kind's angle towards a random azimuth, turned at random about its axis; and the tilt."""
    tilt = {"upright": (0.0, 5.0), "tilted": (15.0, 65.0), "lying": (80.0, 100.0)}[kind]
    tilt = rng.uniform(*tilt)
    azimuth = rng.uniform(0, 2 * math.pi)
    turn = _rotation([0, 1, 0], rng.uniform(0, 2 * math.pi))
    lean = _rotation([math.cos(azimuth), 0, math.sin(azimuth)], math.radians(tilt))
    r = lean @ turn
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = -r @ np.asarray(centre)
    return m, tilt


def draw_camera(rng, probe_mesh, pose):
    """A camera that sees the probe 60 to 300 px tall from -5 to 40 deg elevation, placed at a
    random spot of the frame (wholly inside it, 8 px from the edges)."""
    fov = rng.uniform(30.0, 55.0)
    elevation = math.radians(rng.uniform(-5.0, 40.0))
    azimuth = rng.uniform(0, 2 * math.pi)
    target_px = math.exp(rng.uniform(math.log(60.0), math.log(300.0)))
    spot = rng.uniform(-1.0, 1.0, 2)
    forward = -np.array([math.cos(elevation) * math.sin(azimuth), math.sin(elevation),
                         math.cos(elevation) * math.cos(azimuth)])
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    pts = am.read_obj_positions(probe_mesh) @ pose[:3, :3].T + pose[:3, 3]
    radius = float(np.linalg.norm(pts, axis=1).max())

    def placed(distance, shift):
        cam = {"width": WIDTH, "height": HEIGHT, "fov_y_deg": fov, "up": [0.0, 1.0, 0.0],
               "origin": (shift - forward * distance).tolist(), "target": shift.tolist()}
        col, row = am.project(cam, pts)
        return cam, (col.min(), col.max(), row.min(), row.max())

    distance = 10 * radius
    for _ in range(4):  # the distance that gives the drawn height and fits the frame
        _, (x0, x1, y0, y1) = placed(distance, np.zeros(3))
        distance = max(distance * max((y1 - y0) / target_px, (x1 - x0) / (WIDTH - 24),
                                      (y1 - y0) / (HEIGHT - 24)), 2.5 * radius)
    # Slide the camera sideways (the view direction stays) until the probe's box sits at the
    # drawn spot; up close, perspective makes this nonlinear, so iterate and check.
    per_px = 2 * distance * math.tan(math.radians(fov) / 2) / HEIGHT  # metres at the probe
    for reach in (1.0, 0.5, 0.25, 0.0):
        shift = np.zeros(3)
        for _ in range(6):
            cam, (x0, x1, y0, y1) = placed(distance, shift)
            want_x = WIDTH / 2 + spot[0] * reach * max(WIDTH / 2 - 8 - (x1 - x0) / 2, 0)
            want_y = HEIGHT / 2 + spot[1] * reach * max(HEIGHT / 2 - 8 - (y1 - y0) / 2, 0)
            shift = shift - right * (want_x - (x0 + x1) / 2) * per_px + up * (want_y - (y0 + y1) / 2) * per_px
        cam, (x0, x1, y0, y1) = placed(distance, shift)
        if x0 >= 8 and y0 >= 8 and x1 <= WIDTH - 8 and y1 <= HEIGHT - 8:
            break
    return cam, {"fov_y_deg": round(fov, 2), "elevation_deg": round(math.degrees(elevation), 2),
                 "probe_px": round(float(y1 - y0), 1)}


def draw_scene(split, index):
    """The scene's name and what it draws first (family, pose kind, lighting, and for a real
    map which), with its generator to draw the rest from: (name, rng, family, pose_kind, light,
    source)."""
    rng = np.random.default_rng([SEED, SPLITS[split], index])
    family = _choice(rng, FAMILY_WEIGHTS)
    pose_kind = _choice(rng, POSE_WEIGHTS)
    light = LIGHT_ROTA[index % len(LIGHT_ROTA)]
    turn = sum(LIGHT_ROTA[k % len(LIGHT_ROTA)] == "real" for k in range(index))
    source = REAL[split][turn % len(REAL[split])] if light == "real" else None
    name = "%03d_%s_%s_%s" % (index, family, pose_kind, source or light)
    return name, rng, family, pose_kind, light, source


def make_scene(mi, split, index, folder, spp, sources):
    name, rng, family, pose_kind, light, source = draw_scene(split, index)
    return render_scene(mi, rng, folder, spp, sources, split, pose_kind, light,
                        lambda probe_dir: bp.make_probe(family, rng, probe_dir, am.write_exr),
                        {"name": name, "split": split, "index": index, "family": family},
                        lambda _rng: source)


def real_sources(envmaps):
    """Every real map of both splits by name, as arrays: the bundled ones from `envmaps`, the
    others fetched by tools/real_maps.py when missing."""
    fetched = rm.ensure()
    return {n: am.read_exr(os.path.join(envmaps if n in BUNDLED_NAMES else fetched, n + ".exr"))
            for s in REAL.values() for n in s}


def render_scene(mi, rng, folder, spp, sources, split, pose_kind, light, put_probe, head, pick_map):
    """Draws the rest of a scene from `rng` and writes it to `folder` (whole or not at all):
    `put_probe(dir)` writes its probe folder there and returns the probe's description; `head`
    (name, split, index, family) starts scene.json; `pick_map(rng)` names the real map of a
    scene lit by one."""
    t0 = time.time()
    tmp = folder + ".tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    probe_info = put_probe(os.path.join(tmp, "probe"))
    pose, tilt = draw_pose(rng, pose_kind, probe_info["centre_m"])
    if light == "real":
        source = pick_map(rng)
        env, light_info = bl.real(rng, sources[source])
        light_info["source"] = source
    elif light == "sky":
        env, light_info = bl.sky(rng, mi)
    else:
        env, light_info = bl.room(rng)
    cam, cam_info = draw_camera(rng, os.path.join(tmp, "probe", "mesh.obj"), pose)
    noise = 0.0 if rng.random() < 0.3 else float(rng.uniform(0.005, 0.03))
    clip_quantile = float(rng.uniform(98.0, 99.5)) if rng.random() < 0.2 else None
    seed = int(rng.integers(0, 100000))  # mitsuba_scenes.render seeds passes with seed x 7919 + k: 32 bits

    probe = am.load_probe(os.path.join(tmp, "probe"))
    image, alpha = ms.render(mi, probe, pose, cam, env, spp, MAX_DEPTH, seed)
    mask = alpha >= 0.5
    if mask.sum() < 50:
        sys.exit("%s: the probe covers %d pixels (the draw is broken)" % (head["name"], mask.sum()))
    image = image + (1.0 - alpha[..., None]) * ms.env_background(cam, env)
    clip = None
    if clip_quantile is not None:
        clip = float(np.percentile(image[mask].max(axis=1), clip_quantile))
    image = ms.sensor(image, noise, clip, seed)

    am.write_exr(os.path.join(tmp, "image.exr"), image)
    am.write_exr(os.path.join(tmp, "gt_env.exr"), env)
    am.write_png(os.path.join(tmp, "mask.png"), np.where(mask, 255, 0).astype(np.uint8))
    with open(os.path.join(tmp, "camera.json"), "w") as f:
        json.dump(cam, f, indent=1)
    with open(os.path.join(tmp, "pose.json"), "w") as f:
        json.dump({"to_world": pose.tolist()}, f)
    with open(os.path.join(tmp, "probe.txt"), "w") as f:
        f.write("probe\n")
    meta = dict(head, version=VERSION, seed=seed)
    meta.update({"orientation": probe_info["orientation"], "pose_kind": pose_kind, "tilt_deg": round(tilt, 2),
                 "lighting": light, "probe": probe_info, "light": light_info, "camera": cam_info,
                 "mask_pixels": int(mask.sum()), "noise": round(noise, 4), "exposure_clip": clip,
                 "renderer": "mitsuba %s path max_depth %d, box filter, env background" % (mi.variant(), MAX_DEPTH),
                 "mitsuba_spp": spp, "make_s": round(time.time() - t0, 2)})
    with open(os.path.join(tmp, "scene.json"), "w") as f:
        json.dump(meta, f, indent=1)
    shutil.rmtree(folder, ignore_errors=True)
    os.rename(tmp, folder)
    return meta


def people_inputs(alp, folder, seed):
    """The scene's inputs as people have them (`alp synth inputs`), unless they are there."""
    if not os.path.isfile(os.path.join(folder, "inputs.json")):
        subprocess.run([alp, "synth", "inputs", "--scene", folder, "--seed", str(seed)], check=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="benchmark folder: train/ and test/ go here")
    ap.add_argument("--train", type=int, default=48, help="scenes in the train split")
    ap.add_argument("--test", type=int, default=48, help="scenes in the test split")
    ap.add_argument("--spp", type=int, default=512)
    ap.add_argument("--envmaps", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "assets", "envmaps"))
    ap.add_argument("--variant", default="llvm_ad_rgb", choices=["scalar_rgb", "llvm_ad_rgb"])
    ap.add_argument("--preview", action="store_true", help="also write preview.png (tone-mapped photo) per scene")
    ap.add_argument("--alp", required=True, help="the alp binary (draws each scene's inputs as people have them)")
    args = ap.parse_args()
    mi = am.setup_variant(args.variant)
    sources = real_sources(args.envmaps)
    for split, count in (("train", args.train), ("test", args.test)):
        root = os.path.join(args.out, split)
        os.makedirs(root, exist_ok=True)
        for index in range(count):
            name = draw_scene(split, index)[0]
            folder = os.path.join(root, name)
            meta_path = os.path.join(folder, "scene.json")
            made = am.read_json(meta_path) if os.path.isfile(meta_path) else {}
            if made.get("mitsuba_spp") == args.spp and made.get("version") == VERSION:
                people_inputs(args.alp, folder, made["seed"])
                continue
            meta = make_scene(mi, split, index, folder, args.spp, sources)
            people_inputs(args.alp, folder, meta["seed"])
            if args.preview:
                img = am.read_exr(os.path.join(folder, "image.exr"))
                am.write_png(os.path.join(folder, "preview.png"), am.tonemap(img, 0.6 / max(np.median(img), 1e-6)))
            print("%-6s %-36s %5d px %6.1f s" % (split, name, meta["mask_pixels"], meta["make_s"]), flush=True)


if __name__ == "__main__":
    main()

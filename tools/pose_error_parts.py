#!/usr/bin/env python3
"""Which part of a found pose's error carries the map's error.

For every scene that `tools/benchmark.py` ran (its `runs/SPLIT/NAME/pose.json`), the found pose's
error against the truth is split, in the camera's frame and about the probe's centre (the mesh's
bounding-box centre, scene.json's `centre_m`), into six parts:

- `across_x_mm`, `across_y_mm`: the centre moved across the view ray (image right, image up);
- `along_mm`: the centre moved along the view ray (away from the camera positive);
- `in_view_deg`: the axis (mesh +Y) turned about the view ray (within the image plane: the outline
  shows it);
- `lean_deg`: the axis turned towards or away from the camera (the outline hardly shows it);
- `turn_deg`: the probe turned about its own axis (the twist of the rotation error about the true
  axis; the swing is the two tilts).

Then the lighting is estimated at the true pose moved by one part at a time (`alp estimate
--pose`), and at the found pose itself, and each is scored by `alp eval`: the map's error each part
alone brings, against the true pose's. Python 3 with numpy.

    python3 tools/pose_error_parts.py --alp target/release/alp --bench BENCH \
        --runs BENCH/results/default-traced [--splits train] [--only 000_,...] [--eval-spp 64] \
        [--out BENCH/parts/default-traced]

Writes OUT/parts.jsonl (one line per scene: the parts, and per variant its m / s / d errors) and
OUT/summary.md. A rerun keeps the lines it has (same binary). Parts smaller than 0.05 mm or 0.05 deg
are not run (their errors are the true pose's).
"""

import argparse
import json
import math
import os
import shutil
import sys

import numpy as np

import eval_suite as es

PARTS = ("across_x_mm", "across_y_mm", "along_mm", "in_view_deg", "lean_deg", "turn_deg")
SMALLEST = 0.05
SPHERES = ("mirror", "shiny", "diffuse")


def normalize(v):
    return v / np.linalg.norm(v)


def read_pose(path):
    with open(path) as f:
        m = np.array(json.load(f)["to_world"], dtype=float)
    lin = m[:3, :3]
    scale = np.cbrt(np.linalg.det(lin))
    return lin / scale, scale, m[:3, 3]


def write_pose(path, rot, scale, trans):
    m = np.eye(4)
    m[:3, :3] = rot * scale
    m[:3, 3] = trans
    with open(path, "w") as f:
        json.dump({"to_world": m.tolist()}, f)


def rotation(axis, angle_rad):
    """Rodrigues: the rotation by `angle_rad` about the unit `axis`."""
    a = normalize(np.asarray(axis, dtype=float))
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle_rad) * k + (1 - math.cos(angle_rad)) * k @ k


def rotation_vector(r):
    """The axis times the angle (radians) of the rotation matrix `r`."""
    angle = math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2)))
    if angle < 1e-12:
        return np.zeros(3)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if math.pi - angle < 1e-6:
        # Near a half turn: the axis from the symmetric part.
        w, vecs = np.linalg.eigh((r + r.T) / 2)
        return vecs[:, np.argmax(w)] * angle
    return v / (2 * math.sin(angle)) * angle


class Frame:
    """The camera's frame at the true pose: the view ray through the probe's centre, image right
    and up across it, and the plane square to the true axis split into the view's part (about which
    the axis turns within the image) and the lean's."""

    def __init__(self, camera, truth, centre_mesh):
        rot, scale, trans = truth
        self.centre = rot @ (scale * centre_mesh) + trans
        origin = np.array(camera["origin"], dtype=float)
        self.view = normalize(self.centre - origin)
        self.right = normalize(np.cross(self.view, np.array(camera["up"], dtype=float)))
        self.up = np.cross(self.right, self.view)
        self.axis = rot @ np.array([0.0, 1.0, 0.0])
        across = self.view - self.view.dot(self.axis) * self.axis
        if np.linalg.norm(across) < 1e-6:  # end-on: the image's up stands in
            across = self.up - self.up.dot(self.axis) * self.axis
        self.in_view = normalize(across)
        self.lean = np.cross(self.axis, self.in_view)

    def parts(self, truth, found, centre_mesh):
        """The six parts of `found`'s error against `truth` (see the module's description)."""
        (rt, _, _), (rf, sf, tf) = truth, found
        delta = rf @ (sf * centre_mesh) + tf - self.centre
        error = rf @ rt.T
        # Swing-twist about the true axis: the twist's angle is twice the angle whose tangent is
        # the quaternion's part along the axis over its scalar part.
        w = math.sqrt(max(0.0, 1 + np.trace(error))) / 2
        v = np.array([error[2, 1] - error[1, 2], error[0, 2] - error[2, 0], error[1, 0] - error[0, 1]])
        v = v / (4 * w) if w > 1e-9 else rotation_vector(error) / 2
        turn = 2 * math.atan2(v.dot(self.axis), w)
        swing = rotation_vector(error @ rotation(self.axis, turn).T)
        return {"across_x_mm": 1e3 * delta.dot(self.right), "across_y_mm": 1e3 * delta.dot(self.up),
                "along_mm": 1e3 * delta.dot(self.view), "in_view_deg": math.degrees(swing.dot(self.in_view)),
                "lean_deg": math.degrees(swing.dot(self.lean)), "turn_deg": math.degrees(turn)}

    def moved(self, truth, centre_mesh, part, value):
        """The true pose moved by one part alone (rotations about the probe's centre)."""
        rot, scale, _ = truth
        centre = self.centre
        if part.endswith("_mm"):
            direction = {"across_x_mm": self.right, "across_y_mm": self.up, "along_mm": self.view}[part]
            centre = centre + 1e-3 * value * direction
        else:
            about = {"in_view_deg": self.in_view, "lean_deg": self.lean, "turn_deg": self.axis}[part]
            rot = rotation(about, math.radians(value)) @ rot
        return rot, scale, centre - rot @ (scale * centre_mesh)


def estimate_and_eval(args, scene_dir, run_dir, pose_path, out_dir, cache):
    """`alp estimate --pose` with the run's own inputs, then `alp eval`: m / s / d."""
    with open(os.path.join(run_dir + ".estimate.log")) as f:
        cmd = f.readline()[2:].split()
    # The run's command, the pose given, the output elsewhere.
    out_at = cmd.index("--out") + 1
    cmd[out_at] = out_dir
    cmd[0] = args.alp
    cmd += ["--pose", pose_path]
    shutil.rmtree(out_dir, ignore_errors=True)
    os.makedirs(os.path.dirname(out_dir), exist_ok=True)
    es.run(cmd, cwd=args.out, log_path=out_dir + ".log")
    ev = es.evaluate(args.alp, args.out, scene_dir, out_dir, args.eval_spp, cache, args.alp_sha)
    return [round(ev[s]["angular_deg"], 3) for s in SPHERES]


def run_scene(args, split, name, cache):
    scene_dir = os.path.join(args.bench, split, name)
    run_dir = os.path.join(args.runs, "runs", split, name)
    with open(os.path.join(scene_dir, "scene.json")) as f:
        meta = json.load(f)
    with open(os.path.join(scene_dir, "camera.json")) as f:
        camera = json.load(f)
    centre_mesh = np.array(meta["probe"]["centre_m"], dtype=float)
    truth = read_pose(os.path.join(scene_dir, "pose.json"))
    found = read_pose(os.path.join(run_dir, "pose.json"))
    frame = Frame(camera, truth, centre_mesh)
    parts = frame.parts(truth, found, centre_mesh)
    work = os.path.join(args.out, "runs", split, name)
    os.makedirs(work, exist_ok=True)
    rec = {"split": split, "scene": name, "family": meta["family"], "orientation": meta["orientation"],
           "pose_kind": meta["pose_kind"], "alp_sha256": args.alp_sha[:12],
           "parts": {k: round(v, 4) for k, v in parts.items()}, "errors": {}}
    variants = [("truth", truth), ("found", found)]
    variants += [(p, frame.moved(truth, centre_mesh, p, parts[p])) for p in PARTS
                 if abs(parts[p]) >= SMALLEST]
    for label, pose in variants:
        pose_path = os.path.join(work, label + ".pose.json")
        write_pose(pose_path, *pose)
        rec["errors"][label] = estimate_and_eval(args, scene_dir, run_dir, pose_path,
                                                 os.path.join(work, label), cache)
    for p in PARTS:
        rec["errors"].setdefault(p, rec["errors"]["truth"])
    return rec


def summary(records, cmdline):
    lines = ["# The found pose's error, part by part", "", "`%s`" % cmdline, "",
             "Each part of the found pose's error applied alone to the true pose; the map's mirror / "
             "shiny / diffuse error over the true pose's (deg, mean over scenes; in brackets the mean "
             "absolute size of the part).", "",
             "| variant | scenes | mean part | m / s / d (deg) | over the true pose |", "|---|---|---|---|---|"]
    truth = np.array([r["errors"]["truth"] for r in records])
    for label in ("truth", "found") + PARTS:
        e = np.array([r["errors"][label] for r in records])
        size = ("%.2f" % np.mean([abs(r["parts"][label]) for r in records])) if label in PARTS else ""
        d = e - truth
        se = d.std(axis=0, ddof=1) / math.sqrt(len(d)) if len(d) > 1 else np.zeros(3)
        lines.append("| %s | %d | %s | %s | %s |" % (
            label, len(e), size, " / ".join("%.2f" % x for x in e.mean(axis=0)),
            " / ".join("%+.2f +- %.2f" % (a, b) for a, b in zip(d.mean(axis=0), se))))
    lines += ["", "## Per scene (mirror over the true pose, deg)", "",
              "| scene | found | " + " | ".join(PARTS) + " |", "|---|---|" + "---|" * len(PARTS)]
    for r in records:
        t = r["errors"]["truth"][0]
        cell = lambda p: "%+.1f (%.2f)" % (r["errors"][p][0] - t, r["parts"][p])
        lines.append("| %s | %+.1f | %s |" % (r["scene"], r["errors"]["found"][0] - t,
                                             " | ".join(cell(p) for p in PARTS)))
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--alp", required=True)
    ap.add_argument("--bench", required=True, help="the benchmark folder (train/, test/)")
    ap.add_argument("--runs", required=True, help="a tools/benchmark.py results folder (its runs/ hold the poses)")
    ap.add_argument("--splits", default="train")
    ap.add_argument("--only", default="")
    ap.add_argument("--eval-spp", type=int, default=64)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    es.RSS_VIA = "none"
    args.alp = os.path.abspath(args.alp)
    args.alp_sha = es.sha256_files([args.alp], "")
    args.out = os.path.abspath(args.out or os.path.join(args.bench, "parts", os.path.basename(args.runs.rstrip("/"))))
    os.makedirs(args.out, exist_ok=True)
    results = os.path.join(args.out, "parts.jsonl")
    kept = {}
    if os.path.exists(results):
        with open(results) as f:
            kept = {(r["split"], r["scene"]): r for r in map(json.loads, filter(str.strip, f))
                    if r["alp_sha256"] == args.alp_sha[:12]}
    cache_path = os.path.join(args.out, "eval_cache.json")
    cache = json.load(open(cache_path)) if os.path.exists(cache_path) else {}
    records = []
    for split in filter(None, args.splits.split(",")):
        root = os.path.join(args.runs, "runs", split)
        names = sorted(n for n in os.listdir(root) if os.path.isfile(os.path.join(root, n, "pose.json")))
        for name in names:
            if args.only and not any(w in name for w in args.only.split(",") if w):
                continue
            rec = kept.get((split, name))
            if rec is None:
                try:
                    rec = run_scene(args, split, name, cache)
                except (es.AlpError, OSError, ValueError, KeyError) as e:
                    print("%s/%s: %s" % (split, name, e), file=sys.stderr)
                    continue
                with open(results, "a") as f:
                    f.write(json.dumps(rec) + "\n")
                print("%s/%s: found %s, truth %s" % (split, name, rec["errors"]["found"], rec["errors"]["truth"]),
                      file=sys.stderr, flush=True)
            records.append(rec)
    text = summary(records, " ".join(["python3", "tools/pose_error_parts.py"] + sys.argv[1:]))
    with open(os.path.join(args.out, "summary.md"), "w") as f:
        f.write(text)
    print(text)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""`alp estimate` on the development benchmark (tools/bench_scenes.py): every scene of the
train and test splits, scored by `alp eval`, summarized per split, probe family and pose kind,
with the train-test gap. Python 3 standard library only.

    python3 tools/benchmark.py --alp target/release/alp --bench DIR [--splits train | test | train,test]
        [--quality default] [--inputs exact] [--threads 2] [--out DIR/results/default] [--only SUBSTR,...]

Writes OUT/results.jsonl (one line per scene: scene.json's draw, `alp eval`'s fields, success,
wall_s, cpu_s, max_rss_mb) and OUT/summary.md, and prints the summary. A rerun with the same
binary keeps the lines it already has (delete results.jsonl to start over), so an interrupted
run resumes; lines of scenes outside the run (another split) stay, and the summary covers every
scene the same binary has run there. Tune on train (the default split); read test once, at an
issue's end (`--splits test`).

`--inputs` picks the photo and mask each estimate is given (bench_scenes.py draws them): `exact`
(image.exr, mask.png: the renderer's coverage), `traced` (mask_traced.png), `segmenter`
(mask_segmenter.png), `blur` (image_blur.exr), `jpeg` (image.jpg), `box` (box.txt instead of a
mask).

A pose is found when the observable part of it is within 5 degrees: the rotation for a probe
whose label breaks its symmetry ("full"), the axis direction for one symmetric about its axis
("axis"), the axis line for one also symmetric end for end ("line": a ring), and for a sphere
("none") the position within a tenth of its radius.
"""

import argparse
import json
import os
import shutil
import sys
import time

import eval_suite as es

SUCCESS_DEG = 5.0
# Per --inputs: the photo, and the mask (or, for `box`, the box file), of each scene.
INPUTS = {"exact": ("image.exr", "mask.png"), "traced": ("image.exr", "mask_traced.png"),
          "segmenter": ("image.exr", "mask_segmenter.png"), "blur": ("image_blur.exr", "mask.png"),
          "jpeg": ("image.jpg", "mask.png"), "box": ("image.exr", "box.txt")}
POSE_KINDS = ("upright", "tilted", "lying")
# The pose's parts (alp::pose_frame): what alp eval splits the error into and report.json's deviations.
PARTS = ("across_x_mm", "across_y_mm", "along_mm", "in_view_deg", "lean_deg", "turn_deg")


def found(rec):
    if rec.get("error"):
        return False
    o = rec["orientation"]
    if o == "full":
        return rec["rotation_deg"] < SUCCESS_DEG
    if o == "axis":
        return rec["axis_deg"] < SUCCESS_DEG
    if o == "line":
        return min(rec["axis_deg"], 180.0 - rec["axis_deg"]) < SUCCESS_DEG
    return rec["translation_mm"] < rec["diameter_mm"] / 20.0


def observable(rec, part):
    """Whether a photo can tell the pose's part at all, so that its error is one: a sphere's rotation and a
    symmetric probe's turn are not; a probe alike end for end found the other way up has its parts measured
    against the wrong end."""
    o = rec["orientation"]
    if part.endswith("_mm") or o == "full":
        return True
    if o == "none" or part == "turn_deg":
        return False
    return o == "axis" or rec["axis_deg"] <= 90.0


def run_scene(args, split, scene_dir, cache):
    with open(os.path.join(scene_dir, "scene.json")) as f:
        meta = json.load(f)
    name = meta["name"]
    est_dir = os.path.join(args.out, "runs", split, name)
    shutil.rmtree(est_dir, ignore_errors=True)
    os.makedirs(os.path.dirname(est_dir), exist_ok=True)
    rec = {"split": split, "scene": name, "family": meta["family"], "orientation": meta["orientation"],
           "pose_kind": meta["pose_kind"], "tilt_deg": meta["tilt_deg"], "lighting": meta["lighting"],
           "map": meta["light"].get("source") or "procedural " + meta["lighting"],
           "label": meta["probe"].get("label"), "metal": meta["probe"].get("metal"),
           "diameter_mm": meta["probe"]["diameter_mm"], "triangles": meta["probe"]["triangles"],
           "probe_px": meta["camera"]["probe_px"], "elevation_deg": meta["camera"]["elevation_deg"],
           "noise": meta["noise"], "exposure_clip": meta["exposure_clip"], "quality": args.quality,
           "threads": args.threads, "alp_sha256": args.alp_sha[:12], "known_pose": args.known_pose,
           "estimate_args": args.estimate_args,
           "inputs": args.inputs,
           "load_1m": round(os.getloadavg()[0], 2)}
    image, mask = INPUTS[args.inputs]
    if not os.path.isfile(os.path.join(scene_dir, image)) or not os.path.isfile(os.path.join(scene_dir, mask)):
        sys.exit("%s: no %s or %s (make them with tools/bench_scenes.py --alp)" % (scene_dir, image, mask))
    if args.inputs == "box":
        with open(os.path.join(scene_dir, mask)) as f:
            region = ["--box", f.read().strip()]
    else:
        region = ["--mask", os.path.join(scene_dir, mask)]
    cmd = [args.alp, "estimate", "--image", os.path.join(scene_dir, image)] + region + [
           "--camera", os.path.join(scene_dir, "camera.json"),
           "--probe", os.path.join(scene_dir, "probe"), "--out", est_dir, "--quality", args.quality,
           "--threads", str(args.threads), "--seed", "0"]
    if args.known_pose:
        cmd += ["--pose", os.path.join(scene_dir, "pose.json")]
    cmd += args.estimate_args.split()
    try:
        _, wall, rss, cpu = es.run(cmd, cwd=args.out, log_path=est_dir + ".estimate.log")
        rec.update(wall_s=round(wall, 3), cpu_s=round(cpu, 3), max_rss_mb=round(rss, 1))
        ev = es.evaluate(args.alp, args.out, scene_dir, est_dir, args.eval_spp, cache, args.alp_sha)
        rec.update({k: v for k, v in ev.items() if k != "scene"})
        with open(os.path.join(est_dir, "report.json")) as f:
            report = json.load(f)
        uncertainty = report.get("pose_uncertainty")
        rec["pose_sigma"] = uncertainty and uncertainty["sigma"]
        rec["warnings"] = report.get("warnings", [])
        rec["blur_px"] = report.get("blur_px")
    except (es.AlpError, OSError, ValueError, KeyError) as e:
        rec["error"] = str(e)
    rec["success"] = found(rec)
    return rec


def stats(recs):
    ok = [r for r in recs if not r.get("error")]
    vals = lambda k: [r[k] for r in ok if r.get(k) is not None]
    return {"n": len(recs),
            "ang": [es.mean([r[s]["angular_deg"] for r in ok]) for s in ("mirror", "shiny", "diffuse")],
            "found": sum(r["success"] for r in recs), "wall_med": es.median(vals("wall_s")),
            "speckle": es.mean([100.0 * max(r["speckle"]) for r in ok if r.get("speckle")]) if any(
                r.get("speckle") for r in ok) else None,
            "rss_max": max(vals("max_rss_mb"), default=None)}


def row(label, s):
    ang = " / ".join(es.fmt(a) for a in s["ang"])
    pct = 100.0 * s["found"] / s["n"] if s["n"] else 0.0
    return "| %s | %d | %s | %d / %d (%.0f %%) | %s | %s | %s |" % (
        label, s["n"], ang, s["found"], s["n"], pct, es.fmt(s["wall_med"], 1), es.fmt(s["rss_max"], 0),
        es.fmt(s["speckle"], 2))


def summary(records, cmdline):
    head = ("| %s | scenes | mean angular error, mirror / shiny / diffuse (deg) | poses found | "
            "median wall (s) | peak RSS (MB) | speckle (%%) |\n|---|---|---|---|---|---|---|")
    lines = ["# Benchmark: `alp estimate` on the train and test splits", "", "`%s`" % cmdline, ""]
    splits = [s for s in ("train", "test") if any(r["split"] == s for r in records)]
    by = {s: [r for r in records if r["split"] == s] for s in splits}
    lines += [head % "split"] + [row(s, stats(by[s])) for s in splits]
    if len(splits) == 2:
        tr, te = stats(by["train"]), stats(by["test"])
        gap = ["-" if a is None or b is None else "%+.2f" % (b - a) for a, b in zip(tr["ang"], te["ang"])]
        lines.append("| gap (test - train) | | %s | %+.0f points | | | |" % (
            " / ".join(gap), 100.0 * (te["found"] / te["n"] - tr["found"] / tr["n"])))
    lines += ["", "## Where the error is", "",
              "The mirror sphere where the probe saw the map (its confidence above one half) and "
              "where it did not (means over the pixels of all scenes); map artefacts at 128 x 64 (share of texels whose chromaticity is "
              "0.08 off their 5 x 5 median, 10x darker, 10x brighter), the estimates' and the true maps'.", "",
              "| split | mirror seen / unseen (deg) | seen share | artefacts colour / dark / bright (%) | "
              "true maps' (%) | within 1 / 2 sigma (%) |", "|---|---|---|---|---|---|"]
    for s in splits:
        ok = [r for r in by[s] if not r.get("error")]
        # Pixel-weighted: a scene whose mirror the probe saw all of has no unseen error to average.
        part = lambda k, f: (es.mean([r[k][f] for r in ok if r.get(k)]) if f == "share" else
                             sum(r[k][f] * r[k]["share"] for r in ok if r.get(k))
                             / max(sum(r[k]["share"] for r in ok if r.get(k)), 1e-12) if any(r.get(k) for r in ok)
                             else None)
        art = lambda k: " / ".join(es.fmt(es.mean([r[k][f] for r in ok if r.get(k)])) for f in
                                   ("colour_pct", "dark_pct", "bright_pct"))
        cover = " / ".join(es.fmt(es.mean([100.0 * r["uncertainty"][f] for r in ok if r.get("uncertainty")]), 1)
                           for f in ("within_1_sigma", "within_2_sigma"))
        lines.append("| %s | %s / %s | %s | %s | %s | %s |" % (
            s, es.fmt(part("mirror_seen", "angular_deg")), es.fmt(part("mirror_unseen", "angular_deg")),
            es.fmt(part("mirror_seen", "share")), art("artefacts"), art("true_artefacts"), cover))
    for key, title in (("family", "probe family"), ("pose_kind", "pose kind"), ("lighting", "lighting"),
                       ("map", "map (real maps by name)")):
        for s in splits:
            groups = sorted({r[key] for r in by[s]}, key=lambda g: (POSE_KINDS.index(g) if g in POSE_KINDS else 9, g))
            lines += ["", "## %s, by %s" % (s, title), "", head % title]
            lines += [row(g, stats([r for r in by[s] if r[key] == g])) for g in groups]
    covered = [r for r in records if r.get("pose_sigma") and r.get("pose_parts")]
    if covered:
        lines += ["", "## The pose's uncertainty", "",
                  "How often the found pose's error lies within two of its reported deviations (alp eval's "
                  "pose_parts against report.json's pose_uncertainty), per part over the photos that tell it (and "
                  "where the part is observable: no sphere's rotation, no symmetric probe's turn), and "
                  "over every part told at once; the median deviation; photos with a warning.", "",
                  "| split | " + " | ".join(PARTS) + " | all parts | photos warned |",
                  "|---|" + "---|" * (len(PARTS) + 2)]
        for s in splits:
            rs = [r for r in covered if r["split"] == s]
            if not rs:
                continue
            within = lambda r, p: abs(r["pose_parts"][p]) <= 2.0 * r["pose_sigma"][p]
            told_by = lambda r, p: r["pose_sigma"].get(p) is not None and observable(r, p)
            cells = []
            for p in PARTS:
                told = [r for r in rs if told_by(r, p)]
                cells.append("%.0f %% of %d (%s)" % (100.0 * sum(within(r, p) for r in told) / max(len(told), 1),
                                                   len(told), es.fmt(es.median([r["pose_sigma"][p] for r in told]))))
            every = sum(all(within(r, p) for p in PARTS if told_by(r, p)) for r in rs)
            lines.append("| %s | %s | %.0f %% of %d | %d |" % (s, " | ".join(cells), 100.0 * every / len(rs), len(rs),
                                                          sum(bool(r.get("warnings")) for r in by[s])))
    failed = [r for r in records if not r["success"]]
    if failed:
        lines += ["", "## Poses not found", "", "| split | scene | rotation | axis | translation (mm) | error |",
                  "|---|---|---|---|---|---|"]
        for r in failed:
            lines.append("| %s | %s | %s | %s | %s | %s |" % (
                r["split"], r["scene"], es.fmt(r.get("rotation_deg"), 1), es.fmt(r.get("axis_deg"), 1),
                es.fmt(r.get("translation_mm"), 1), "".join((r.get("error") or "").splitlines()[-1:])))
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--alp", required=True, help="the alp binary")
    ap.add_argument("--bench", required=True, help="the benchmark folder (train/, test/) of bench_scenes.py")
    ap.add_argument("--splits", default="train",
                    help="comma-separated splits; train unless told: test is read once, at an issue's end")
    ap.add_argument("--quality", default="default")
    ap.add_argument("--inputs", default="exact", choices=sorted(INPUTS),
                    help="the photo and mask as given: exact, or as people have them")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=None, help="results folder (default BENCH/results/QUALITY)")
    ap.add_argument("--only", default="", help="keep scenes whose name contains one of these (comma-separated)")
    ap.add_argument("--estimate-args", default="",
                    help="more flags for every alp estimate, e.g. \"--rounds 2\" (a settings variant)")
    ap.add_argument("--eval-spp", type=int, default=256, help="alp eval --spp")
    ap.add_argument("--known-pose", action="store_true",
                    help="give the estimate each scene's true pose (pose.json): the lighting alone is measured")
    args = ap.parse_args()
    es.RSS_VIA = "auto"
    args.alp = os.path.abspath(args.alp)
    suffix = "" if args.inputs == "exact" else "-" + args.inputs
    args.out = os.path.abspath(args.out or os.path.join(args.bench, "results", args.quality + suffix))
    args.alp_sha = es.sha256_files([args.alp], "")
    os.makedirs(args.out, exist_ok=True)
    cmdline = " ".join(["python3", "tools/benchmark.py"] + sys.argv[1:])
    results = os.path.join(args.out, "results.jsonl")
    existing, kept = [], {}
    if os.path.exists(results):
        with open(results) as f:
            existing = [json.loads(line) for line in f if line.strip()]
    same_run = lambda r: (r["alp_sha256"], r["quality"], r.get("known_pose", False), r.get("inputs", "exact"),
                          r.get("estimate_args", "")) == (
        args.alp_sha[:12], args.quality, args.known_pose, args.inputs, args.estimate_args)
    kept = {(r["split"], r["scene"]): r for r in existing if same_run(r)}
    cache_path = os.path.join(args.out, "eval_cache.json")
    cache = json.load(open(cache_path)) if os.path.exists(cache_path) else {}
    plan = []
    for split in filter(None, args.splits.split(",")):
        root = os.path.join(args.bench, split)
        if not os.path.isdir(root):
            sys.exit("%s: no such split folder (make it with tools/bench_scenes.py)" % root)
        names = sorted(n for n in os.listdir(root) if os.path.isfile(os.path.join(root, n, "scene.json")))
        plan += [(split, os.path.join(root, n)) for n in names
                 if not args.only or any(w in n for w in args.only.split(",") if w)]
    if not plan:
        sys.exit("no scenes to run in %s" % args.bench)
    records = []
    with open(results, "a") as out:
        for k, (split, scene_dir) in enumerate(plan):
            key = (split, os.path.basename(scene_dir))
            rec = kept.get(key)
            if rec is None:
                t0 = time.perf_counter()
                rec = run_scene(args, split, scene_dir, cache)
                print("[%d/%d] %s/%s: %s (%.0f s)" % (
                    k + 1, len(plan), split, key[1], "ERROR " + rec["error"].splitlines()[-1] if rec.get("error") else
                    "%s, rot %.1f axis %.1f, ang %.1f / %.1f / %.1f" % (
                        "found" if rec["success"] else "NOT FOUND", rec["rotation_deg"], rec["axis_deg"],
                        rec["mirror"]["angular_deg"], rec["shiny"]["angular_deg"], rec["diffuse"]["angular_deg"]),
                    time.perf_counter() - t0), file=sys.stderr, flush=True)
            records.append(rec)
            if key not in kept:
                out.write(json.dumps(rec) + "\n")
                out.flush()
    # Lines of scenes outside the plan (another split, an earlier --only)
    # stay; the plan's scenes have their kept or new lines, in its order.
    planned = {(r["split"], r["scene"]) for r in records}
    others = [r for r in existing if (r["split"], r["scene"]) not in planned]
    with open(results + ".tmp", "w") as f:
        f.writelines(json.dumps(r) + "\n" for r in others + records)
    os.replace(results + ".tmp", results)
    # The summary covers every scene this binary has run here (both splits
    # when they were run one after the other).
    text = summary([r for r in others if same_run(r)] + records, cmdline)
    with open(os.path.join(args.out, "summary.md"), "w") as f:
        f.write(text)
    print(text)


if __name__ == "__main__":
    main()

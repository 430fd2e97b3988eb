"""The capture benchmark: is a probe that `alp acquire` made as good as the true one? A **train**
and a **test** split of probes drawn from fixed seeds by the estimate benchmark's generator
(tools/bench_probes.py), each captured as a user would (views on rings round it, path-traced by
Mitsuba 3 under a real map of its split), acquired, and judged downstream: the same estimate
scenes of that probe (tools/bench_scenes.py's draw of pose, lighting, camera and sensor) run
once with the true asset and once with the acquired one. Tune on train; report test.

    python3 tools/capture_bench.py --out DIR --alp target/release/alp [--label main] [--splits train,test]
        [--probes 12] [--views 32] [--scenes 6] [--acquire-args "--solver adam"]

Layout (every stage is written whole and kept, so an interrupted run resumes):
    DIR/<split>/<NN_family>/probe/          the true probe (bench_probes.py), info.json what was drawn
                            capture_env.exr the capture's lighting (a real map of the split, turned)
                            capture/        the capture folder, Mitsuba's (mitsuba_captures.py)
                            scenes/<k_...>/ the downstream scenes (scene folders, bench_scenes.py)
    DIR/runs/true-<sha>/<split>/...          estimates with the true asset (one per --estimate-alp)
    DIR/runs/<label>/<split>/<NN_family>/acquired/   the acquired probe, and its estimates
    DIR/<label>.jsonl                        one line per probe; DIR/<label>.md the tables

The tables, per split and probe family: the relighting error (mean angular, mirror / shiny /
diffuse) with each asset and their ratio, the worst probe's ratio, the textures' RMSE and the
placement's error (`alp acquire`'s report against the capture's truth), the acquisition's wall
time and CPU use (CPU seconds over wall seconds: 2.0 is both cores busy).

Probe families in turn: can, cap, bottle, ring, can, cap (12 probes: 4 cans, 4 caps, 2 bottles,
2 rings). Needs Mitsuba 3 and numpy (tools/README.md).
"""

import argparse
import json
import os
import shutil
import subprocess
import sys

import numpy as np

import alp_mitsuba as am
import bench_lighting as bl
import bench_probes as bp
import bench_scenes as bs
import eval_suite as es

SEED = 20261205
ROTA = ("can", "cap", "bottle", "ring", "can", "cap")
SPHERES = ("mirror", "shiny", "diffuse")
HERE = os.path.dirname(os.path.abspath(__file__))
# The draw this benchmark was made with (bench_scenes.py's earlier one): a capture under a
# bundled map of its split, downstream scenes lit by one 40 % of the time.
BUNDLED = {"train": ("courtyard", "studio"), "test": ("sunset",)}
LIGHT_WEIGHTS = {"bundled": 0.4, "sky": 0.3, "room": 0.3}


def probe_name(index):
    return "%02d_%s" % (index, ROTA[index % len(ROTA)])


def make_probe(args, mi, sources, split, index, folder):
    """The probe, its capture and its downstream scenes, unless they are there."""
    family = ROTA[index % len(ROTA)]
    rng = np.random.default_rng([SEED, bs.SPLITS[split], index])
    os.makedirs(folder, exist_ok=True)
    info_path = os.path.join(folder, "info.json")
    if not os.path.isfile(info_path):
        shutil.rmtree(os.path.join(folder, "probe"), ignore_errors=True)
        info = bp.make_probe(family, rng, os.path.join(folder, "probe"), am.write_exr)
        source = str(rng.choice(BUNDLED[split]))
        env, light = bl.real(rng, sources[source])
        am.write_exr(os.path.join(folder, "capture_env.exr"), env)
        info.update(capture_source=source, capture_light=light, capture_seed=int(rng.integers(0, 500)))  # x 1000 x 7919 in Mitsuba's seeds: 32 bits
        with open(info_path + ".tmp", "w") as f:
            json.dump(info, f, indent=1)
        os.replace(info_path + ".tmp", info_path)
    info = am.read_json(info_path)
    capture = os.path.join(folder, "capture")
    made = am.read_json(os.path.join(capture, "bench.json")) if os.path.isdir(capture) else {}
    if made.get("views") != args.views or made.get("spp") != args.capture_spp:
        ours = os.path.join(folder, "capture_ours")
        shutil.rmtree(ours, ignore_errors=True)
        seed = str(info["capture_seed"])
        subprocess.run([args.alp, "synth", "captures", "--probe", os.path.join(folder, "probe"),
                        "--env", os.path.join(folder, "capture_env.exr"), "--views", str(args.views),
                        "--seed", seed, "--spp", "4", "--out", ours], check=True, stdout=subprocess.DEVNULL)
        subprocess.run([sys.executable, os.path.join(HERE, "mitsuba_captures.py"), "--capture", ours,
                        "--probe", os.path.join(folder, "probe"), "--out", capture, "--spp", str(args.capture_spp),
                        "--seed", seed], check=True, stdout=subprocess.DEVNULL)
        shutil.rmtree(ours)
        with open(os.path.join(capture, "bench.json"), "w") as f:
            json.dump({"views": args.views, "spp": args.capture_spp}, f)
    scenes = []
    for k in range(args.scenes):
        rng = np.random.default_rng([SEED, bs.SPLITS[split], index, 1 + k])
        pose_kind, light = bs._choice(rng, bs.POSE_WEIGHTS), bs._choice(rng, LIGHT_WEIGHTS)
        name = "%d_%s_%s" % (k, pose_kind, light)
        scene = os.path.join(folder, "scenes", name)
        made = am.read_json(os.path.join(scene, "scene.json")) if os.path.isdir(scene) else {}
        if made.get("mitsuba_spp") != args.scene_spp:

            def put_probe(d):
                shutil.copytree(os.path.join(folder, "probe"), d)
                return info

            bs.render_scene(mi, rng, scene, args.scene_spp, sources, split,
                            pose_kind, "real" if light == "bundled" else light, put_probe,
                            {"name": name, "split": split, "index": k, "family": family},
                            lambda rng: str(rng.choice(BUNDLED[split])))
        scenes.append(scene)
    return info, scenes


def estimate(args, scene, asset, out, cache):
    """`alp estimate` of `scene` with the probe `asset`, then `alp eval`: the record (kept in
    out/record.json, so a second run reads it)."""
    path = os.path.join(out, "record.json")
    if os.path.isfile(path):
        return am.read_json(path)
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    rec = {"scene": os.path.basename(scene)}
    cmd = [args.estimate_alp, "estimate", "--image", os.path.join(scene, "image.exr"), "--mask",
           os.path.join(scene, "mask.png"), "--camera", os.path.join(scene, "camera.json"), "--probe", asset,
           "--out", out, "--threads", str(args.threads), "--seed", "0"]
    try:
        _, wall, _, _ = es.run(cmd, cwd=args.out, log_path=out + ".log")
        ev = es.evaluate(args.estimate_alp, args.out, scene, out, args.eval_spp, cache, args.estimate_sha)
        rec.update(wall_s=round(wall, 2), **{s: ev[s]["angular_deg"] for s in SPHERES})
    except (es.AlpError, OSError, ValueError, KeyError) as e:
        rec["error"] = str(e)
        return rec
    with open(path, "w") as f:
        json.dump(rec, f)
    return rec


def acquire(args, capture, out):
    """`alp acquire` of `capture` into `out` unless it is there: (report.json, wall, CPU seconds)."""
    times = out + ".times.json"
    if not (os.path.isfile(os.path.join(out, "report.json")) and os.path.isfile(times)):
        shutil.rmtree(out, ignore_errors=True)
        os.makedirs(os.path.dirname(out), exist_ok=True)
        cmd = [args.alp, "acquire", "--captures", capture, "--out", out, "--threads", str(args.threads)]
        _, wall, rss, cpu = es.run(cmd + args.acquire_args.split(), cwd=args.out, log_path=out + ".log")
        with open(times, "w") as f:
            json.dump({"wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "max_rss_mb": round(rss, 1)}, f)
    return am.read_json(os.path.join(out, "report.json")), am.read_json(times)


def true_in_acquired_frame(true_map, acquired, coverage):
    """The true texture resampled to the acquired one's size and turned as the acquisition turned
    it: a turn about the axis of revolution, which no silhouette tells, is a shift of the
    texture's columns (u runs round the axis), found as the coverage-weighted least-squares fit."""
    h, w = acquired.shape[:2]
    rows = ((np.arange(h) + 0.5) * true_map.shape[0] / h).astype(int)
    cols = ((np.arange(w) + 0.5) * true_map.shape[1] / w).astype(int)
    resampled = true_map[rows][:, cols]
    cost = [float((coverage[..., :1] * (acquired - np.roll(resampled, k, axis=1)) ** 2).sum()) for k in range(w)]
    return np.roll(resampled, int(np.argmin(cost)), axis=1)


def swapped_asset(acquired, true_probe, which, out):
    """The acquired probe with the true `which` texture (albedo or roughness) in its frame."""
    if not os.path.isfile(os.path.join(out, "probe.json")):
        shutil.rmtree(out, ignore_errors=True)
        shutil.copytree(acquired, out + ".tmp", dirs_exist_ok=True)
        mine = am.read_exr(os.path.join(acquired, which + ".exr"))
        true = am.read_exr(os.path.join(true_probe, which + ".exr"))
        coverage = am.read_exr(os.path.join(acquired, "coverage.exr"))
        am.write_exr(os.path.join(out + ".tmp", which + ".exr"), true_in_acquired_frame(true, mine, coverage))
        os.rename(out + ".tmp", out)
    return out


def mean_of(recs, sphere):
    ok = [r[sphere] for r in recs if not r.get("error")]
    return float(np.mean(ok)) if ok else float("nan")


def run_probe(args, mi, sources, split, index, cache):
    name = probe_name(index)
    folder = os.path.join(args.out, split, name)
    info, scenes = make_probe(args, mi, sources, split, index, folder)
    true_runs = os.path.join(args.out, "runs", "true-" + args.estimate_sha[:12], split, name)
    runs = os.path.join(args.out, "runs", args.label, split, name)
    report, times = acquire(args, os.path.join(folder, "capture"), os.path.join(runs, "acquired"))
    true = [estimate(args, s, os.path.join(folder, "probe"), os.path.join(true_runs, os.path.basename(s)), cache)
            for s in scenes]
    acquired = [estimate(args, s, os.path.join(runs, "acquired"), os.path.join(runs, os.path.basename(s)), cache)
                for s in scenes]
    truth = report.get("truth") or {}
    swaps = {}
    for which in ("albedo", "roughness") if args.swaps else ():
        asset = swapped_asset(os.path.join(runs, "acquired"), os.path.join(folder, "probe"), which,
                              os.path.join(runs, "true_" + which))
        recs = [estimate(args, s, asset, os.path.join(runs, "true_" + which, os.path.basename(s)), cache)
                for s in scenes]
        swaps["true_" + which] = {s: mean_of(recs, s) for s in SPHERES}
    return {"split": split, "probe": name, "family": info["family"], "label": info.get("label"),
            "metal": info.get("metal"), "capture_source": info["capture_source"], "views": args.views,
            "alp_sha256": args.alp_sha[:12], "estimate_sha256": args.estimate_sha[:12], "acquire_args": args.acquire_args,
            "true": {s: mean_of(true, s) for s in SPHERES}, "acquired": {s: mean_of(acquired, s) for s in SPHERES},
            **swaps,
            "scenes": [{"scene": t["scene"], "true": {s: t.get(s) for s in SPHERES},
                        "acquired": {s: a.get(s) for s in SPHERES}, "error": t.get("error") or a.get("error")}
                       for t, a in zip(true, acquired)],
            **{k: truth.get(k) for k in ("axis_deg", "centre_pct", "scale_pct", "albedo_rmse", "roughness_rmse")},
            # A probe alike at both ends (a ring) is as right end for end.
            **({"axis_deg": min(truth["axis_deg"], 180.0 - truth["axis_deg"])}
               if info["orientation"] == "line" and truth.get("axis_deg") is not None else {}),
            "seconds": report["seconds"], **times, "cpu_use": round(times["cpu_s"] / max(times["wall_s"], 1e-9), 2)}


def fmt3(xs, nd=2):
    return " / ".join(es.fmt(x, nd) for x in xs)


def swap_table(records, split):
    """Per family, the acquired asset's error with its own textures and with each true one swapped in."""
    keys = [k for k in ("acquired", "true_albedo", "true_roughness", "true") if all(k in r for r in records)]
    lines = ["| %s | probes | %s |" % (split, " | ".join(k.replace("_", " ") for k in keys)),
             "|---|---|" + "---|" * len(keys)]
    for family in list(dict.fromkeys(ROTA)) + ["all"]:
        recs = [r for r in records if family in ("all", r["family"])]
        if recs:
            lines.append("| %s | %d | %s |" % (family, len(recs), " | ".join(
                fmt3([np.mean([r[k][s] for r in recs]) for s in SPHERES]) for k in keys)))
    return "\n".join(lines)


def table(records, split):
    lines = ["| %s | probes | true asset (mirror / shiny / diffuse) | acquired | ratio | worst probe | albedo RMSE | "
             "roughness RMSE | axis (deg) | centre (%%) | wall (s) | CPU use |" % split,
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    groups = [(f, [r for r in records if r["family"] == f]) for f in dict.fromkeys(ROTA)] + [("all", records)]
    for family, recs in groups:
        if not recs:
            continue
        true = [np.mean([r["true"][s] for r in recs]) for s in SPHERES]
        acq = [np.mean([r["acquired"][s] for r in recs]) for s in SPHERES]
        worst = max(max(r["acquired"][s] / r["true"][s] for s in SPHERES) for r in recs)
        avg = lambda k: float(np.mean([r[k] for r in recs if r.get(k) is not None]))
        lines.append("| %s | %d | %s | %s | %s | %.2f | %.3f | %.3f | %.2f | %.2f | %.0f | %.2f |" % (
            family, len(recs), fmt3(true), fmt3(acq), fmt3([a / t for a, t in zip(acq, true)]), worst,
            avg("albedo_rmse"), avg("roughness_rmse"), avg("axis_deg"), avg("centre_pct"),
            float(np.median([r["wall_s"] for r in recs])), avg("cpu_use")))
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="the benchmark folder")
    ap.add_argument("--alp", required=True, help="the alp binary")
    ap.add_argument("--estimate-alp", default="",
                    help="the alp binary of every estimate and eval (default --alp): held fixed, it pairs "
                         "acquisitions by different binaries on the same true-asset runs")
    ap.add_argument("--label", default="main", help="the acquisition run's name (its folder under runs/)")
    ap.add_argument("--splits", default="train,test")
    ap.add_argument("--probes", type=int, default=12, help="probes per split")
    ap.add_argument("--only", default="", help="probe indices to run, comma-separated (default all)")
    ap.add_argument("--views", type=int, default=32, help="views per capture")
    ap.add_argument("--capture-spp", type=int, default=128)
    ap.add_argument("--scenes", type=int, default=6, help="downstream scenes per probe")
    ap.add_argument("--scene-spp", type=int, default=256)
    ap.add_argument("--eval-spp", type=int, default=256, help="alp eval --spp")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--acquire-args", default="", help="more flags for alp acquire, e.g. \"--quality fast\"")
    ap.add_argument("--swaps", action="store_true",
                    help="also estimate with the acquired probe holding the true albedo, then the true roughness "
                         "(each turned into the acquired frame): which texture costs most downstream")
    ap.add_argument("--envmaps", default=os.path.join(HERE, "..", "assets", "envmaps"))
    ap.add_argument("--variant", default="llvm_ad_rgb", choices=["scalar_rgb", "llvm_ad_rgb"])
    args = ap.parse_args()
    es.RSS_VIA = "auto"
    args.alp, args.out = os.path.abspath(args.alp), os.path.abspath(args.out)
    args.estimate_alp = os.path.abspath(args.estimate_alp or args.alp)
    args.alp_sha = es.sha256_files([args.alp], "")
    args.estimate_sha = es.sha256_files([args.estimate_alp], "")
    os.makedirs(args.out, exist_ok=True)
    mi = am.setup_variant(args.variant)
    sources = {n: am.read_exr(os.path.join(args.envmaps, n + ".exr")) for s in BUNDLED.values() for n in s}
    cache_path = os.path.join(args.out, "eval_cache.json")
    cache = am.read_json(cache_path) if os.path.exists(cache_path) else {}
    only = {int(i) for i in args.only.split(",") if i}
    records = []
    for split in args.splits.split(","):
        for index in range(args.probes):
            if only and index not in only:
                continue
            rec = run_probe(args, mi, sources, split, index, cache)
            records.append(rec)
            print("%-5s %-10s ratio %s  albedo %.3f roughness %.3f  %.0f s" % (
                split, rec["probe"], fmt3([rec["acquired"][s] / rec["true"][s] for s in SPHERES]),
                rec["albedo_rmse"] or float("nan"), rec["roughness_rmse"] or float("nan"), rec["wall_s"]), flush=True)
    with open(os.path.join(args.out, args.label + ".jsonl"), "w") as f:
        f.writelines(json.dumps(r) + "\n" for r in records)
    cmdline = " ".join(["python3", "tools/capture_bench.py"] + sys.argv[1:])
    splits = [s for s in args.splits.split(",") if any(r["split"] == s for r in records)]
    md = "`%s`\n\n" % cmdline + "\n\n".join(table([r for r in records if r["split"] == s], s) for s in splits)
    if args.swaps:
        md += "\n\n" + "\n\n".join(swap_table([r for r in records if r["split"] == s], s) for s in splits)
    with open(os.path.join(args.out, args.label + ".md"), "w") as f:
        f.write(md + "\n")
    print(md)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Evaluation suite: `alp estimate` on a fixed, reproducible set of synthetic scenes.

Python 3 standard library only. Usage (from anywhere):

    python3 tools/eval_suite.py --alp PATH_TO_ALP --work DIR \\
        [--qualities fast,default] [--threads 2] [--scenes N] [--out DIR/results.jsonl] \\
        [--extra-runs default:1:6] [--eval-spp 256] [--sphere] [--only SUBSTR,...] \\
        [--envmaps assets/envmaps] [--rss auto|time|wait4] [--mask-error PX]

e.g. the full suite (18 scenes, fast + default with 2 threads, default with 1 thread on the
first 6 scenes; ~30 min on 2 cores):

    cargo build --release -p alp
    python3 tools/eval_suite.py --alp target/release/alp --work /tmp/alp_eval \\
        --qualities fast,default --threads 2 --extra-runs default:1:6

What it does:

1. Scenes (`alp synth`, 640 x 480, 256 spp) in DIR/scenes/, made once and reused when the folder
   exists (its scene.json must then match the table; delete the folder to remake it). The default
   18 are the 3 env maps (courtyard, studio, sunset) x probes {can, cap} x 3 variants:
     clean   upright (random turn about the axis), no noise;
     tilted  `--tilted` (axis tilted 36-54 degrees from vertical, or lying on its side), no noise;
     noisy   `--noise 0.02`, upright (3) or tilted (3: 17 and 33 degrees, and lying); 3 of the
             6 also get a slight exposure clip: the level is the 98th percentile of the brightest
             channel over the probe's pixels of the same scene made without the clip (so ~2 % of
             the probe's pixels saturate; the level is stored in scene.json).
   9 of the 18 are tilted, 3 of those lying on their side. Seeds are fixed (SCENES). The order
   interleaves variants so that the first 6 scenes cover every env map x probe once and every
   variant twice: `--scenes 6` is a representative subset.
   `--sphere` appends 3 sphere scenes (one per env map; clean, noisy, noisy + clip).
2. For each scene, each quality in --qualities and each thread count in --threads:
   `alp estimate --quality Q --threads T --seed 0` into DIR/runs/SCENE/Q_tT/, timed (wall clock
   of the process, and the estimate's own report.json wall_s) with its peak resident memory
   (`/usr/bin/time -v` "Maximum resident set size" when /usr/bin/time exists; otherwise the
   rusage of that one child from os.wait4). Estimates run one at a time. The 1-minute load
   average before each run is recorded (load_1m) to show whether something else was running.
   `--extra-runs Q:T:N[,...]` adds runs of quality Q with T threads on the first N scenes only.
   `--mask-error PX` gives every estimate its scene's mask grown (PX > 0) or shrunk (PX < 0) by
   |PX| pixels (a disk of that radius; written once to WORK/masks/), as a segmentation errs at the
   probe's edge; those runs go to runs/SCENE/Q_tT_mask+PX/ and their records carry mask_error_px.
3. `alp eval --scene S --env env.exr --pose pose.json --spp EVAL_SPP`. Evaluation is cached by
   the SHA-256 of (env.exr, pose.json, scene, spp) in DIR/eval_cache.json, so a byte-identical
   estimate (e.g. the same run with another thread count) is not relit again.
   The cache key includes the SHA-256 of the alp binary (a rebuilt alp is evaluated afresh).
   --eval-spp (default 256, a square): eval's own default of 1024 takes ~3.5x the time (33 s vs
   9 s per eval on 2 idle cores). Noise floor measured on 3 estimates (studio cap, sunset can
   noisy, courtyard can): 256 vs 1024 spp differ by <= 0.02 degrees of angular error and
   <= 0.007 si-RMSE (the largest: the shiny sphere under sunset, 0.391 vs 0.384; seed 0 vs 1 at
   256 spp: 0.391 vs 0.383), far below the differences between estimates.
4. One JSON line per (scene, quality, threads) in --out (default DIR/results.jsonl): scene
   parameters, every field of `alp eval` (mirror/shiny/diffuse angular_deg and si_rmse,
   rotation_deg, axis_deg, translation_mm, scale_ratio), success, wall_s, cpu_s (user + system
   CPU time of the process: less sensitive than wall time to other jobs), report_wall_s, max_rss_mb, psnr_db, clipped_pixels, load_1m, and `error` (alp's stderr) when a step failed.
   Then a Markdown summary on stdout and in DIR/summary.md.

Success (pose): rotation_deg < 5 for a probe without rotational symmetry (the can: its label
has a logo window, so its turn about the axis is observable); for a probe symmetric about its
axis (the cap: its material does not vary around the axis) only the axis direction is
observable, so axis_deg < 5. A sphere has no observable orientation at all: its success is
translation_mm < --sphere-success-mm (default 3 mm, a tenth of its 30 mm radius). Failed runs
(alp error) count as failures in the success rate and are left out of the error means.
"Rotation" columns of the summary are over the probes whose rotation is observable (the can);
the per-probe table gives the rotation error of every probe.
"""

import argparse
import hashlib
import json
import math
import os
import shutil
import statistics
import struct
import subprocess
import sys
import time
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_ENVMAPS = os.path.join(os.path.dirname(HERE), "assets", "envmaps")

ENVS = ["courtyard", "studio", "sunset"]
PROBES = ["can", "cap"]
# Probes symmetric about their axis (turn about it unobservable) and without any orientation.
AXIS_SYMMETRIC = {"cap"}
NO_ORIENTATION = {"sphere"}
SUCCESS_DEG = 5.0
NOISE = 0.02
CLIP_QUANTILE = 0.98
SYNTH_SPP = 256

# The default scenes: (env, probe, variant, seed, tilted, noise, exposure clip). Every (env, probe)
# has the three variants; the order interleaves them so that the first 6 scenes cover every
# (env, probe) once and every variant twice. A seed names a scene (pose, camera, render, noise).
# Seeds of tilted scenes were picked (pose only, from quick 64 x 48 renders) so that 3 of the 9
# tilted scenes lie on their side (axis horizontal) and the other 6 are tilted 17-55 degrees
# (`--tilted` draws lying with probability 1/4 and tilts uniform in 0-60 degrees otherwise).
SCENES = [
    ("courtyard", "can", "clean", 1000, False, 0.0, False),
    ("courtyard", "cap", "tilted", 1511, True, 0.0, False),        # lying
    ("studio", "can", "noisy", 1222, True, NOISE, True),           # tilted 33 degrees
    ("studio", "cap", "clean", 1030, False, 0.0, False),
    ("sunset", "can", "tilted", 1041, True, 0.0, False),           # tilted 52 degrees
    ("sunset", "cap", "noisy", 1152, True, NOISE, True),           # lying
    ("courtyard", "can", "tilted", 1001, True, 0.0, False),        # tilted 36 degrees
    ("courtyard", "cap", "noisy", 1012, True, NOISE, False),       # tilted 17 degrees
    ("studio", "can", "clean", 1020, False, 0.0, False),
    ("studio", "cap", "tilted", 1031, True, 0.0, False),           # tilted 49 degrees
    ("sunset", "can", "noisy", 1042, False, NOISE, False),
    ("sunset", "cap", "clean", 1050, False, 0.0, False),
    ("courtyard", "can", "noisy", 1002, False, NOISE, True),
    ("courtyard", "cap", "clean", 1010, False, 0.0, False),
    ("studio", "can", "tilted", 1421, True, 0.0, False),           # lying
    ("studio", "cap", "noisy", 1032, False, NOISE, False),
    ("sunset", "can", "clean", 1040, False, 0.0, False),
    ("sunset", "cap", "tilted", 1051, True, 0.0, False),           # tilted 54 degrees
]
# `--sphere`: one per env map (its orientation is unobservable: upright only).
SPHERE_SCENES = [
    ("courtyard", "sphere", "clean", 2000, False, 0.0, False),
    ("studio", "sphere", "noisy", 2001, False, NOISE, False),
    ("sunset", "sphere", "noisy", 2002, False, NOISE, True),
]
VARIANTS = ["clean", "tilted", "noisy"]


def scene_table(with_sphere=False):
    rows = SCENES + (SPHERE_SCENES if with_sphere else [])
    return [make_scene(*row) for row in rows]


def make_scene(env, probe, variant, seed, tilted, noise, clip):
    name = "%s_%s_%s%s%s_s%d" % (env, probe, "tilted" if tilted else "upright",
                                 "_noise" if noise else "", "_clip" if clip else "", seed)
    return {"name": name, "env": env, "probe": probe, "variant": variant, "seed": seed,
            "tilted": tilted, "noise": noise, "clip": clip}


# ---------------------------------------------------------------- EXR (scanline, NONE/ZIPS/ZIP)

def read_exr(path):
    """(width, height, {channel: list of floats row-major}) of a scanline EXR (half/float,
    compression NONE, ZIPS or ZIP): enough for the images `alp synth` writes."""
    with open(path, "rb") as f:
        data = f.read()
    if struct.unpack_from("<I", data, 0)[0] != 20000630:
        raise ValueError("%s: not an OpenEXR file" % path)
    if struct.unpack_from("<I", data, 4)[0] & 0x200:
        raise ValueError("%s: tiled EXR is not supported" % path)
    i, attrs = 8, {}
    while data[i] != 0:
        j = data.index(b"\0", i)
        k = data.index(b"\0", j + 1)
        size = struct.unpack_from("<i", data, k + 1)[0]
        attrs[data[i:j].decode()] = data[k + 5:k + 5 + size]
        i = k + 5 + size
    i += 1
    channels, c = [], attrs["channels"]
    p = 0
    while c[p] != 0:
        q = c.index(b"\0", p)
        ptype = struct.unpack_from("<i", c, q + 1)[0]
        channels.append((c[p:q].decode(), ptype))
        p = q + 17
    compression = attrs["compression"][0]
    xmin, ymin, xmax, ymax = struct.unpack("<4i", attrs["dataWindow"])
    w, h = xmax - xmin + 1, ymax - ymin + 1
    lines = {0: 1, 2: 1, 3: 16}.get(compression)
    if lines is None:
        raise ValueError("%s: EXR compression %d is not supported" % (path, compression))
    nchunks = (h + lines - 1) // lines
    offsets = struct.unpack_from("<%dQ" % nchunks, data, i)
    out = {name: [0.0] * (w * h) for name, _ in channels}
    for off in offsets:
        y, size = struct.unpack_from("<ii", data, off)
        raw = data[off + 8:off + 8 + size]
        n = min(lines, ymax + 1 - y)
        expected = sum(w * n * (2 if t == 1 else 4) for _, t in channels)
        if compression != 0 and size < expected:
            t = bytearray(zlib.decompress(raw))
            for m in range(1, len(t)):
                t[m] = (t[m - 1] + t[m] - 128) & 0xFF
            half = (len(t) + 1) // 2
            raw = bytearray(len(t))
            raw[0::2] = t[:half]
            raw[1::2] = t[half:]
        pos = 0
        for line in range(n):
            row = (y - ymin + line) * w
            for name, ptype in channels:
                fmt, nb = ("<%de" % w, 2) if ptype == 1 else ("<%df" % w, 4)
                if ptype == 0:
                    raise ValueError("%s: uint EXR channels are not supported" % path)
                out[name][row:row + w] = struct.unpack_from(fmt, raw, pos)
                pos += nb * w
    return w, h, out


def clip_level(image_exr):
    """The CLIP_QUANTILE quantile of the brightest channel over the probe's (non-black) pixels."""
    _, _, ch = read_exr(image_exr)
    names = [n for n in ("R", "G", "B") if n in ch]
    peaks = sorted(v for v in (max(px) for px in zip(*(ch[n] for n in names))) if v > 0.0)
    if not peaks:
        raise RuntimeError("%s: the probe is black" % image_exr)
    return peaks[min(len(peaks) - 1, int(CLIP_QUANTILE * len(peaks)))], len(peaks)


# ---------------------------------------------------------------- running alp

class AlpError(RuntimeError):
    pass


RSS_VIA = "auto"  # "auto": /usr/bin/time -v when present, else wait4; or "time" / "wait4"


def run(cmd, cwd, log_path=None):
    """Runs cmd; returns (stdout, wall_s, max_rss_mb, cpu_s). Raises AlpError with stderr on failure."""
    time_file = None
    full = list(cmd)
    if RSS_VIA == "time" or (RSS_VIA == "auto" and os.path.exists("/usr/bin/time")):
        time_file = (log_path or os.path.join(cwd, "last")) + ".time"
        full = ["/usr/bin/time", "-v", "-o", time_file] + full
    out_path = (log_path or os.path.join(cwd, "last")) + ".out"
    err_path = (log_path or os.path.join(cwd, "last")) + ".err"
    # Output to files (no pipe can fill up and block the child); wait4 reaps this very child and
    # returns its own rusage (not that of every child so far, as RUSAGE_CHILDREN would).
    with open(out_path, "w") as fo, open(err_path, "w") as fe:
        t0 = time.perf_counter()
        proc = subprocess.Popen(full, cwd=cwd, stdout=fo, stderr=fe)
        _, status, rusage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    with open(out_path) as f:
        out = f.read()
    with open(err_path) as f:
        err = f.read()
    os.remove(out_path)
    os.remove(err_path)
    rss_kb = rusage.ru_maxrss  # KiB on Linux; of `time` itself + its waited-for child when wrapped
    if time_file and os.path.exists(time_file):
        with open(time_file) as f:
            for line in f:
                if "Maximum resident set size" in line:
                    rss_kb = int(line.rsplit(":", 1)[1])
    if log_path:
        with open(log_path, "w") as f:
            f.write("$ %s\n%s" % (" ".join(cmd), err))
    if proc.returncode != 0:
        raise AlpError("`%s` exited with %d:\n%s" % (" ".join(cmd), proc.returncode, err.strip()))
    # User + system CPU time of the child and its waited-for descendants (alp under `time`).
    cpu = rusage.ru_utime + rusage.ru_stime
    return out, wall, rss_kb / 1024.0, cpu


def scene_files_present(d):
    return all(os.path.isfile(os.path.join(d, f)) for f in
               ("image.exr", "mask.png", "camera.json", "probe.txt", "gt_env.exr", "pose.json"))


def axis_tilt_deg(pose_json):
    with open(pose_json) as f:
        m = json.load(f)["to_world"]
    # The mesh +Y axis in world: the second column of the linear part (scale divided out).
    col = [m[0][1], m[1][1], m[2][1]]
    n = math.sqrt(sum(x * x for x in col))
    return math.degrees(math.acos(max(-1.0, min(1.0, col[1] / n))))


def ensure_scene(alp, work, envmaps, sc):
    """Makes the scene folder unless it exists; returns its scene.json dict."""
    d = os.path.join(work, "scenes", sc["name"])
    meta_path = os.path.join(d, "scene.json")
    want = {k: sc[k] for k in ("env", "probe", "variant", "seed", "tilted", "noise", "clip")}
    want["synth_spp"] = SYNTH_SPP
    if os.path.isdir(d):
        if not (scene_files_present(d) and os.path.isfile(meta_path)):
            raise RuntimeError("%s exists but is incomplete: delete it to remake it" % d)
        with open(meta_path) as f:
            meta = json.load(f)
        if {k: meta.get(k) for k in want} != want:
            raise RuntimeError("%s was made with other parameters (%s): delete it to remake it" % (d, meta))
        return meta
    env = os.path.join(envmaps, sc["env"] + ".exr")
    base = [alp, "synth", "--probe", sc["probe"], "--env", env, "--seed", str(sc["seed"]),
            "--spp", str(SYNTH_SPP)]
    if sc["tilted"]:
        base.append("--tilted")
    if sc["noise"]:
        base += ["--noise", repr(sc["noise"])]
    os.makedirs(os.path.join(work, "scenes"), exist_ok=True)
    meta = dict(want)
    t0 = time.perf_counter()
    if sc["clip"]:
        tmp = d + ".noclip.tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        run(base + ["--out", tmp], cwd=work)
        level, probe_px = clip_level(os.path.join(tmp, "image.exr"))
        shutil.rmtree(tmp)
        meta["exposure_clip"] = level
        meta["probe_pixels"] = probe_px
        run(base + ["--exposure-clip", repr(level), "--out", d], cwd=work)
    else:
        run(base + ["--out", d], cwd=work)
    meta["synth_s"] = round(time.perf_counter() - t0, 2)
    meta["axis_tilt_deg"] = axis_tilt_deg(os.path.join(d, "pose.json"))
    with open(meta_path, "w") as f:
        json.dump(meta, f, indent=1)
    return meta


def sha256_files(paths, extra):
    h = hashlib.sha256(extra.encode())
    for p in paths:
        with open(p, "rb") as f:
            h.update(f.read())
    return h.hexdigest()


def evaluate(alp, work, scene_dir, est_dir, spp, cache, alp_sha):
    env, pose = os.path.join(est_dir, "env.exr"), os.path.join(est_dir, "pose.json")
    extra = []
    for flag, name in (("--confidence", "confidence.exr"), ("--uncertainty", "uncertainty.exr")):
        if os.path.isfile(os.path.join(est_dir, name)):
            extra += [flag, os.path.join(est_dir, name)]
    key = sha256_files([env, pose] + extra[1::2], "%s|%d|%s" % (os.path.abspath(scene_dir), spp, alp_sha))
    if key in cache:
        return dict(cache[key], eval_cached=True)
    out, wall, _, _ = run([alp, "eval", "--scene", scene_dir, "--env", env, "--pose", pose, "--spp", str(spp)] + extra,
                       cwd=work, log_path=os.path.join(est_dir, "eval.log"))
    res = json.loads(out.strip().splitlines()[-1])
    res["eval_s"] = round(wall, 2)
    cache[key] = res
    with open(os.path.join(work, "eval_cache.json.tmp"), "w") as f:
        json.dump(cache, f)
    os.replace(os.path.join(work, "eval_cache.json.tmp"), os.path.join(work, "eval_cache.json"))
    return dict(res, eval_cached=False)


def success(rec, sphere_mm):
    if rec.get("error"):
        return False
    if rec["probe"] in NO_ORIENTATION:
        return rec["translation_mm"] < sphere_mm
    if rec["probe"] in AXIS_SYMMETRIC:
        return rec["axis_deg"] < SUCCESS_DEG
    return rec["rotation_deg"] < SUCCESS_DEG


def read_png_gray(path):
    """(width, height, first-channel bytes row-major) of an 8-bit non-interlaced PNG (grey, grey +
    alpha, RGB or RGBA): enough for the masks `alp synth` and the Mitsuba twins write."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError("%s: not a PNG file" % path)
    i, idat, head = 8, b"", None
    while i < len(data):
        size, kind = struct.unpack_from(">I4s", data, i)
        body = data[i + 8:i + 8 + size]
        if kind == b"IHDR":
            head = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        i += 12 + size
    w, h, depth, colour, _, _, interlace = head
    channels = {0: 1, 4: 2, 2: 3, 6: 4}.get(colour)
    if depth != 8 or channels is None or interlace:
        raise ValueError("%s: only 8-bit non-interlaced grey/RGB(A) PNGs are read" % path)
    raw, stride = zlib.decompress(idat), w * channels
    rows, prev = [], bytearray(stride)
    for y in range(h):
        kind, line = raw[y * (stride + 1)], bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for x in range(stride):
            a = line[x - channels] if x >= channels else 0
            b = prev[x]
            c = prev[x - channels] if x >= channels else 0
            if kind == 1:
                line[x] = (line[x] + a) & 0xFF
            elif kind == 2:
                line[x] = (line[x] + b) & 0xFF
            elif kind == 3:
                line[x] = (line[x] + (a + b) // 2) & 0xFF
            elif kind == 4:
                pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                line[x] = (line[x] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 0xFF
        rows.append(bytes(line[0::channels]))
        prev = line
    return w, h, b"".join(rows)


def write_png_gray(path, w, h, grey):
    """An 8-bit greyscale PNG of `grey` (row-major bytes)."""
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    rows = b"".join(b"\0" + grey[y * w:(y + 1) * w] for y in range(h))
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(rows, 9)) + chunk(b"IEND", b""))


def perturbed_mask(work, scene_dir, name, px):
    """The scene's mask grown (px > 0) or shrunk (px < 0) by |px| pixels: a pixel joins (leaves) it
    when a mask (non-mask) pixel lies within a disk of that radius. Written once to
    WORK/masks/NAME_mask+PX.png; returns its path."""
    path = os.path.join(work, "masks", "%s_mask%+d.png" % (name, px))
    if os.path.exists(path):
        return path
    w, h, grey = read_png_gray(os.path.join(scene_dir, "mask.png"))
    inside = [v > 127 for v in grey]
    r = abs(px)
    disk = [(dx, dy) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if dx * dx + dy * dy <= r * r]
    grow = px > 0
    out = bytearray(w * h)
    for y in range(h):
        for x in range(w):
            near = any(inside[(y + dy) * w + x + dx] == grow
                       for dx, dy in disk if 0 <= x + dx < w and 0 <= y + dy < h)
            out[y * w + x] = 255 if near == grow else 0
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = path + ".tmp"
    write_png_gray(tmp, w, h, bytes(out))
    os.replace(tmp, path)
    return path


def run_one(args, sc, meta, quality, threads, cache):
    scene_dir = os.path.join(args.work, "scenes", sc["name"])
    est_dir = os.path.join(args.work, "runs", sc["name"], "%s_t%d%s" % (
        quality, threads, "_mask%+d" % args.mask_error if args.mask_error else ""))
    shutil.rmtree(est_dir, ignore_errors=True)
    os.makedirs(os.path.dirname(est_dir), exist_ok=True)
    rec = {"scene": sc["name"], "env": sc["env"], "probe": sc["probe"], "variant": sc["variant"],
           "seed": sc["seed"], "tilted": sc["tilted"], "axis_tilt_deg": round(meta["axis_tilt_deg"], 2),
           "noise": sc["noise"], "exposure_clip": meta.get("exposure_clip"),
           "quality": quality, "threads": threads, "load_1m": round(os.getloadavg()[0], 2),
           "alp_sha256": args.alp_sha[:12], "mask_error_px": args.mask_error}
    with open(os.path.join(scene_dir, "probe.txt")) as f:
        probe = f.read().strip()
    mask = os.path.join(scene_dir, "mask.png")
    if args.mask_error:
        mask = perturbed_mask(args.work, scene_dir, sc["name"], args.mask_error)
    cmd = [args.alp, "estimate", "--image", os.path.join(scene_dir, "image.exr"),
           "--mask", mask, "--camera", os.path.join(scene_dir, "camera.json"),
           "--probe", probe, "--out", est_dir, "--quality", quality, "--threads", str(threads), "--seed", "0"]
    log = est_dir + ".estimate.log"
    try:
        _, wall, rss, cpu = run(cmd, cwd=args.work, log_path=log)
        rec["wall_s"] = round(wall, 3)
        rec["cpu_s"] = round(cpu, 3)
        rec["max_rss_mb"] = round(rss, 1)
        with open(os.path.join(est_dir, "report.json")) as f:
            report = json.load(f)
        for k in ("wall_s", "psnr_db", "clipped_pixels", "chosen_start"):
            if k in report:
                rec["report_" + k if k == "wall_s" else k] = report[k]
        ev = evaluate(args.alp, args.work, scene_dir, est_dir, args.eval_spp, cache, args.alp_sha)
        for k, v in ev.items():
            if k != "scene":
                rec[k] = v
    except (AlpError, OSError, ValueError, KeyError) as e:
        rec["error"] = str(e)
    rec["success"] = success(rec, args.sphere_success_mm)
    return rec


# ---------------------------------------------------------------- summary

def fmt(x, nd=2):
    if x is None:
        return "-"
    if isinstance(x, float) and (math.isnan(x) or math.isinf(x)):
        return str(x)
    return ("%." + str(nd) + "f") % x


def mean(xs):
    return statistics.fmean(xs) if xs else None


def median(xs):
    return statistics.median(xs) if xs else None


def group_row(recs):
    ok = [r for r in recs if not r.get("error")]
    asym = [r for r in ok if r["probe"] not in AXIS_SYMMETRIC | NO_ORIENTATION]
    oriented = [r for r in ok if r["probe"] not in NO_ORIENTATION]
    g = lambda rs, k: [r[k] for r in rs if r.get(k) is not None]
    return {
        "n": len(recs), "failed": len(recs) - len(ok),
        "ang": [mean([r[s]["angular_deg"] for r in ok]) for s in ("mirror", "shiny", "diffuse")],
        "si": [mean([r[s]["si_rmse"] for r in ok]) for s in ("mirror", "shiny", "diffuse")],
        "rot_med": median(g(asym, "rotation_deg")), "rot_mean": mean(g(asym, "rotation_deg")),
        "axis_med": median(g(oriented, "axis_deg")), "axis_mean": mean(g(oriented, "axis_deg")),
        "tr_med": median(g(ok, "translation_mm")), "tr_mean": mean(g(ok, "translation_mm")),
        "success": sum(r["success"] for r in recs) / len(recs) if recs else None,
        "n_success": sum(r["success"] for r in recs),
        "wall_med": median(g(ok, "wall_s")), "wall_mean": mean(g(ok, "wall_s")),
        "cpu_med": median(g(ok, "cpu_s")),
        "rss_max": max(g(ok, "max_rss_mb"), default=None),
        "load_max": max(g(recs, "load_1m"), default=None),
    }


def summary(records, args, cmdline):
    keys = sorted({(r["quality"], r["threads"]) for r in records},
                  key=lambda k: (["fast", "default", "best"].index(k[0]) if k[0] in ("fast", "default", "best") else 9, -k[1]))
    L = ["# alp evaluation suite", "",
         "`%s`" % cmdline, "",
         "alp: `%s` (sha256 %s); eval spp %d; success: rotation < %g deg (can), axis < %g deg (cap, symmetric about "
         "its axis), translation < %g mm (sphere). Angular error in degrees, translation in mm, wall "
         "time in seconds per image (the whole `alp estimate` process), RSS = max resident set of "
         "`alp estimate`, CPU = its user + system time, max load = the highest 1-minute load average "
         "seen just before a run (the preceding `alp eval`, on 2 threads, adds ~1.5 by itself). "
         "Rotation columns: the can only (observable turn); axis: can + cap.%s"
         % (args.alp, args.alp_sha[:12], args.eval_spp, SUCCESS_DEG, SUCCESS_DEG, args.sphere_success_mm,
            " Masks %s by %d px (`--mask-error`)." % ("grown" if args.mask_error > 0 else "shrunk",
                                                   abs(args.mask_error)) if args.mask_error else ""), "",
         "## Per quality and thread count", "",
         "| quality | threads | scenes | failed | ang. mirror | ang. shiny | ang. diffuse | si-RMSE mirror | "
         "si-RMSE shiny | si-RMSE diffuse | rot. median | rot. mean | axis median | axis mean | "
         "transl. median | transl. mean | success | wall median | wall mean | CPU median | max RSS MB | max load |",
         "|" + " --- |" * 22]
    for q, t in keys:
        rs = [r for r in records if (r["quality"], r["threads"]) == (q, t)]
        g = group_row(rs)
        L.append("| %s | %d | %d | %d | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %d/%d (%s %%) | %s | %s | %s | %s | %s |" % (
            q, t, g["n"], g["failed"], *[fmt(x) for x in g["ang"]], *[fmt(x, 3) for x in g["si"]],
            fmt(g["rot_med"], 1), fmt(g["rot_mean"], 1), fmt(g["axis_med"], 1), fmt(g["axis_mean"], 1),
            fmt(g["tr_med"], 1), fmt(g["tr_mean"], 1), g["n_success"], g["n"],
            fmt(100 * g["success"], 0) if g["success"] is not None else "-",
            fmt(g["wall_med"], 2), fmt(g["wall_mean"], 2), fmt(g["cpu_med"], 2), fmt(g["rss_max"], 0),
            fmt(g["load_max"], 2)))
    # Thread counts compared on the same scenes.
    by_q = {}
    for q, t in keys:
        by_q.setdefault(q, []).append(t)
    pairs = [(q, ts) for q, ts in by_q.items() if len(ts) > 1]
    if pairs:
        L += ["", "## Thread counts on the same scenes", "",
              "| quality | threads | scenes | wall median | wall mean | CPU median | speed-up (median of per-scene wall ratios) | max RSS MB | success |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for q, ts in pairs:
            common = set.intersection(*[{r["scene"] for r in records if (r["quality"], r["threads"]) == (q, t)} for t in ts])
            base = {r["scene"]: r for r in records if (r["quality"], r["threads"]) == (q, min(ts)) and r["scene"] in common}
            for t in ts:
                rs = [r for r in records if (r["quality"], r["threads"]) == (q, t) and r["scene"] in common]
                g = group_row(rs)
                ratios = [base[r["scene"]]["wall_s"] / r["wall_s"] for r in rs
                          if r.get("wall_s") and base[r["scene"]].get("wall_s")]
                L.append("| %s | %d | %d | %s | %s | %s | %s | %s | %d/%d |" % (
                    q, t, len(rs), fmt(g["wall_med"]), fmt(g["wall_mean"]), fmt(g["cpu_med"]),
                    fmt(median(ratios)) + " (vs %d)" % min(ts) if ratios else "-",
                    fmt(g["rss_max"], 0), g["n_success"], g["n"]))
    # Breakdown by probe and by variant.
    L += ["", "## By probe and variant", "",
          "| quality | threads | subset | scenes | success | ang. mirror | ang. shiny | ang. diffuse | "
          "si-RMSE diffuse | rot. median (all probes) | axis median | transl. median | wall median |",
          "|" + " --- |" * 13]
    for q, t in keys:
        rs = [r for r in records if (r["quality"], r["threads"]) == (q, t)]
        subsets = [("probe " + p, lambda r, p=p: r["probe"] == p) for p in sorted({r["probe"] for r in rs})]
        subsets += [(v, lambda r, v=v: r["variant"] == v) for v in VARIANTS if any(r["variant"] == v for r in rs)]
        subsets += [("env " + e, lambda r, e=e: r["env"] == e) for e in ENVS if any(r["env"] == e for r in rs)]
        for label, pred in subsets:
            sub = [r for r in rs if pred(r)]
            ok = [r for r in sub if not r.get("error")]
            g = group_row(sub)
            L.append("| %s | %d | %s | %d | %d/%d | %s | %s | %s | %s | %s | %s | %s | %s |" % (
                q, t, label, len(sub), g["n_success"], g["n"], *[fmt(x) for x in g["ang"]], fmt(g["si"][2], 3),
                fmt(median([r["rotation_deg"] for r in ok]), 1), fmt(g["axis_med"], 1), fmt(g["tr_med"], 1),
                fmt(g["wall_med"])))
    # Per scene.
    L += ["", "## Per scene", "",
          "| scene | tilt deg | quality | threads | ang. mirror/shiny/diffuse | si-RMSE m/s/d | rot. | axis | transl. mm | scale | ok | wall s | RSS MB |",
          "|" + " --- |" * 13]
    for r in records:
        if r.get("error"):
            L.append("| %s | %s | %s | %d | ERROR | | | | | | no | | |" % (r["scene"], fmt(r["axis_tilt_deg"], 0), r["quality"], r["threads"]))
            continue
        L.append("| %s | %s | %s | %d | %s / %s / %s | %s / %s / %s | %s | %s | %s | %s | %s | %s | %s |" % (
            r["scene"], fmt(r["axis_tilt_deg"], 0), r["quality"], r["threads"],
            *[fmt(r[s]["angular_deg"], 1) for s in ("mirror", "shiny", "diffuse")],
            *[fmt(r[s]["si_rmse"], 3) for s in ("mirror", "shiny", "diffuse")],
            fmt(r["rotation_deg"], 1), fmt(r["axis_deg"], 1), fmt(r["translation_mm"], 1), fmt(r["scale_ratio"], 3),
            "yes" if r["success"] else "no", fmt(r["wall_s"]), fmt(r["max_rss_mb"], 0)))
    errs = [r for r in records if r.get("error")]
    if errs:
        L += ["", "## Failures", ""]
        for r in errs:
            L += ["- %s, %s, %d threads:" % (r["scene"], r["quality"], r["threads"]), "", "```", r["error"], "```", ""]
    return "\n".join(L) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--alp", required=True, help="the alp binary")
    ap.add_argument("--work", required=True, help="work folder: scenes/, runs/, results, summary.md")
    ap.add_argument("--qualities", default="fast,default")
    ap.add_argument("--threads", default="2", help="comma-separated thread counts, e.g. 2,1")
    ap.add_argument("--scenes", type=int, default=None, help="only the first N scenes of the table")
    ap.add_argument("--out", default=None, help="JSON lines (default: WORK/results.jsonl)")
    ap.add_argument("--extra-runs", default="", help="Q:T:N[,...]: quality Q, T threads, first N scenes only")
    ap.add_argument("--eval-spp", type=int, default=256, help="alp eval --spp (a square)")
    ap.add_argument("--sphere", action="store_true", help="append 3 sphere scenes")
    ap.add_argument("--only", default="", help="keep only scenes whose name contains one of these "
                    "comma-separated strings (after --scenes), e.g. sphere or studio_can")
    ap.add_argument("--sphere-success-mm", type=float, default=3.0)
    ap.add_argument("--envmaps", default=DEFAULT_ENVMAPS)
    ap.add_argument("--mask-error", type=int, default=0,
                    help="estimate from each scene's mask grown (> 0) or shrunk (< 0) by this many pixels")
    ap.add_argument("--rss", choices=["auto", "time", "wait4"], default="auto",
                    help="peak memory from `/usr/bin/time -v` (auto: when present) or os.wait4's rusage")
    args = ap.parse_args()
    global RSS_VIA
    RSS_VIA = args.rss
    args.alp = os.path.abspath(args.alp)
    args.work = os.path.abspath(args.work)
    args.envmaps = os.path.abspath(args.envmaps)
    args.alp_sha = sha256_files([args.alp], "")
    os.makedirs(args.work, exist_ok=True)
    out_path = os.path.abspath(args.out or os.path.join(args.work, "results.jsonl"))
    cmdline = " ".join(["python3", os.path.relpath(__file__)] + sys.argv[1:])

    scenes = scene_table(args.sphere)
    if args.scenes is not None:
        scenes = scenes[:args.scenes]
    if args.only:
        scenes = [sc for sc in scenes if any(w in sc["name"] for w in args.only.split(",") if w)]
    plan = [(i, q, int(t)) for i in range(len(scenes))
            for q in args.qualities.split(",") if q for t in args.threads.split(",") if t]
    for spec in filter(None, args.extra_runs.split(",")):
        q, t, n = spec.split(":")
        plan += [(i, q, int(t)) for i in range(min(int(n), len(scenes)))]
    seen, ordered = set(), []
    for p in plan:
        if p not in seen:
            seen.add(p)
            ordered.append(p)
    ordered.sort(key=lambda p: p[0])

    print("%d scenes, %d estimates; work %s" % (len(scenes), len(ordered), args.work), file=sys.stderr)
    metas = []
    for sc in scenes:
        t0 = time.perf_counter()
        try:
            metas.append(ensure_scene(args.alp, args.work, args.envmaps, sc))
        except AlpError as e:
            sys.exit("scene %s: %s" % (sc["name"], e))
        print("scene %-45s tilt %5.1f deg%s (%.1f s)" % (
            sc["name"], metas[-1]["axis_tilt_deg"],
            ", clip %.4g" % metas[-1]["exposure_clip"] if metas[-1].get("exposure_clip") else "",
            time.perf_counter() - t0), file=sys.stderr)

    cache_path = os.path.join(args.work, "eval_cache.json")
    cache = {}
    if os.path.exists(cache_path):
        with open(cache_path) as f:
            cache = json.load(f)
    records = []
    with open(out_path, "w") as out:
        for n, (i, q, t) in enumerate(ordered):
            rec = run_one(args, scenes[i], metas[i], q, t, cache)
            records.append(rec)
            out.write(json.dumps(rec) + "\n")
            out.flush()
            if rec.get("error"):
                print("[%d/%d] %s %s t%d: ERROR %s" % (n + 1, len(ordered), scenes[i]["name"], q, t, rec["error"]),
                      file=sys.stderr)
            else:
                print("[%d/%d] %s %s t%d: %.2f s, %.0f MB, rot %.1f axis %.1f tr %.1f mm, ang %.1f/%.1f/%.1f%s" % (
                    n + 1, len(ordered), scenes[i]["name"], q, t, rec["wall_s"], rec["max_rss_mb"],
                    rec["rotation_deg"], rec["axis_deg"], rec["translation_mm"], rec["mirror"]["angular_deg"],
                    rec["shiny"]["angular_deg"], rec["diffuse"]["angular_deg"],
                    " (eval cached)" if rec.get("eval_cached") else ""), file=sys.stderr)
    text = summary(records, args, cmdline)
    with open(os.path.join(args.work, "summary.md"), "w") as f:
        f.write(text)
    print(text)


if __name__ == "__main__":
    main()

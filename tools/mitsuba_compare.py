#!/usr/bin/env python3
"""Render one probe scene with Mitsuba 3 and compare it with our renderer's image.

    python3 mitsuba_compare.py --probe DIR --pose pose.json --camera camera.json --env env.exr \
        --spp N [--ours image.exr [--mask mask.png] | --alp-bin PATH] \
        [--variant scalar_rgb|llvm_ad_rgb] [--integrator direct|path] [--out-dir DIR]

Prints ONE JSON line on stdout (metrics over the probe pixels: pixels fully covered by the probe
in Mitsuba's coverage, eroded by one pixel, and in our mask when one is given, also eroded):
  rel_err_mean     mean over pixels and channels of |ours - mitsuba| / mitsuba
  rel_err_of_means |mean(ours) - mean(mitsuba)| / mean(mitsuba), averaged over channels
  rel_err_of_means_rgb  the same per channel (signed: (ours - mitsuba) / mitsuba)
  rmse, rel_rmse   RMSE, and RMSE / RMS(mitsuba)
  mitsuba_noise_rel  Mitsuba's own Monte Carlo noise on the same statistic as rel_err_mean
                   (from two independent halves of its samples): the floor of rel_err_mean
and writes out-dir/{mitsuba.exr, ours.exr (if rendered here), compare.png (ours | mitsuba |
relative error, 0 black .. 10% white, cropped to the probe), mask_used.png}.

The model (PAPER.md / FORMATS.md) in Mitsuba terms: the OBJ with to_world = pose; a
`roughconductor` (GGX, alpha = r^2, `material: none`, `specular_reflectance` = albedo) or a
smooth `conductor` for r = 0; the `envmap` emitter from our EXR resampled to Mitsuba's rows
(alp_mitsuba.env_to_mitsuba); a `perspective` sensor (fov_axis y, look_at, box filter).
Integrator `direct` (default on LLVM): direct lighting at the first hit with shadow rays, times
the visibility texture, with Schlick's Fresnel applied per sample (`--fresnel schlick`, default):
our model exactly; `path` (max_depth 2, hide_emitters): Mitsuba's own, which folds the
visibility into the reflectance and has only the conductor's Fresnel.
`--fresnel none` shows the known difference: Mitsuba's `material: none` Fresnel is
1 x reflectance, ours Schlick with F0 = albedo (identical for albedo 1; otherwise ours is
brighter towards grazing angles).
"""

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

import alp_mitsuba as am


def render_mitsuba(mi, probe, pose, cam, env, spp, integrator_kind, crop, pass_samples, fresnel):
    """Average of independent passes (bounded memory). Returns (rgb, alpha, halfA, halfB) over
    the crop."""
    import drjit as dr
    x0, y0, x1, y1 = crop
    npx = (x1 - x0) * (y1 - y0)
    per_pass = max(1, min(spp, pass_samples // max(npx, 1)))
    white = False
    if integrator_kind == "direct":
        # the visibility is applied by the integrator (a texture or a constant), never folded
        white = fresnel == "schlick"
        fold = False
        vis = probe["visibility"]
        vis_tex = mi.load_dict(am._texture(mi, vis, 1) if isinstance(vis, np.ndarray)
                               else {"type": "uniform", "value": float(vis)})
        integ_dict = am.make_direct_integrator(
            mi, mi.load_dict(am._texture(mi, probe["albedo"], 3)) if white else None, vis_tex)
    elif integrator_kind == "path":
        if fresnel == "schlick":
            sys.exit("--fresnel schlick needs --integrator direct (Mitsuba's own integrators "
                     "only have the conductor Fresnel)")
        fold = True
        integ_dict = {"type": "path", "max_depth": 3, "hide_emitters": True}
    else:
        sys.exit("unknown integrator %r" % integrator_kind)
    scene = mi.load_dict(am.scene_dict(mi, probe, pose, cam, env, per_pass, integ_dict, crop,
                                       seed=0, fold_visibility=fold, white=white))
    passes = []
    done = 0
    k = 0
    while done < spp:
        n = min(per_pass, spp - done)
        img = np.array(mi.render(scene, seed=1000 + k, spp=n), dtype=np.float64)
        passes.append((img, n))
        done += n
        k += 1
    tot = sum(n for _, n in passes)
    full = sum(img * n for img, n in passes) / tot
    # two independent halves for a noise estimate
    half = len(passes) // 2
    if half >= 1:
        a = sum(img * n for img, n in passes[:half]) / sum(n for _, n in passes[:half])
        b = sum(img * n for img, n in passes[half:]) / sum(n for _, n in passes[half:])
    else:
        a = b = None
    return full[:, :, :3], full[:, :, 3], a, b, len(passes)


def erode(m, r=1):
    out = m.copy()
    h, w = m.shape
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            s = np.zeros_like(m)
            ys = slice(max(0, dy), h + min(0, dy))
            yd = slice(max(0, -dy), h + min(0, -dy))
            xs = slice(max(0, dx), w + min(0, dx))
            xd = slice(max(0, -dx), w + min(0, -dx))
            s[yd, xd] = m[ys, xs]
            out &= s
    return out


def block_mean(img, mask, b):
    """b x b block averages over the blocks entirely inside `mask`."""
    h, w = mask.shape
    hb, wb = h // b, w // b
    m = mask[:hb * b, :wb * b].reshape(hb, b, wb, b).all(axis=(1, 3))
    x = img[:hb * b, :wb * b].reshape(hb, b, wb, b, -1).mean(axis=(1, 3))
    return x, m


def metrics(ours, ref, mask, eps=1e-6, block=4):
    out = _metrics(ours, ref, mask, eps)
    ob, mb = block_mean(ours, mask, block)
    rb, _ = block_mean(ref, mask, block)
    if mb.any():
        rel = np.abs(ob[mb] - rb[mb]) / np.maximum(rb[mb], eps)
        out["rel_err_mean_block%d" % block] = float(rel.mean())
        out["blocks"] = int(mb.sum())
    return out


def _metrics(ours, ref, mask, eps=1e-6):
    o = ours[mask].astype(np.float64)
    m = ref[mask].astype(np.float64)
    rel = np.abs(o - m) / np.maximum(m, eps)
    mo, mm = o.mean(0), m.mean(0)
    rmse = float(np.sqrt(np.mean((o - m) ** 2)))
    return {
        "pixels": int(mask.sum()),
        "rel_err_mean": float(rel.mean()),
        "rel_err_median": float(np.median(rel.mean(1))),
        "rel_err_of_means": float(np.mean(np.abs(mo - mm) / mm)),
        "rel_err_of_means_rgb": [float(x) for x in (mo - mm) / mm],
        "rmse": rmse,
        "rel_rmse": rmse / float(np.sqrt(np.mean(m ** 2))),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--probe", required=True)
    ap.add_argument("--pose", required=True)
    ap.add_argument("--camera", required=True)
    ap.add_argument("--env", required=True)
    ap.add_argument("--spp", type=int, required=True, help="Mitsuba's samples per pixel (and ours with --alp-bin)")
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--ours", help="our render (linear EXR)")
    g.add_argument("--alp-bin", help="our `alp` binary: render with it here")
    ap.add_argument("--mask", help="our probe mask PNG (with --ours); --alp-bin writes one")
    ap.add_argument("--ours-spp", type=int, help="spp for our render (default --spp)")
    ap.add_argument("--seed", type=int, default=0, help="seed of our render")
    ap.add_argument("--ours-noise", action="store_true",
                    help="with --alp-bin: render ours a second time (seed + 1) to estimate its noise")
    ap.add_argument("--variant", default=None, choices=["scalar_rgb", "llvm_ad_rgb"],
                    help="default llvm_ad_rgb if libLLVM 19 is found, else scalar_rgb")
    ap.add_argument("--integrator", default=None, choices=["direct", "path"],
                    help="default: direct on LLVM, path on scalar (a Python integrator is "
                         "called per sample in scalar variants: slow)")
    ap.add_argument("--fresnel", default=None, choices=["schlick", "none"],
                    help="schlick (default with direct): ours exactly, Schlick applied in the "
                         "integrator; none: Mitsuba's `material: none` (F = 1 x albedo)")
    ap.add_argument("--out-dir", default="mitsuba_compare_out")
    ap.add_argument("--pass-samples", type=int, default=1 << 22,
                    help="samples per Mitsuba pass (memory bound)")
    ap.add_argument("--label", default="", help="free text copied into the JSON line")
    a = ap.parse_args()

    variant = a.variant
    if variant is None:
        import glob
        variant = "llvm_ad_rgb" if (os.environ.get("DRJIT_LIBLLVM_PATH") or glob.glob(am.LLVM_GLOB)) else "scalar_rgb"
    integ = a.integrator or ("direct" if variant.startswith("llvm") else "path")
    fresnel = a.fresnel or ("schlick" if integ == "direct" else "none")
    mi = am.setup_variant(variant)
    mi.set_log_level(mi.LogLevel.Error)  # scalar variants warn about the maps' tiny negative texels
    os.makedirs(a.out_dir, exist_ok=True)

    probe = am.load_probe(a.probe)
    pose = am.load_pose(a.pose)
    cam = am.load_camera(a.camera)
    env = am.read_exr(a.env)
    W, H = int(cam["width"]), int(cam["height"])

    # Ours
    ours_mask = None
    ours_time = None
    ours2 = None
    if a.alp_bin:
        ours_path = os.path.join(a.out_dir, "ours.exr")
        mask_path = os.path.join(a.out_dir, "ours_mask.png")
        cmd = [a.alp_bin, "render", "--probe", a.probe, "--pose", a.pose, "--camera", a.camera,
               "--env", a.env, "--out", ours_path, "--spp", str(a.ours_spp or a.spp),
               "--mask-out", mask_path, "--seed", str(a.seed)]
        t0 = time.time()
        r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        ours_time = time.time() - t0
        if r.returncode != 0:
            sys.exit("alp render failed (%d):\n%s\n%s" % (r.returncode, r.stdout, r.stderr))
        ours = am.read_exr(ours_path)
        ours_mask = am.read_mask(mask_path)
        ours2 = None
        if a.ours_noise:
            p2 = os.path.join(a.out_dir, "ours_seed2.exr")
            cmd2 = list(cmd)
            cmd2[cmd2.index("--out") + 1] = p2
            cmd2[cmd2.index("--seed") + 1] = str(a.seed + 1)
            cmd2[cmd2.index("--mask-out") + 1] = os.path.join(a.out_dir, "ours_mask2.png")
            r = subprocess.run(cmd2, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            if r.returncode != 0:
                sys.exit("alp render failed (%d):\n%s\n%s" % (r.returncode, r.stdout, r.stderr))
            ours2 = am.read_exr(p2)
    elif a.ours:
        ours = am.read_exr(a.ours)
        if a.mask:
            ours_mask = am.read_mask(a.mask)
    else:
        ours = None
    if ours is not None and ours.shape[:2] != (H, W):
        sys.exit("our image is %dx%d, camera.json says %dx%d" % (ours.shape[1], ours.shape[0], W, H))

    # Mitsuba over the probe's bounding box
    crop = am.probe_bbox(cam, probe, pose)
    x0, y0, x1, y1 = crop
    t0 = time.time()
    rgb, alpha, ha, hb, npasses = render_mitsuba(mi, probe, pose, cam, env, a.spp, integ, crop,
                                                 a.pass_samples, fresnel)
    mi_time = time.time() - t0
    mits = np.zeros((H, W, 3), np.float32)
    mits[y0:y1, x0:x1] = rgb
    cov = np.zeros((H, W), bool)
    cov[y0:y1, x0:x1] = alpha >= 1.0 - 1e-6
    am.write_exr(os.path.join(a.out_dir, "mitsuba.exr"), mits)

    mask = erode(cov, 1)
    if ours_mask is not None:
        mask &= erode(ours_mask, 1)
    am.write_png(os.path.join(a.out_dir, "mask_used.png"), np.where(mask, 255, 0).astype(np.uint8))

    out = {"label": a.label, "probe": a.probe, "env": os.path.basename(a.env), "spp": a.spp,
           "ours_spp": (a.ours_spp or a.spp) if a.alp_bin else None,
           "variant": variant, "integrator": integ, "fresnel": fresnel, "mitsuba_passes": npasses,
           "mitsuba_seconds": round(mi_time, 2),
           "ours_seconds": round(ours_time, 2) if ours_time is not None else None}
    em = eo = None
    if ha is not None:
        hmask = mask[y0:y1, x0:x1]
        # E|A - B| / 2 = E|error of the full average|: Mitsuba's expected share of rel_err_mean
        em = np.abs(ha - hb)[hmask][:, :3] / 2 / np.maximum(rgb[hmask], 1e-6)
        out["mitsuba_noise_rel"] = float(np.mean(em))
    if ours2 is not None:
        # E|o1 - o2| / sqrt(2) = E|error of one render of ours|
        eo = np.abs(ours - ours2)[mask] / np.sqrt(2) / np.maximum(mits[mask], 1e-6)
        out["ours_noise_rel"] = float(np.mean(eo))
        if em is not None:
            # what rel_err_mean would be from noise alone (both renders unbiased)
            out["noise_floor_rel"] = float(np.mean(np.sqrt(eo ** 2 + em ** 2)))
    if ours is not None and mask.any():
        out.update(metrics(ours, mits, mask))
        # Side by side, cropped to the probe, same exposure
        ref = mits[mask]
        exposure = 0.5 / max(float(np.percentile(ref.mean(1), 90)), 1e-6)
        oc = ours[y0:y1, x0:x1]
        mc = mits[y0:y1, x0:x1]
        rel = np.abs(oc - mc).mean(2) / np.maximum(mc.mean(2), 1e-6)
        heat = np.clip(rel / 0.10, 0, 1)
        heat = np.where(mask[y0:y1, x0:x1], heat, 0)
        heat8 = np.stack([heat * 255, heat * 255, heat * 255], 2).astype(np.uint8)
        heat8[~mask[y0:y1, x0:x1]] = [40, 0, 40]
        sep = np.full((y1 - y0, 4, 3), 128, np.uint8)
        side = np.concatenate([am.tonemap(oc, exposure), sep, am.tonemap(mc, exposure), sep, heat8], 1)
        am.write_png(os.path.join(a.out_dir, "compare.png"), side)
    print(json.dumps(out))


if __name__ == "__main__":
    main()

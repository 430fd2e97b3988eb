#!/usr/bin/env python3
"""Time Mitsuba 3's LLVM backend (llvm_ad_rgb) on one forward + backward iteration of the work
our benchmark does: the procedural can (~200 px tall) in a 640 x 480 camera, 8 spp, L1 image loss
against a reference image, gradients w.r.t. a 128 x 64 environment map and the probe's pose.

    python3 mitsuba_timing.py --probe DIR [--threads 1 2] [--iters 10] [--spp 8] [--crop bbox|full]

`--probe` is a probe folder (`alp probe make can --out DIR`). Prints one JSON line per thread
count: the median (and min / max) wall time in ms of the warm iterations.

One iteration:
  1. our 64 x 128 map (a leaf tensor) -> Mitsuba's `envmap` `data` (2H + 1 rows + the wrap
     column, alp_mitsuba.env_to_mitsuba done with Dr.Jit gathers, so the gradient reaches our
     texels), and the pose (yaw angle + translation, leaves) -> the mesh's `vertex_positions`;
     params.update() (Mitsuba rebuilds the envmap's sampling distribution here);
  2. mi.render with the `prb` integrator (max_depth 2: direct lighting, emitter + BSDF sampling,
     occlusion tested; prb ignores visibility discontinuities, i.e. no silhouette gradients),
     film cropped to the probe's bounding box (our renderer also traces only that box);
  3. loss = mean |image - reference|; dr.backward(loss); the gradients are evaluated.
The reference is rendered once at 64 spp with the true parameters; the iteration starts from a
perturbed pose and a blurred / dimmed map. Iterations after `--warmup` (kernels compiled and
cached by then) are timed.
"""

import argparse
import json
import os
import statistics
import time

import numpy as np

import alp_mitsuba as am


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--probe", required=True, help="probe folder (alp probe make can --out DIR)")
    ap.add_argument("--env", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..",
                                                  "assets", "envmaps", "courtyard.exr"))
    ap.add_argument("--env-size", type=int, nargs=2, default=[128, 64], help="width height")
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--iters", type=int, default=10)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--crop", choices=["bbox", "full"], default="bbox")
    ap.add_argument("--grads", choices=["both", "env", "pose", "none"], default="both",
                    help="which parameters get gradients (both: the benchmark's work; none: forward only)")
    ap.add_argument("--integrator", default="prb", help="prb (default) or prb_basic, direct_projective...")
    a = ap.parse_args()

    mi = am.setup_variant("llvm_ad_rgb")
    import drjit as dr
    mi.set_log_level(mi.LogLevel.Error)

    probe = am.load_probe(a.probe)
    # camera: 640 x 480, the can ~200 px tall, seen slightly from above
    cam = {"width": 640, "height": 480, "fov_y_deg": 40.0, "origin": [0.0, 0.09, 0.4],
           "target": [0.0, 0.061, 0.0], "up": [0.0, 1.0, 0.0]}
    pos = am.read_obj_positions(probe["mesh"])
    centre = 0.5 * (pos.min(0) + pos.max(0))
    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.061, 0.0] - centre  # mesh centre at the target
    crop = am.probe_bbox(cam, probe, pose) if a.crop == "bbox" else None
    height_px = None
    c, r = am.project(cam, pos + pose[:3, 3])
    height_px = float(np.nanmax(r) - np.nanmin(r))

    # our env map, box-downsampled to env-size
    W, H = a.env_size
    full = am.read_exr(a.env).astype(np.float64)
    fh, fw = full.shape[:2]
    env_true = full.reshape(H, fh // H, W, fw // W, 3).mean(axis=(1, 3)).astype(np.float32)

    integ = {"type": a.integrator, "max_depth": 2, "hide_emitters": True}
    sd = am.scene_dict(mi, probe, pose, cam, env_true, a.spp, integ, crop)
    scene = mi.load_dict(sd)
    params = mi.traverse(scene)
    vkey, ekey = "probe.vertex_positions", "env.data"
    v0 = mi.Point3f(dr.unravel(mi.Point3f, params[vkey]))
    dr.eval(v0)

    # our map -> Mitsuba's data, as Dr.Jit gathers (differentiable in our texels)
    k = np.arange(2 * H + 1)
    cr = np.clip(k / 2.0 - 0.5, 0, H - 1)
    i0 = np.floor(cr).astype(np.int64)
    i1 = np.minimum(i0 + 1, H - 1)
    fr = cr - i0
    jj = np.arange(W + 1) % W
    ch = np.arange(3)
    idx0 = ((i0[:, None, None] * W + jj[None, :, None]) * 3 + ch[None, None, :]).ravel()
    idx1 = ((i1[:, None, None] * W + jj[None, :, None]) * 3 + ch[None, None, :]).ravel()
    frac = np.broadcast_to(fr[:, None, None], (2 * H + 1, W + 1, 3)).ravel()
    idx0, idx1 = mi.UInt32(idx0.astype(np.uint32)), mi.UInt32(idx1.astype(np.uint32))
    frac = mi.Float(frac.astype(np.float32))
    shape = (2 * H + 1, W + 1, 3)

    def set_params(env_flat, yaw, t):
        data = dr.lerp(dr.gather(mi.Float, env_flat, idx0), dr.gather(mi.Float, env_flat, idx1), frac)
        params[ekey] = mi.TensorXf(data, shape)
        c_ = [float(x) for x in pose[:3, 3]]
        xf = (mi.Transform4f().translate(mi.Vector3f(c_[0], c_[1], c_[2]) + t)
              @ mi.Transform4f().rotate([0, 1, 0], yaw)
              @ mi.Transform4f().translate(mi.Vector3f(-c_[0], -c_[1], -c_[2])))
        params[vkey] = dr.ravel(xf @ v0)
        params.update()

    # reference at the true parameters
    set_params(mi.Float(env_true.ravel()), mi.Float(0.0), mi.Vector3f(0.0))
    ref = mi.render(scene, params, spp=64, seed=12345)
    dr.eval(ref)

    # start: blurred, dimmed map; pose off by 10 degrees and 3 mm
    env0 = (0.7 * env_true + 0.3 * env_true.mean((0, 1))).astype(np.float32)
    results = []
    for n in a.threads:
        dr.set_thread_count(n)
        env_var = mi.Float(env0.ravel())
        yaw = mi.Float(10.0)
        t = mi.Vector3f(0.003, -0.002, 0.0)
        times = []
        for it in range(a.warmup + a.iters):
            t0 = time.perf_counter()
            if a.grads in ("both", "env"):
                dr.enable_grad(env_var)
            if a.grads in ("both", "pose"):
                dr.enable_grad(yaw, t)
            set_params(env_var, yaw, t)
            img = mi.render(scene, params, spp=a.spp, seed=it)
            loss = dr.mean(dr.abs(img - ref), axis=None)
            if a.grads != "none":
                dr.backward(loss)
            g_env, g_yaw, g_t = dr.grad(env_var), dr.grad(yaw), dr.grad(t)
            dr.eval(loss, g_env, g_yaw, g_t)
            dr.sync_thread()
            dt = time.perf_counter() - t0
            if it >= a.warmup:
                times.append(dt * 1e3)
            # a plain gradient step so that every iteration sees new values
            env_var = dr.detach(dr.maximum(env_var - 1e-2 * dr.sign(g_env), 0.0))
            yaw = dr.detach(yaw - 1e-1 * dr.sign(g_yaw))
            t = dr.detach(t - 1e-5 * dr.sign(g_t))
        g = np.array(g_env)
        results.append({
            "threads": n, "median_ms": round(statistics.median(times), 1),
            "min_ms": round(min(times), 1), "max_ms": round(max(times), 1), "iters": a.iters,
            "spp": a.spp, "integrator": a.integrator, "grads": a.grads, "crop": crop or "full",
            "image": [cam["width"], cam["height"]], "probe_height_px": round(height_px),
            "env": [W, H], "loss": float(np.array(loss).ravel()[0]),
            "grad_env_nonzero": int((g != 0).sum()), "grad_yaw": float(g_yaw[0]),
            "grad_t": [float(x[0]) for x in g_t],
            "mitsuba": mi.__version__, "drjit": dr.__version__})
        print(json.dumps(results[-1]), flush=True)


if __name__ == "__main__":
    main()

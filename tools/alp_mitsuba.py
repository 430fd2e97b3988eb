"""Shared helpers of the Mitsuba 3 reference tools (mitsuba_compare.py, mitsuba_timing.py,
mirror_sphere_reference.py): reading the project's files (shared/FORMATS.md), turning them into a
Mitsuba 3 scene, and a direct-lighting integrator that matches our forward model.

Nothing here is a CI dependency: it needs `pip install mitsuba==3.9.1 drjit==1.5.0` (and
libllvm19 for the LLVM variants, see README.md).
"""

import glob
import json
import os
import sys

import numpy as np

LLVM_GLOB = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19*"


def setup_variant(variant):
    """Import Mitsuba and select `variant`; for LLVM variants point Dr.Jit at libLLVM 19."""
    if variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        found = sorted(glob.glob(LLVM_GLOB))
        if found:
            os.environ["DRJIT_LIBLLVM_PATH"] = found[0]
        else:
            sys.exit("variant %s needs libLLVM 19: apt-get install -y libllvm19, or set "
                     "DRJIT_LIBLLVM_PATH to libLLVM.so.19.1 (LLVM 15 crashes)" % variant)
    import mitsuba as mi
    mi.set_variant(variant)
    return mi


# ---------------------------------------------------------------------------------------------
# Files (FORMATS.md)

def read_json(path):
    with open(path) as f:
        return json.load(f)


def read_exr(path):
    """Linear RGB image as float32 (H, W, 3)."""
    import mitsuba as mi
    b = mi.Bitmap(path)
    if b.channel_count() not in (3, 4):
        b = b.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, srgb_gamma=False)
    a = np.array(b.convert(component_format=mi.Struct.Type.Float32, srgb_gamma=False), dtype=np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    return np.ascontiguousarray(a[:, :, :3])


def write_exr(path, rgb):
    import mitsuba as mi
    mi.Bitmap(np.ascontiguousarray(rgb, dtype=np.float32), mi.Bitmap.PixelFormat.RGB).write(path)


def read_mask(path):
    """8-bit PNG mask -> bool (H, W): value > 127 marks the probe."""
    import mitsuba as mi
    a = np.array(mi.Bitmap(path))
    if a.ndim == 3:
        a = a[:, :, 0]
    return a > 127


def write_png(path, rgb8):
    import mitsuba as mi
    a = np.ascontiguousarray(rgb8, dtype=np.uint8)
    fmt = mi.Bitmap.PixelFormat.Y if a.ndim == 2 else mi.Bitmap.PixelFormat.RGB
    mi.Bitmap(a, fmt).write(path)


def tonemap(rgb, exposure):
    """Linear radiance -> 8-bit sRGB."""
    x = np.clip(rgb * exposure, 0.0, 1.0)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (x * 255 + 0.5).astype(np.uint8)


def load_camera(path):
    c = read_json(path)
    for k in ("width", "height", "fov_y_deg", "origin", "target", "up"):
        if k not in c:
            sys.exit("%s: missing field %r (FORMATS.md camera.json)" % (path, k))
    return c


def load_pose(path):
    m = np.array(read_json(path)["to_world"], dtype=np.float64)
    if m.shape != (4, 4):
        sys.exit("%s: to_world must be a 4x4 row-major matrix" % path)
    return m


def load_probe(folder):
    """probe.json -> dict(mesh=path, albedo=, roughness=, visibility=): each a constant list of
    3 floats / a float, or an (H, W, 3) array (row 0 = top = OBJ vt v = 1)."""
    meta = read_json(os.path.join(folder, "probe.json"))
    out = {"name": meta.get("name", os.path.basename(folder)),
           "mesh": os.path.join(folder, meta["mesh"])}
    for key, default in (("albedo", None), ("roughness", None), ("visibility", 1.0)):
        v = meta.get(key, default)
        if v is None:
            sys.exit("%s/probe.json: missing %r" % (folder, key))
        if isinstance(v, str):
            out[key] = read_exr(os.path.join(folder, v))
        elif isinstance(v, (int, float)):
            out[key] = float(v)
        else:
            v = [float(x) for x in v]
            out[key] = v if key == "albedo" else v[0]
    return out


def read_obj_positions(path):
    pts = []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                pts.append([float(x) for x in line.split()[1:4]])
    return np.array(pts, dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# Environment map: our rows -> Mitsuba's rows

def env_to_mitsuba(env):
    """Our lat-long map (H rows, texel centres at v = (i + 0.5) / H, bilinear, clamped in v)
    -> the map Mitsuba's `envmap` needs to give the SAME radiance in every direction.

    Mitsuba puts row k of an H'-row map at v = k / (H' - 1) and interpolates linearly between
    rows. Our lookup is piecewise linear in v with knots at (i + 0.5) / H and constant beyond
    the first/last knot. With H' = 2H + 1 Mitsuba's knots k / (2H) include all of ours, so
    sampling our lookup there reproduces it exactly (checked to 1e-6). Columns agree as they
    are (Mitsuba: u = (j + 0.5) / W, wrapping)."""
    h = env.shape[0]
    k = np.arange(2 * h + 1)
    c = np.clip(k / 2.0 - 0.5, 0, h - 1)
    i0 = np.floor(c).astype(int)
    i1 = np.minimum(i0 + 1, h - 1)
    f = (c - i0)[:, None, None]
    return ((1 - f) * env[i0] + f * env[i1]).astype(np.float32)


def env_lookup(env, d):
    """Our env map lookup (FORMATS.md) for unit directions d (..., 3) -> radiance (..., 3)."""
    h, w = env.shape[:2]
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    u = np.mod(np.arctan2(x, -z) / (2 * np.pi), 1.0)
    v = np.arccos(np.clip(y, -1, 1)) / np.pi
    cx = u * w - 0.5
    cy = np.clip(v * h - 0.5, 0, h - 1)
    j0 = np.floor(cx).astype(int)
    i0 = np.floor(cy).astype(int)
    fx = (cx - j0)[..., None]
    fy = (cy - i0)[..., None]
    i1 = np.minimum(i0 + 1, h - 1)
    j0w, j1w = np.mod(j0, w), np.mod(j0 + 1, w)
    top = (1 - fx) * env[i0, j0w] + fx * env[i0, j1w]
    bot = (1 - fx) * env[i1, j0w] + fx * env[i1, j1w]
    return (1 - fy) * top + fy * bot


# ---------------------------------------------------------------------------------------------
# Camera (FORMATS.md), independent of Mitsuba

def camera_basis(cam):
    o = np.array(cam["origin"], float)
    fwd = np.array(cam["target"], float) - o
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.array(cam["up"], float))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    return o, fwd, right, up


def camera_rays(cam, px, py):
    """Unit ray directions through image points (px = column coordinate, py = row coordinate,
    pixel (r, c) covers [c, c+1) x [r, r+1), row 0 at the top)."""
    o, fwd, right, up = camera_basis(cam)
    t = np.tan(np.radians(cam["fov_y_deg"]) / 2)
    w, h = cam["width"], cam["height"]
    sx = (2 * px / w - 1) * t * w / h
    sy = (1 - 2 * py / h) * t
    d = fwd + sx[..., None] * right + sy[..., None] * up
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def project(cam, pts):
    """World points (N, 3) -> (col, row) image coordinates; NaN behind the camera."""
    o, fwd, right, up = camera_basis(cam)
    t = np.tan(np.radians(cam["fov_y_deg"]) / 2)
    w, h = cam["width"], cam["height"]
    q = pts - o
    zc = q @ fwd
    with np.errstate(divide="ignore", invalid="ignore"):
        sx = (q @ right) / (zc * t * w / h)
        sy = (q @ up) / (zc * t)
    col = (sx + 1) * w / 2
    row = (1 - sy) * h / 2
    bad = zc <= 1e-9
    col[bad] = np.nan
    row[bad] = np.nan
    return col, row


def probe_bbox(cam, probe, pose, margin=2):
    """Pixel box [x0, x1) x [y0, y1) around the posed probe (whole image if behind the camera)."""
    p = read_obj_positions(probe["mesh"])
    pw = p @ pose[:3, :3].T + pose[:3, 3]
    col, row = project(cam, pw)
    w, h = cam["width"], cam["height"]
    if np.any(np.isnan(col)):
        return 0, 0, w, h
    x0 = int(max(0, np.floor(col.min()) - margin))
    y0 = int(max(0, np.floor(row.min()) - margin))
    x1 = int(min(w, np.ceil(col.max()) + margin))
    y1 = int(min(h, np.ceil(row.max()) + margin))
    if x1 <= x0 or y1 <= y0:
        sys.exit("the probe is outside the image")
    return x0, y0, x1, y1


# ---------------------------------------------------------------------------------------------
# Mitsuba scene

def _texture(mi, value, channels):
    """A constant or a bilinear, clamped `bitmap` texture (raw: no colour conversion). Mitsuba's
    OBJ loader flips vt v (uv.y = 1 - v) and its bitmap puts uv.y = 0 at row 0, so OBJ v = 0 is
    the bottom row as in FORMATS.md: no flip needed (checked on a textured quad)."""
    if isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value[:, :, :channels], dtype=np.float32)
        fmt = mi.Bitmap.PixelFormat.Y if channels == 1 else mi.Bitmap.PixelFormat.RGB
        return {"type": "bitmap", "bitmap": mi.Bitmap(a, fmt), "raw": True,
                "filter_type": "bilinear", "wrap_mode": "clamp"}
    if channels == 1:
        return float(value)
    return {"type": "rgb", "value": [float(x) for x in value]}


def _resize_bilinear(img, h, w):
    """Our texture lookup (bilinear, clamp, texel centres at +0.5) sampled on an h x w grid."""
    H, W = img.shape[:2]
    y = np.clip((np.arange(h) + 0.5) * H / h - 0.5, 0, H - 1)
    x = np.clip((np.arange(w) + 0.5) * W / w - 0.5, 0, W - 1)
    y0 = np.floor(y).astype(int); x0 = np.floor(x).astype(int)
    y1 = np.minimum(y0 + 1, H - 1); x1 = np.minimum(x0 + 1, W - 1)
    fy = (y - y0)[:, None, None]; fx = (x - x0)[None, :, None]
    return ((1 - fy) * ((1 - fx) * img[y0][:, x0] + fx * img[y0][:, x1])
            + fy * ((1 - fx) * img[y1][:, x0] + fx * img[y1][:, x1]))


def bsdf_dict(mi, probe, fold_visibility, white=False):
    """Our metal as a Mitsuba BSDF: `roughconductor` (GGX, alpha = r^2, `material: none` i.e.
    Fresnel = 1 times `specular_reflectance`), or a smooth `conductor` when r = 0 everywhere.
    `specular_reflectance` = albedo, times the visibility when `fold_visibility` (exact for
    constants; for textures the product is taken per texel, then interpolated)."""
    albedo = probe["albedo"]
    vis = probe["visibility"]
    if fold_visibility:
        if isinstance(albedo, np.ndarray) or isinstance(vis, np.ndarray):
            a = albedo if isinstance(albedo, np.ndarray) else np.ones((1, 1, 3)) * np.array(albedo)
            v = vis if isinstance(vis, np.ndarray) else np.full((1, 1, 3), vis)
            h = max(a.shape[0], v.shape[0]); w = max(a.shape[1], v.shape[1])
            if a.shape[:2] != (h, w):
                a = _resize_bilinear(a, h, w)
            if v.shape[:2] != (h, w):
                v = _resize_bilinear(v, h, w)
            albedo = a * v[:, :, :1]
        else:
            albedo = [x * vis for x in albedo]
    rough = probe["roughness"]
    refl = _texture(mi, [1.0, 1.0, 1.0] if white else albedo, 3)
    if not isinstance(rough, np.ndarray) and rough <= 0.0:
        return {"type": "conductor", "material": "none", "specular_reflectance": refl}
    if isinstance(rough, np.ndarray):
        alpha = np.maximum(rough[:, :, :1] ** 2, 1e-4)
    else:
        alpha = max(rough * rough, 1e-4)
    return {"type": "roughconductor", "distribution": "ggx", "material": "none",
            "alpha": _texture(mi, alpha, 1), "specular_reflectance": refl}


def sensor_dict(mi, cam, spp, crop=None, seed=0, sampler="independent", rfilter="box"):
    """Mitsuba's perspective sensor for our camera; `rfilter` is the film's reconstruction filter
    (ours is a box: a pixel is the mean over its square; Mitsuba's default is "gaussian")."""
    film = {"type": "hdrfilm", "width": int(cam["width"]), "height": int(cam["height"]),
            "rfilter": {"type": rfilter}, "pixel_format": "rgba",
            "component_format": "float32"}
    if crop is not None:
        x0, y0, x1, y1 = crop
        film.update({"crop_offset_x": x0, "crop_offset_y": y0,
                     "crop_width": x1 - x0, "crop_height": y1 - y0})
    return {"type": "perspective", "fov_axis": "y", "fov": float(cam["fov_y_deg"]),
            "near_clip": 1e-3, "far_clip": 1e4,
            "to_world": mi.ScalarTransform4f().look_at(origin=cam["origin"], target=cam["target"],
                                                       up=cam["up"]),
            "film": film,
            "sampler": {"type": sampler, "sample_count": int(spp), "seed": int(seed)}}


def scene_dict(mi, probe, pose, cam, env, spp, integrator, crop=None, seed=0, fold_visibility=True,
               white=False, rfilter="box"):
    """The whole scene. `env` is OUR map (H x W x 3); it is resampled to Mitsuba's rows."""
    return {
        "type": "scene",
        "integrator": integrator,
        "sensor": sensor_dict(mi, cam, spp, crop, seed, rfilter=rfilter),
        "probe": {"type": "obj", "filename": probe["mesh"], "face_normals": False,
                  "to_world": mi.ScalarTransform4f(pose.tolist()),
                  "bsdf": bsdf_dict(mi, probe, fold_visibility, white)},
        "env": {"type": "envmap", "bitmap": mi.Bitmap(env_to_mitsuba(env), mi.Bitmap.PixelFormat.RGB)},
    }


def make_direct_integrator(mi, albedo_texture=None, visibility_texture=None, bounce=True):
    """Our forward model as a Mitsuba integrator: at the first hit, direct lighting from the
    environment with shadow rays (the probe shadows itself), and with `bounce` (our
    `render_image`) one bounce of inter-reflection: a BSDF sample the probe blocks goes on from
    the point it hits with one BSDF sample there, shadowed in turn (no MIS weight on the first:
    no emitter sample reaches that light); times the visibility texture at each hit; primary
    rays that miss are black. Estimator: one emitter sample + one BSDF sample combined by MIS
    (balance heuristic); it converges to the same integral as our BSDF-only estimator.

    With `albedo_texture` the scene's BSDF must have specular_reflectance 1 (`material: none`,
    i.e. F = 1) and this integrator multiplies each sample by Schlick's
    F = A + (1 - A)(1 - |h.wi|)^5 with A = albedo at the hit (h from the sampled pair): that is
    exactly our BRDF. Without it Mitsuba's F = specular_reflectance is kept."""
    import drjit as dr

    def schlick(a, wi, wo):
        h = dr.normalize(wi + wo)
        c = dr.abs(dr.dot(h, wi))
        return a + (1.0 - a) * dr.power(dr.maximum(1.0 - c, 0.0), 5)

    class Direct(mi.SamplingIntegrator):
        def __init__(self, props=mi.Properties()):
            super().__init__(props)
            self.albedo = albedo_texture
            self.vis = visibility_texture
            self.bounce = bounce

        def sample(self, scene, sampler, ray, medium=None, active=True):
            si = scene.ray_intersect(ray, active)
            valid = si.is_valid() & active
            bsdf = si.bsdf(ray)
            ctx = mi.BSDFContext()
            env = scene.environment()
            result = mi.Spectrum(0.0)
            a = self.albedo.eval(si, valid) if self.albedo is not None else None

            # Emitter sampling, with a shadow ray.
            ds, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(valid), True, valid)
            wo = si.to_local(ds.d)
            bval, bpdf = bsdf.eval_pdf(ctx, si, wo, valid)
            w_em = dr.select(ds.delta, 1.0, ds.pdf / (ds.pdf + bpdf))
            c_em = em_weight * bval * w_em
            if a is not None:
                c_em *= schlick(a, si.wi, wo)
            result += dr.select(valid & (ds.pdf > 0), c_em, 0.0)

            # BSDF sampling; the environment is looked up in the sampled direction unless the
            # probe is in the way.
            bs, bweight = bsdf.sample(ctx, si, sampler.next_1d(valid), sampler.next_2d(valid), valid)
            d = si.to_world(bs.wo)
            lit = valid & ~scene.ray_test(si.spawn_ray(d), valid)
            if a is not None:
                bweight *= schlick(a, si.wi, bs.wo)
            sie = dr.zeros(mi.SurfaceInteraction3f)
            sie.wi = -d
            sie.wavelengths = si.wavelengths
            le = env.eval(sie, valid)
            dse = dr.zeros(mi.DirectionSample3f)
            dse.d = d
            epdf = env.pdf_direction(si, dse, valid)
            delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            w_bs = dr.select(delta, 1.0, bs.pdf / (bs.pdf + epdf))
            c_bs = bweight * le * w_bs
            result += dr.select(lit & (bs.pdf > 0), c_bs, 0.0)

            if self.bounce:
                # The blocked BSDF sample goes on from the probe point it hits.
                blocked = valid & ~lit & (bs.pdf > 0)
                si2 = scene.ray_intersect(si.spawn_ray(d), blocked)
                blocked &= si2.is_valid()
                bsdf2 = si2.bsdf()
                bs2, bweight2 = bsdf2.sample(ctx, si2, sampler.next_1d(blocked), sampler.next_2d(blocked),
                                             blocked)
                d2 = si2.to_world(bs2.wo)
                lit2 = blocked & (bs2.pdf > 0) & ~scene.ray_test(si2.spawn_ray(d2), blocked)
                sie2 = dr.zeros(mi.SurfaceInteraction3f)
                sie2.wi = -d2
                sie2.wavelengths = si.wavelengths
                c_2 = bweight * bweight2 * env.eval(sie2, lit2)
                if self.albedo is not None:
                    c_2 *= schlick(self.albedo.eval(si2, lit2), si2.wi, bs2.wo)
                if self.vis is not None:
                    c_2 *= self.vis.eval_1(si2, lit2)
                result += dr.select(lit2, c_2, 0.0)

            if self.vis is not None:
                result *= self.vis.eval_1(si, valid)
            return dr.select(valid, result, 0.0), valid, []

        def aov_names(self):
            return []

        def to_string(self):
            return "Direct[]"

    return Direct()

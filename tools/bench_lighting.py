"""Environment maps of the development benchmark (tools/bench_scenes.py), each drawn at random
from a generator `rng` (numpy) as a W x H equirectangular map in shared/FORMATS.md's convention:

    real     a real map (the bundled three in assets/envmaps, the others of tools/real_maps.py),
             turned about the vertical, perhaps mirrored, white-balanced and exposed at random
    sky      Mitsuba 3's `sunsky` emitter (Hosek-Wilkie sky and sun) at a random sun position
             and turbidity, baked texel by texel (supersampled where the sun is), above a ground
             and a skyline of buildings lit by that sky
    room     a box room seen from a table: painted walls with pictures and doors, a floor of
             boards, a ceiling, windows (bright, bluish) and lamps (small, very bright, warm)

Every map is linear radiance; the sun of a sky reaches ~1e4, so maps are float32 EXR.
"""

import math

import numpy as np

W, H = 512, 256


def directions(w, h, sub=1, texels=None):
    """Unit directions of a sub x sub grid in each texel of a w x h map (FORMATS.md: u =
    atan2(x, -z) / 2 pi, v = acos(y) / pi, row 0 up): (h, w, sub*sub, 3), or (n, sub*sub, 3)
    for the n texels (rows, cols) of `texels`."""
    k = (np.arange(sub) + 0.5) / sub
    ju, jv = (g.reshape(1, -1) for g in np.meshgrid(k, k))
    if texels is None:
        rows, cols = np.mgrid[0:h, 0:w]
    else:
        rows, cols = texels
    u = (cols[..., None] + ju) / w
    v = (rows[..., None] + jv) / h
    theta, phi = v * math.pi, u * 2 * math.pi
    return np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], axis=-1)


def _box_downsample(img, h, w):
    """The mean of each block when the size divides evenly (keeps small lights' energy),
    else nearest texel centres."""
    hh, ww = img.shape[:2]
    if hh % h == 0 and ww % w == 0:
        return img.reshape(h, hh // h, w, ww // w, 3).mean(axis=(1, 3))
    rows = ((np.arange(h) + 0.5) * hh / h).astype(int)
    cols = ((np.arange(w) + 0.5) * ww / w).astype(int)
    return img[rows][:, cols]


def real(rng, source):
    """A real map (H x W x 3 array) turned, perhaps mirrored, white-balanced and exposed."""
    img = _box_downsample(source, H, W) if source.shape[:2] != (H, W) else source.copy()
    img = np.roll(img, int(rng.integers(0, W)), axis=1)
    mirrored = bool(rng.random() < 0.5)
    if mirrored:
        img = img[:, ::-1]
    gains = np.exp(rng.normal(0.0, 0.12, 3))
    gains /= gains.mean()
    exposure = math.exp(rng.uniform(math.log(0.5), math.log(2.0)))
    return np.ascontiguousarray(img * gains * exposure), {"mirrored": mirrored,
                                                          "white_balance": [round(float(g), 3) for g in gains]}


def _to_mitsuba(d):
    """Our +Y-up directions in Mitsuba's sunsky frame (+Z up): a proper rotation."""
    return np.stack([d[..., 0], -d[..., 2], d[..., 1]], axis=-1)


def _eval_emitter(mi, emitter, d):
    import drjit as dr
    flat = _to_mitsuba(d).reshape(-1, 3)
    si = dr.zeros(mi.SurfaceInteraction3f, flat.shape[0])
    si.wi = -mi.Vector3f(flat[:, 0], flat[:, 1], flat[:, 2])
    return np.array(emitter.eval(si), dtype=np.float64).T.reshape(d.shape)  # Dr.Jit gives (3, n)


def _value_noise(rng, shape, cells):
    """Smooth noise in [0, 1): bilinear upsampling of a random grid."""
    g = rng.random((cells[0] + 1, cells[1] + 1))
    y = np.linspace(0, cells[0], shape[0], endpoint=False)
    x = np.linspace(0, cells[1], shape[1], endpoint=False)
    y0, x0 = y.astype(int), x.astype(int)
    fy, fx = (y - y0)[:, None], (x - x0)[None, :]
    return ((1 - fy) * ((1 - fx) * g[y0][:, x0] + fx * g[y0][:, x0 + 1])
            + fy * ((1 - fx) * g[y0 + 1][:, x0] + fx * g[y0 + 1][:, x0 + 1]))


def sky(rng, mi):
    """A baked `sunsky` map over a ground and a skyline, and its parameters."""
    elevation = rng.uniform(5.0, 70.0)
    azimuth = rng.uniform(0.0, 360.0)
    turbidity = rng.uniform(2.0, 8.0)
    e, a = math.radians(elevation), math.radians(azimuth)
    sun = np.array([math.cos(e) * math.sin(a), math.sin(e), -math.cos(e) * math.cos(a)])
    emitter = mi.load_dict({"type": "sunsky", "sun_direction": _to_mitsuba(sun).tolist(),
                            "turbidity": float(turbidity), "albedo": 0.2})
    img = _eval_emitter(mi, emitter, directions(W, H, 2)).mean(axis=2)
    # The sun covers about half a degree: texels within 2 degrees of it get 32 x 32 samples.
    centre = directions(W, H)[:, :, 0]
    near = np.nonzero(centre @ sun > math.cos(math.radians(2.0)))
    if near[0].size:
        fine = directions(W, H, 32, near)
        img[near] = _eval_emitter(mi, emitter, fine).mean(axis=1)
    # The ground and a skyline reflect the sky's light on the horizontal: E / pi x albedo.
    up = centre[:, :, 1]
    solid = (2 * math.pi / W) * (math.pi / H) * np.sin((np.arange(H) + 0.5) / H * math.pi)[:, None]
    irradiance = (img * (np.maximum(up, 0.0) * solid)[:, :, None]).sum(axis=(0, 1))
    ground_albedo = rng.uniform(0.08, 0.3) * np.exp(rng.normal(0, 0.2, 3))
    texture = 0.7 + 0.6 * _value_noise(rng, (H, W), (8, 32))[:, :, None]
    below = up < 0
    img[below] = (irradiance / math.pi * ground_albedo * texture)[below]
    skyline = np.zeros(W)
    col = 0
    while col < W:  # blocks of buildings or trees, some gaps
        width = int(rng.integers(6, 60))
        if rng.random() < 0.6:
            skyline[col:col + width] = rng.uniform(2.0, 18.0)
        col += width
    elev = 90.0 - (np.arange(H) + 0.5) / H * 180.0
    blocked = (elev[:, None] >= 0) & (elev[:, None] < skyline[None, :])
    facade = rng.uniform(0.1, 0.4) * np.exp(rng.normal(0, 0.15, 3))
    lit = 0.4 + 0.6 * np.clip(np.cos(np.arange(W) / W * 2 * math.pi - a), 0, 1)  # facing the sun
    shade = (irradiance / math.pi * facade)[None, None, :] * lit[None, :, None] * texture
    img[blocked] = shade[blocked]
    return img.astype(np.float32), {"sun_elevation_deg": round(elevation, 1),
                                    "sun_azimuth_deg": round(azimuth, 1), "turbidity": round(turbidity, 2)}


def room(rng):
    """A box room around a point at table height: its map and parameters."""
    half = np.array([rng.uniform(1.5, 4.0), 0.0, rng.uniform(1.5, 4.0)])
    floor, ceiling = -rng.uniform(0.7, 1.0), rng.uniform(1.4, 2.6)
    lo = np.array([-half[0], floor, -half[2]]) * np.array([rng.uniform(0.3, 1.0), 1, rng.uniform(0.3, 1.0)])
    hi = np.array([half[0], ceiling, half[2]])
    walls = np.exp(rng.normal(0, 0.25, 3)) * rng.uniform(0.35, 0.75)
    boards = np.array([0.35, 0.22, 0.12]) * rng.uniform(0.5, 1.5)
    # Windows on walls (face index, centre along the wall, centre height, half width, half
    # height) and lamps (position, radius) near the ceiling.
    windows = [(int(rng.integers(0, 4)), rng.uniform(-0.6, 0.6), rng.uniform(0.3, 1.2),
                rng.uniform(0.3, 1.0), rng.uniform(0.4, 0.8)) for _ in range(rng.integers(0, 3))]
    window_light = np.array([0.85, 0.95, 1.15]) * rng.uniform(3.0, 30.0)
    lamps = [(np.array([rng.uniform(lo[0], hi[0]) * 0.8, ceiling - 0.05, rng.uniform(lo[2], hi[2]) * 0.8]),
              rng.uniform(0.05, 0.2)) for _ in range(rng.integers(1 if not windows else 0, 5))]
    lamp_light = np.array([1.0, 0.85, 0.6]) * rng.uniform(50.0, 600.0)
    decor = [(int(rng.integers(0, 4)), rng.uniform(-0.8, 0.8), rng.uniform(0.0, 1.4), rng.uniform(0.15, 0.6),
              rng.uniform(0.15, 0.9), np.clip(rng.random(3), 0.05, 0.9)) for _ in range(rng.integers(3, 9))]

    d = directions(W, H, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_hi, t_lo = hi / d, lo / d
    t = np.where(d > 0, t_hi, t_lo)
    t = np.where(np.isfinite(t) & (t > 0), t, np.inf)
    axis = np.argmin(t, axis=-1)
    p = d * np.min(t, axis=-1)[..., None]
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    # Walls 0..3: +x, -x, +z, -z; s runs along the wall in [-1, 1].
    wall = np.where(axis == 0, np.where(d[..., 0] > 0, 0, 1), np.where(d[..., 2] > 0, 2, 3))
    s = np.where(axis == 0, z / np.where(z > 0, hi[2], -lo[2]), x / np.where(x > 0, hi[0], -lo[0]))
    albedo = np.broadcast_to(walls, d.shape).copy()
    on_wall = axis != 1
    for face, c, cy, hw, hh, colour in decor:
        m = on_wall & (wall == face) & (np.abs(s - c) < hw) & (np.abs(y - cy) < hh)
        albedo[m] = colour
    is_floor, is_ceiling = (axis == 1) & (d[..., 1] < 0), (axis == 1) & (d[..., 1] > 0)
    plank = 0.75 + 0.5 * ((np.floor(x / 0.15) * 7919) % 13) / 13
    albedo[is_floor] = (boards * plank[..., None])[is_floor]
    albedo[is_ceiling] = 0.8
    # Light on a surface: ambient plus each lamp's and window's inverse-square share.
    normal = np.zeros_like(p)
    np.put_along_axis(normal, axis[..., None], -np.sign(np.take_along_axis(d, axis[..., None], -1)), -1)
    irradiance = np.full(d.shape, 0.3 * rng.uniform(0.5, 2.0))
    sources = [(q, math.pi * r * r * lamp_light) for q, r in lamps]
    for face, c, cy, hw, hh in windows:
        centre = _wall_point(face, c, cy, lo, hi)
        sources.append((centre, 4 * hw * hh * window_light))
    for q, power in sources:
        v = q - p
        r2 = np.maximum((v * v).sum(-1), 0.05)
        cos = np.clip((v * normal).sum(-1) / np.sqrt(r2), 0, 1)
        irradiance += power[None, None, None, :] * (cos / r2)[..., None] / math.pi
    radiance = albedo * irradiance / math.pi
    for face, c, cy, hw, hh in windows:
        m = on_wall & (wall == face) & (np.abs(s - c) < hw) & (np.abs(y - cy) < hh)
        bars = (np.abs(s - c) < 0.02 * hw / 0.5) | (np.abs(y - cy) < 0.02)
        radiance[m & ~bars] = window_light
    for q, r in lamps:
        m = is_ceiling & ((x - q[0]) ** 2 + (z - q[2]) ** 2 < r * r)
        radiance[m] = lamp_light
    img = radiance.mean(axis=2)
    return img.astype(np.float32), {"windows": len(windows), "lamps": len(lamps)}


def _wall_point(face, c, cy, lo, hi):
    """The point at position c in [-1, 1] along wall `face` and height cy."""
    if face in (0, 1):
        return np.array([hi[0] if face == 0 else lo[0], cy, c * (hi[2] if c > 0 else -lo[2])])
    return np.array([c * (hi[0] if c > 0 else -lo[0]), cy, hi[2] if face == 2 else lo[2]])

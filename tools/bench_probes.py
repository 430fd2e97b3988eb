"""Procedural probes of the development benchmark (tools/bench_scenes.py): surfaces of revolution
drawn at random per scene, written as probe folders (shared/FORMATS.md) that our code never made.

Families, each from a random generator `rng` (numpy):

    can     a drinks can: concave base, necked top with a rim round a recessed lid; a label of
            a random design (bands, stripes, logos and text all round) in a saturated or metallic
            colour
    cap     a cap or lid, squat to tall (height / diameter 0.25 to 1.2), often with grooves
            round its side and a recessed top; one metal, two roughnesses (side, top)
    bottle  a metal bottle: body, shoulder, neck, lip; half of them with a label
    sphere  a ball bearing or ornament: one metal
    ring    a torus (finger ring): one metal

The axis of revolution is mesh +Y. `orientation` says what a photo can tell of the pose:
"full" (a label breaks the symmetry), "axis" (symmetric about +Y: the axis direction only),
"line" (also symmetric end for end: the axis line only), "none" (a sphere).
Meshes hold 5k to 40k triangles, with `vt` (u round the axis, v along the profile's arc
length) and smooth `vn` (the seam welded). Textures are RGB OpenEXR (row 0 = vt v = 1).
"""

import json
import math
import os

import numpy as np

TEX = 512  # texture side, texels

# Albedo F0 of the label and metal colours the issue names (linear RGB).
COLOURS = {
    "red": (0.75, 0.10, 0.10),
    "blue": (0.10, 0.22, 0.75),
    "green": (0.12, 0.60, 0.18),
    "gold": (0.90, 0.68, 0.30),
    "silver": (0.90, 0.90, 0.90),
}
METALS = ("silver", "gold", "silver", "red", "blue")  # caps, bottles, rings: mostly plain metal


def _jitter(rng, rgb, amount=0.06):
    return np.clip(np.array(rgb) * (1.0 + amount * rng.standard_normal(3)), 0.02, 0.98)


def _rough(rng, lo=0.03, hi=0.4):
    """A roughness drawn log-uniformly in [lo, hi]."""
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


# ------------------------------------------------------------------------------- profiles

def _fillet_polyline(points, radius, per_arc=6):
    """Rounds each interior corner of the (r, y) polyline by a circular arc of `radius` (smaller
    where a segment is short), so that smooth vertex normals are right at the rims."""
    pts = [np.array(p, dtype=float) for p in points]
    out = [pts[0]]
    for a, b, c in zip(pts[:-2], pts[1:-1], pts[2:]):
        d1, d2 = b - a, c - b
        l1, l2 = np.linalg.norm(d1), np.linalg.norm(d2)
        if l1 < 1e-12 or l2 < 1e-12:
            continue
        d1, d2 = d1 / l1, d2 / l2
        turn = math.acos(np.clip(np.dot(d1, d2), -1.0, 1.0))
        if turn < 1e-3:
            out.append(b)
            continue
        t = min(radius * math.tan(turn / 2), 0.45 * l1, 0.45 * l2)
        p0, p1 = b - d1 * t, b + d2 * t
        for k in range(per_arc + 1):  # a quadratic Bezier through the corner: close to an arc
            s = k / per_arc
            out.append((1 - s) ** 2 * p0 + 2 * s * (1 - s) * b + s * s * p1)
    out.append(pts[-1])
    return np.array(out)


def _resample(profile, n):
    """n points evenly spaced in arc length along the polyline, and their arc-length fraction."""
    seg = np.linalg.norm(np.diff(profile, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.linspace(0.0, s[-1], n)
    r = np.interp(t, s, profile[:, 0])
    y = np.interp(t, s, profile[:, 1])
    return np.stack([r, y], axis=1), t / s[-1]


def revolve(profile, triangles, groove=None):
    """The surface of revolution of an (r, y) profile with about `triangles` triangles.

    groove: (count, depth, y0, y1) grooves cut round the side between heights y0 and y1
    (radius times 1 - depth * (0.5 + 0.5 cos(count phi))); a closed loop makes a torus. Returns (positions, uvs, normals, faces) with the seam's vertices duplicated."""
    n_u = int(np.clip(math.sqrt(triangles / 2.0) * 1.6, 24, 400))
    if groove is not None:
        n_u = max(n_u, 8 * groove[0])
    n_v = max(8, int(triangles / (2 * n_u)))
    pts, v = _resample(profile, n_v)
    phi = np.linspace(0.0, 2 * math.pi, n_u + 1)
    r = pts[:, 0][:, None] * np.ones_like(phi)[None, :]
    if groove is not None:
        count, depth, y0, y1 = groove
        inside = ((pts[:, 1] > y0) & (pts[:, 1] < y1)).astype(float)[:, None]
        r = r * (1.0 - inside * depth * (0.5 + 0.5 * np.cos(count * phi))[None, :])
    pos = np.stack([r * np.sin(phi)[None, :], pts[:, 1][:, None] * np.ones_like(phi)[None, :],
                    r * np.cos(phi)[None, :]], axis=2)  # (n_v, n_u + 1, 3)
    uv = np.stack([np.broadcast_to(phi / (2 * math.pi), (n_v, n_u + 1)),
                   np.broadcast_to(1.0 - v[:, None], (n_v, n_u + 1))], axis=2)
    idx = np.arange(n_v * (n_u + 1)).reshape(n_v, n_u + 1)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([b, d, c], -1).reshape(-1, 3)])
    p = pos.reshape(-1, 3)
    # Drop the faces that collapse on the axis (r = 0 at both ends of a profile). A profile
    # that keeps the solid on its left (up the outside, inward over the top) gives outward
    # faces; vertex normals are area-weighted, welded across the seam and the poles.
    fn = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])
    kept = np.linalg.norm(fn, axis=1) > 1e-14
    faces, fn = faces[kept], fn[kept]
    key = np.round(p / 1e-9).astype(np.int64)
    _, weld = np.unique(key, axis=0, return_inverse=True)
    weld = weld.reshape(-1)
    acc = np.zeros((weld.max() + 1, 3))
    for k in range(3):
        np.add.at(acc, weld[faces[:, k]], fn)
    n = acc[weld]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
    return p, uv.reshape(-1, 2), n, faces


def write_obj(path, p, uv, n, faces):
    with open(path, "w") as f:
        f.write("# procedural probe of tools/bench_probes.py\n")
        f.write("".join("v %.7g %.7g %.7g\n" % tuple(x) for x in p))
        f.write("".join("vt %.7g %.7g\n" % tuple(x) for x in uv))
        f.write("".join("vn %.6g %.6g %.6g\n" % tuple(x) for x in n))
        f.write("".join("f %d/%d/%d %d/%d/%d %d/%d/%d\n" % (a, a, a, b, b, b, c, c, c)
                        for a, b, c in faces + 1))


# ------------------------------------------------------------------------------- families

def _label(rng, colour):
    """A label's albedo and roughness (TEX x TEX over the label's u, v range): a base colour,
    bands and thin silver stripes round the can, logos and lines of text at random places."""
    base = _jitter(rng, COLOURS[colour])
    r_base = _rough(rng, 0.08, 0.4)
    alb = np.broadcast_to(base, (TEX, TEX, 3)).copy()
    rough = np.full((TEX, TEX), r_base)
    vv, uu = np.mgrid[0:TEX, 0:TEX] / TEX
    silver, r_silver = _jitter(rng, COLOURS["silver"], 0.03), _rough(rng, 0.03, 0.15)
    for _ in range(rng.integers(0, 5)):  # thin stripes or wide bands
        c = rng.uniform(0.05, 0.95)
        w = rng.uniform(0.005, 0.03) if rng.random() < 0.6 else rng.uniform(0.05, 0.15)
        m = np.abs(vv - c) < w / 2
        second = rng.random() < 0.5
        alb[m] = silver if second else _jitter(rng, COLOURS[rng.choice(list(COLOURS))])
        rough[m] = r_silver if second else _rough(rng, 0.05, 0.4)
    # Logos and lines of text all round the can, of other colours: from any side the photo shows
    # some, which tell the turn about the axis.
    others = [k for k in COLOURS if k != colour]
    for _ in range(rng.integers(3, 7)):
        u0, v0 = rng.uniform(0, 1), rng.uniform(0.2, 0.8)
        hu, hv = rng.uniform(0.03, 0.1), rng.uniform(0.08, 0.25)
        du = (uu - u0 + 0.5) % 1.0 - 0.5
        if rng.random() < 0.5:
            m = (du / hu) ** 2 + ((vv - v0) / hv) ** 2 < 1
        else:
            m = (np.abs(du) < hu) & (np.abs(vv - v0) < hv)
        alb[m] = _jitter(rng, COLOURS[rng.choice(others)])
        rough[m] = _rough(rng, 0.03, 0.3)
    text = _jitter(rng, COLOURS[rng.choice(others)])
    for _ in range(rng.integers(8, 30)):
        u0, v0 = rng.uniform(0, 1), rng.uniform(0.05, 0.95)
        m = (np.abs((uu - u0 + 0.5) % 1.0 - 0.5) < rng.uniform(0.01, 0.05)) & (np.abs(vv - v0) < rng.uniform(0.004, 0.015))
        alb[m] = text
    return alb, rough


def _paint(regions):
    """Albedo and roughness textures from regions along the profile: a list of (v0, v1, albedo,
    roughness) over the profile's arc-length fraction v (0 = first profile point), where albedo
    and roughness are constants or (TEX x TEX) arrays spanning [v0, v1]. Later regions win."""
    alb = np.zeros((TEX, TEX, 3))
    rough = np.zeros((TEX, TEX))
    # Texture row k holds vt v = 1 - (k + 0.5) / rows, i.e. profile fraction (k + 0.5) / rows.
    frac = (np.arange(TEX) + 0.5) / TEX
    for v0, v1, a, r in regions:
        rows = np.nonzero((frac >= v0) & (frac <= v1))[0]
        if rows.size == 0:
            continue
        if isinstance(a, np.ndarray) and a.ndim == 3:
            src = np.clip(((frac[rows] - v0) / max(v1 - v0, 1e-9) * a.shape[0]).astype(int), 0, a.shape[0] - 1)
            alb[rows] = a[src]
            rough[rows] = r[src]
        else:
            alb[rows] = a
            rough[rows] = r
    return alb, rough


def _profile_fraction(profile, y_at):
    """Arc-length fraction of the profile where it first reaches height y_at."""
    dense, frac = _resample(profile, 20000)
    return float(frac[int(np.argmax(dense[:, 1] >= y_at))])


def can(rng, triangles):
    R = rng.uniform(0.026, 0.034)
    H = R * rng.uniform(1.5, 2.0) * 2
    neck = R * rng.uniform(0.80, 0.88)
    recess = rng.uniform(0.004, 0.008)
    prof = _fillet_polyline([(0, 0.008), (0.75 * R, 0.008), (0.82 * R, 0.0), (R, 0.08 * H), (R, 0.88 * H),
                             (neck, H - 0.002), (neck, H + 0.002), (neck - 0.002, H + 0.002),
                             (neck - 0.003, H + 0.002 - recess), (0, H + 0.002 - recess)], 0.003)
    colour = rng.choice(list(COLOURS))
    v0, v1 = _profile_fraction(prof, 0.1 * H), _profile_fraction(prof, 0.86 * H)
    end = (_jitter(rng, COLOURS["silver"], 0.02), _rough(rng, 0.1, 0.3))
    lab = _label(rng, colour)
    alb, rough = _paint([(0, 1, end[0], end[1]), (v0, v1, lab[0], lab[1])])
    return prof, None, alb, rough, "full", {"label": str(colour), "diameter_mm": round(2000 * R, 1),
                                            "height_mm": round(1000 * H, 1)}


def cap(rng, triangles):
    R = rng.uniform(0.015, 0.04)
    H = 2 * R * rng.uniform(0.25, 1.2)
    depth = H * rng.uniform(0.04, 0.2) if rng.random() < 0.7 else 0.0
    lip = R * rng.uniform(0.05, 0.12)
    prof = _fillet_polyline([(0, 0), (R, 0), (R, H), (R - lip, H), (R - lip, H - depth), (0, H - depth)],
                            min(0.002, 0.2 * H))
    grooves = None
    if rng.random() < 0.7:
        grooves = (int(rng.integers(24, 90)), rng.uniform(0.01, 0.03), 0.12 * H, 0.9 * H)
    metal = rng.choice(METALS)
    colour = _jitter(rng, COLOURS[metal])
    side, top = _rough(rng), _rough(rng)
    vt = _profile_fraction(prof, H * 0.999)
    alb, rough = _paint([(0, 1, colour, side), (vt, 1, colour, top)])
    return prof, grooves, alb, rough, "axis", {"metal": str(metal), "diameter_mm": round(2000 * R, 1),
                                               "height_mm": round(1000 * H, 1), "grooves": 0 if grooves is None else grooves[0],
                                               "recess_mm": round(1000 * depth, 1)}


def bottle(rng, triangles):
    R = rng.uniform(0.025, 0.04)
    body = R * rng.uniform(2.5, 4.0)
    shoulder = R * rng.uniform(0.6, 1.2)
    rn = R * rng.uniform(0.3, 0.45)
    neck = R * rng.uniform(0.5, 1.2)
    shoulder_pts = [(rn + (R - rn) * (0.5 + 0.5 * math.cos(math.pi * t)), body + shoulder * t)
                    for t in np.linspace(0, 1, 12)]
    prof = _fillet_polyline([(0, 0.004), (0.8 * R, 0.004), (0.9 * R, 0.0), (R, 0.04 * body)] + shoulder_pts
                            + [(rn, body + shoulder + neck), (rn * 1.15, body + shoulder + neck),
                               (rn * 1.15, body + shoulder + neck + 0.004), (0, body + shoulder + neck + 0.004)],
                            0.003)
    metal = rng.choice(METALS)
    regions = [(0, 1, _jitter(rng, COLOURS[metal]), _rough(rng))]
    orientation = "axis"
    info = {"metal": str(metal), "diameter_mm": round(2000 * R, 1),
            "height_mm": round(1000 * (body + shoulder + neck), 1)}
    if rng.random() < 0.5:
        colour = rng.choice(list(COLOURS))
        lab = _label(rng, colour)
        regions.append((_profile_fraction(prof, 0.2 * body), _profile_fraction(prof, 0.8 * body), lab[0], lab[1]))
        orientation = "full"
        info["label"] = str(colour)
    alb, rough = _paint(regions)
    return prof, None, alb, rough, orientation, info


def sphere(rng, triangles):
    R = rng.uniform(0.015, 0.05)
    prof = np.array([(R * math.sin(t), -R * math.cos(t)) for t in np.linspace(0, math.pi, 200)])
    metal = rng.choice(METALS)
    alb, rough = _paint([(0, 1, _jitter(rng, COLOURS[metal]), _rough(rng, 0.03, 0.3))])
    return prof, None, alb, rough, "none", {"metal": str(metal), "diameter_mm": round(2000 * R, 1)}


def ring(rng, triangles):
    Rm = rng.uniform(0.009, 0.012)
    w = rng.uniform(0.0015, 0.004)  # half the band's width along the axis
    t = rng.uniform(0.0008, 0.0018)  # half its thickness
    # A band's cross-section: a rounded rectangle (a comfort-fit ring), anticlockwise in (r, y).
    loop = [(Rm + t * math.copysign(abs(math.cos(a)) ** 0.5, math.cos(a)),
             w * math.copysign(abs(math.sin(a)) ** 0.5, math.sin(a))) for a in np.linspace(-math.pi, math.pi, 160)]
    prof = np.array(loop)
    metal = rng.choice(("gold", "silver", "gold"))
    alb, rough = _paint([(0, 1, _jitter(rng, COLOURS[metal]), _rough(rng, 0.03, 0.2))])
    return prof, None, alb, rough, "line", {"metal": str(metal), "diameter_mm": round(2000 * (Rm + t), 1)}


FAMILIES = {"can": can, "cap": cap, "bottle": bottle, "sphere": sphere, "ring": ring}


def make_probe(family, rng, folder, write_exr):
    """Draws a probe of `family`, writes its folder (probe.json, mesh.obj, albedo.exr,
    roughness.exr) and returns its description for scene.json."""
    triangles = int(math.exp(rng.uniform(math.log(5000), math.log(40000))))
    prof, groove, alb, rough, orientation, info = FAMILIES[family](rng, triangles)
    p, uv, n, faces = revolve(np.asarray(prof, dtype=float), triangles, groove)
    os.makedirs(folder, exist_ok=True)
    write_obj(os.path.join(folder, "mesh.obj"), p, uv, n, faces)
    write_exr(os.path.join(folder, "albedo.exr"), alb)
    write_exr(os.path.join(folder, "roughness.exr"), np.repeat(rough[:, :, None], 3, axis=2))
    with open(os.path.join(folder, "probe.json"), "w") as f:
        json.dump({"name": family, "mesh": "mesh.obj", "albedo": "albedo.exr", "roughness": "roughness.exr"}, f)
    lo, hi = p.min(axis=0), p.max(axis=0)
    return dict(info, family=family, orientation=orientation, triangles=int(len(faces)),
                roughness_range=[round(float(rough.min()), 3), round(float(rough.max()), 3)],
                extent_m=[round(float(x), 4) for x in hi - lo], centre_m=[round(float(x), 4) for x in (hi + lo) / 2])

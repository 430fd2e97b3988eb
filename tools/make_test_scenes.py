#!/usr/bin/env python3
"""Write the poses and the camera of the comparison test cases (no rendering, no Mitsuba):

    python3 make_test_scenes.py --out-dir DIR

writes DIR/camera.json (640 x 480, FORMATS.md's example camera: probes come out 150-200 px tall)
and DIR/pose_{can,cap,sphere}.json: each probe's mesh-frame centre moved to the camera target,
turned about its axis and tilted towards the camera (so that wrong row / column / uv / handedness
conventions show), e.g. can: T(target) Rx(8 deg) Ry(25 deg) T(-centre).
"""

import argparse
import json
import os

import numpy as np


def rot_x(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])


def rot_y(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1]])


def trans(t):
    m = np.eye(4)
    m[:3, 3] = t
    return m


# (mesh-frame centre, tilt about x (deg), turn about y (deg)) of `alp probe make` probes
CASES = {
    "can": ([0.0, 0.061, 0.0], 8.0, 25.0),
    "cap": ([0.0, 0.025, 0.0], 25.0, 40.0),
    "sphere": ([0.0, 0.0, 0.0], 0.0, 30.0),
}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out-dir", required=True)
    a = ap.parse_args()
    os.makedirs(a.out_dir, exist_ok=True)
    target = [0.0, 0.06, 0.0]
    cam = {"width": 640, "height": 480, "fov_y_deg": 40.0,
           "origin": [0.0, 0.1, 0.5], "target": target, "up": [0.0, 1.0, 0.0]}
    with open(os.path.join(a.out_dir, "camera.json"), "w") as f:
        json.dump(cam, f, indent=1)
    for name, (centre, tilt, turn) in CASES.items():
        m = trans(target) @ rot_x(tilt) @ rot_y(turn) @ trans(-np.array(centre))
        with open(os.path.join(a.out_dir, "pose_%s.json" % name), "w") as f:
            json.dump({"to_world": [[round(x, 9) for x in row] for row in m.tolist()]}, f, indent=1)
    print(json.dumps({"out_dir": a.out_dir, "cases": sorted(CASES)}))


if __name__ == "__main__":
    main()

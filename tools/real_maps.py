"""The real HDR environment maps of the development benchmark beside the three bundled ones:
11 Poly Haven maps (CC0) as the npm package `@pmndrs/assets` carries them (512 x 256 EXRs,
each a base64 string in `hdri/NAME.exr.js`).

    python3 tools/real_maps.py [--out assets/envmaps/real]

fetches the package once (`npm pack`, pinned version: npm checks its integrity against the
registry), decodes the maps and writes NAME.exr (float32, FORMATS.md's convention: the package's
maps are equirectangular with row 0 up; the benchmark turns each about the vertical at random)
and LICENSE.txt to the folder.
`bench_scenes.py` calls `ensure` itself, so the benchmark stays one command.

The package's EXRs are DWAB-compressed (lossy): around bright lights its ringing leaves a few
texels negative (up to 1.7 % of a map's values, the worst beside a sun of 3e4). They are set to 0,
which FORMATS.md requires of a map; `real_maps.json` records how many per map.

The other seven maps of the package are left out: city, forest, night, park, studio, sunrise and
sunset are near copies of maps the benchmark judges on, or of each other.
"""

import argparse
import base64
import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile

import numpy as np

import alp_mitsuba as am

PACKAGE = "@pmndrs/assets@1.7.0"
MAPS = ("apartment", "bridge", "dawn", "esplanade", "hall", "lab", "lobby", "sky", "venice", "warehouse", "workshop")
DEFAULT_OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "assets", "envmaps", "real")


def ensure(out=DEFAULT_OUT):
    """The folder holding the 11 maps (NAME.exr), fetched and decoded when one is missing."""
    out = os.path.abspath(out)
    if all(os.path.isfile(os.path.join(out, n + ".exr")) for n in MAPS):
        return out
    if shutil.which("npm") is None:
        sys.exit("real_maps: npm is needed to fetch %s (the benchmark's real maps) into %s" % (PACKAGE, out))
    os.makedirs(out, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(["npm", "pack", PACKAGE, "--pack-destination", tmp, "--silent"], check=True,
                       stdout=subprocess.DEVNULL)
        (tarball,) = [f for f in os.listdir(tmp) if f.endswith(".tgz")]
        counts = {}
        with tarfile.open(os.path.join(tmp, tarball)) as tar:
            licence = tar.extractfile("package/LICENSE").read()
            for name in MAPS:
                text = tar.extractfile("package/hdri/%s.exr.js" % name).read().decode()
                found = re.search(r"base64,([A-Za-z0-9+/=]+)", text)
                if found is None:
                    sys.exit("real_maps: %s in %s holds no base64 EXR" % (name, PACKAGE))
                raw = os.path.join(tmp, name + ".dwab.exr")
                with open(raw, "wb") as f:
                    f.write(base64.b64decode(found.group(1)))
                env = am.read_exr(raw)
                if env.shape != (256, 512, 3) or not np.isfinite(env).all():
                    sys.exit("real_maps: %s is %s or not finite; expected 256 x 512 RGB" % (name, env.shape))
                counts[name] = int((env < 0).sum())
                am.write_exr(os.path.join(out, name + ".exr.tmp.exr"), np.maximum(env, 0.0))
                os.replace(os.path.join(out, name + ".exr.tmp.exr"), os.path.join(out, name + ".exr"))
    with open(os.path.join(out, "LICENSE.txt"), "wb") as f:
        f.write(b"Poly Haven HDRIs as shipped (512 x 256, DWAB) in the npm package %s; CC0:\n\n"
                % PACKAGE.encode() + licence)
    with open(os.path.join(out, "real_maps.json"), "w") as f:
        json.dump({"package": PACKAGE, "negative_values_set_to_0": counts}, f, indent=1)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=DEFAULT_OUT, help="folder of the maps")
    args = ap.parse_args()
    am.setup_variant("scalar_rgb")
    print(ensure(args.out))


if __name__ == "__main__":
    main()

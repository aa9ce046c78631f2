#!/usr/bin/env python3
"""Render the reference Cornell box with Mitsuba 3 (`pip install mitsuba`) and compare its error,
and Arbor's, against the 4096-spp reference image, so both are measured in one run.

    cargo build --release --bin render
    python3 bench/mitsuba_cornell.py --spp 1024 --variant scalar_rgb
    apt-get install libllvm19   # for the llvm variant, then:
    DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 \
        python3 bench/mitsuba_cornell.py --spp 1024 --variant llvm_ad_rgb

Arbor renders scenes/cornell-box.toml with the same spp and max depth; both report wall time and
the relative MSE, mean over pixels and channels of (x - ref)^2 / (ref^2 + 0.01).
"""
import argparse
import json
import pathlib
import subprocess
import time

import mitsuba as mi

ROOT = pathlib.Path(__file__).resolve().parent.parent
REF = ROOT.parent / "shared" / "reference" / "cornell-box"


def load_dict(variant_spp, max_depth):
    d = json.loads((REF / "cornell.json").read_text())["mitsuba_load_dict"]

    def fix(v):
        if isinstance(v, dict):
            if "matrix_4x4_row_major" in v:
                return mi.ScalarTransform4f(v["matrix_4x4_row_major"])
            return {k: fix(x) for k, x in v.items()}
        return v

    d = fix(d)
    d["integrator"]["max_depth"] = max_depth
    d["sensor"]["sampler"]["sample_count"] = variant_spp
    return d


def rel_mse(img, ref):
    import numpy as np

    return float(np.mean((img - ref) ** 2 / (ref**2 + 0.01)))


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--spp", type=int, default=1024)
    p.add_argument("--max-depth", type=int, default=8)
    p.add_argument("--variant", default="scalar_rgb")
    p.add_argument("--out", default="/tmp")
    a = p.parse_args()
    import numpy as np

    mi.set_variant(a.variant)
    ref = np.array(mi.Bitmap(str(REF / "cornell_spp4096.exr")), dtype=np.float64)[..., :3]

    ours_path = pathlib.Path(a.out) / "arbor_cornell.exr"
    t = time.time()
    subprocess.run(
        [str(ROOT / "target/release/render"), str(ROOT / "scenes/cornell-box.toml"), "-o", str(ours_path),
         "--spp", str(a.spp), "--max-depth", str(a.max_depth), "--quiet"],
        check=True,
    )
    ours_s = time.time() - t
    ours = np.array(mi.Bitmap(str(ours_path)), dtype=np.float64)[..., :3]

    scene = mi.load_dict(load_dict(a.spp, a.max_depth))
    t = time.time()
    img = mi.render(scene, spp=a.spp)
    if hasattr(img, "numpy"):
        img = img.numpy()
    theirs_s = time.time() - t
    theirs = np.array(img, dtype=np.float64)[..., :3]

    print(f"spp {a.spp}, max depth {a.max_depth}, 256x256")
    print(f"arbor (CPU, all threads):  {ours_s:8.2f} s  rel MSE {rel_mse(ours, ref):.3e}  mean {ours.mean(axis=(0, 1))}")
    print(f"mitsuba {a.variant:12s}: {theirs_s:8.2f} s  rel MSE {rel_mse(theirs, ref):.3e}  mean {theirs.mean(axis=(0, 1))}")
    print(f"time ratio arbor / mitsuba: {ours_s / theirs_s:.3f}")


if __name__ == "__main__":
    main()

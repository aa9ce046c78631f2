#!/usr/bin/env python3
"""End-to-end time of `render` per builder: the whole process (load, build, render, write), for
each scene, sample count and builder, the builders alternated, each (scene, spp) repeated.

    python3 bench/builder_e2e.py run RENDER OUT.jsonl SCENES SPPS BUILDERS REPS [DEVICE]
    python3 bench/builder_e2e.py table OUT.jsonl [MORE.jsonl ...]

`run` appends one JSON line per process: scene, spp, builder (`default` runs without
`--builder`), rep, wall seconds, the render's own seconds, the BVH's milliseconds, and for `auto`
its summary and estimate. `table` prints a Markdown table of medians: each builder's wall time,
`auto` over the fastest fixed builder (`lbvh`, `binned-sah`, `lbvh+prbvh`, `ploc+prbvh`),
`lbvh+prbvh` (or `default`, where run) over it, `auto`'s estimate and the LBVH's render.

Example (docs/benchmarks.md, "Builder auto"):

    cargo build --release
    python3 bench/builder_e2e.py run target/release/render e2e.jsonl \\
        scenes/cornell-box.toml,bench/scenes/dragon.toml 1,16,256 \\
        lbvh,binned-sah,lbvh+prbvh,ploc+prbvh,auto 2 cpu
    python3 bench/builder_e2e.py table e2e.jsonl
"""
import collections
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time

FIXED = ["lbvh", "binned-sah", "lbvh+prbvh", "ploc+prbvh"]
ORDER = FIXED + ["auto", "default"]


def run(render, out, scenes, spps, builders, reps, device):
    image = os.path.join(tempfile.mkdtemp(prefix="arbor-e2e-"), "out.exr")
    with open(out, "a") as f:
        for scene in scenes:
            for spp in spps:
                for r in range(reps):
                    # Rotate the order each repetition, so that no builder always runs first.
                    order = builders[r % len(builders):] + builders[: r % len(builders)]
                    for b in order:
                        flag = [] if b == "default" else ["--builder", b]
                        cmd = [render, scene, "-o", image, "--spp", str(spp), "--device", device] + flag
                        t = time.time()
                        p = subprocess.run(cmd, capture_output=True, text=True)
                        wall = time.time() - t
                        o = p.stdout
                        m = re.search(r"render ([0-9.]+) s", o)
                        bm = re.search(r"BVH \((.*?)\) ([0-9.]+) ms", o)
                        est = re.search(r"estimated at ([0-9.]+) s", o)
                        auto = [line for line in o.splitlines() if line.startswith("auto:")]
                        rec = {
                            "scene": os.path.basename(scene),
                            "spp": spp,
                            "builder": b,
                            "rep": r,
                            "wall": wall,
                            "ok": p.returncode == 0,
                            "render": float(m.group(1)) if m else None,
                            "bvh_ms": float(bm.group(2)) if bm else None,
                            "estimate": float(est.group(1)) if est else None,
                            "auto": auto[0] if auto else (bm.group(1) if bm else None),
                            "err": p.stderr[-300:] if p.returncode else "",
                        }
                        f.write(json.dumps(rec) + "\n")
                        f.flush()
                        print(rec["scene"], spp, b, r, round(wall, 2), rec["render"], rec["estimate"], flush=True)


def table(files):
    rows = [json.loads(line) for name in files for line in open(name)]
    cells = collections.OrderedDict()
    for r in rows:
        if r["ok"]:
            key = (r["scene"].replace(".toml", ""), r["spp"])
            cells.setdefault(key, collections.defaultdict(list))[r["builder"]].append(r)
    present = [b for b in ORDER if any(b in d for d in cells.values())]
    print("| scene | spp | " + " | ".join(present) + " | auto / best | old default / best | auto estimate, s | lbvh render, s |")
    print("|" + "---|" * (len(present) + 6))
    for (scene, spp), d in cells.items():
        med = {b: statistics.median(x["wall"] for x in v) for b, v in d.items()}
        best = min(med[b] for b in FIXED if b in med)
        old = med.get("default", med.get("lbvh+prbvh"))
        est = [x["estimate"] for x in d.get("auto", []) if x["estimate"]]
        lbvh = [x["render"] for x in d.get("lbvh", []) if x["render"]]
        ratio = lambda v: f"{v / best:.2f}" if v is not None else "—"
        print(
            f"| {scene} | {spp} | "
            + " | ".join(f"{med[b]:.2f}" if b in med else "" for b in present)
            + f" | {ratio(med.get('auto'))} | {ratio(old)}"
            + f" | {f'{statistics.median(est):.2f}' if est else '—'} | {f'{statistics.median(lbvh):.2f}' if lbvh else '—'} |"
        )


if __name__ == "__main__":
    a = sys.argv[1:]
    if a[:1] == ["run"] and len(a) in (7, 8):
        run(a[1], a[2], a[3].split(","), [int(x) for x in a[4].split(",")], a[5].split(","), int(a[6]),
            a[7] if len(a) == 8 else "cpu")
    elif a[:1] == ["table"] and len(a) >= 2:
        table(a[1:])
    else:
        sys.exit(__doc__)

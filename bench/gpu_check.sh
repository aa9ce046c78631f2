#!/usr/bin/env bash
# The GPU check: every tree form on one card, in one run, in under 8 minutes with the build.
#
#   bench/gpu_check.sh OUT_DIR
#
# Builds `render` and `bvh-bench` (release), then measures on the same machine:
#   1. GPU builds (LBVH, PRBVH, the collapse into the compressed 8-wide form) and trace speeds of
#      primary, shadow and diffuse rays through both forms (binary: the baseline) on the dragon,
#      city:1M and hairball:1M (`bvh-bench --gpu`);
#   2. renders of bench/scenes/dragon.toml, scenes/instanced-field.toml (animated, 4 frames) and
#      scenes/textured-sky.toml on the GPU in both forms and on the CPU;
#   3. the animated scene's per-frame update and render speed on the GPU in two levels (the top
#      level updated in place, or rebuilt) against flattening it every frame, in both forms
#      (`bvh-bench --animated SCENE --gpu`).
# Prints one table and writes OUT_DIR/gpu_check.json (rewritten after every step, so a run
# stopped by a signal or by a step's time limit still leaves what it measured, and prints a
# partial table). Each step has a time limit (STEP_SECONDS, default 90), and the whole run one
# (TOTAL_SECONDS, default 420, the build included): a step that would start with under 15 s left
# is recorded as skipped.
#
# Environment: ARBOR_BIN=DIR uses already-built `render` and `bvh-bench` from DIR instead of
# building; GPU_CHECK_QUICK=1 uses small inputs (a smoke test of the script itself, as CI runs
# it on lavapipe).
#
# On a lent machine without a Rust toolchain (this workplace's `device`), build here and carry
# the stripped binaries, the dragon and the Vulkan loader (the device README's `.gl` folder):
#   cargo build --release --bin render -p arbor && cargo build --release -p arbor-bench --bin bvh-bench
#   mkdir -p .gpu-bin && strip -o .gpu-bin/render target/release/render \
#     && strip -o .gpu-bin/bvh-bench target/release/bvh-bench && cp ../shared/models/dragon_res2.obj .gpu-bin/
#   (.gpu-bin and .gl listed in .git/info/exclude), then run with carry [".gl", ".gpu-bin"]:
#   for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig; mkdir -p ../shared/models \
#     && cp .gpu-bin/dragon_res2.obj ../shared/models/ && ARBOR_BIN=.gpu-bin bash bench/gpu_check.sh $OUT
set -u
out=${1:?usage: bench/gpu_check.sh OUT_DIR}
mkdir -p "$out" || exit 2
out=$(cd "$out" && pwd)
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root" || exit 2
step_seconds=${STEP_SECONDS:-90}
total_seconds=${TOTAL_SECONDS:-420}
quick=${GPU_CHECK_QUICK:-0}
results="$out/gpu_check.steps"
: >"$results"
started=$(date +%s)

# The time limit of the next step: STEP_SECONDS or what is left of TOTAL_SECONDS; 0 when too
# little is left to start one.
step_limit() {
    local left=$((started + total_seconds - $(date +%s)))
    if [ "$left" -lt 15 ]; then echo 0; elif [ "$left" -lt "$step_seconds" ]; then echo "$left"; else echo "$step_seconds"; fi
}

# Records a step that was not started: the time was spent.
skipped() {
    echo "$1" | python3 -c 'import json,sys; d=json.loads(sys.stdin.read()); d["error"]="skipped: TOTAL_SECONDS spent"; print(json.dumps(d))' >>"$results"
    summarise >/dev/null
}

# One JSON line per step in $results; the table and gpu_check.json are made from them.
summarise() {
    python3 - "$results" "$out/gpu_check.json" "$started" <<'EOF'
import json, sys, time
steps = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
report = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "seconds": round(time.time() - float(sys.argv[3]), 1), "steps": steps}
adapter = next((s.get("adapter") for s in steps if s.get("adapter")), None)
report["adapter"] = adapter
tmp = sys.argv[2] + ".tmp"
with open(tmp, "w") as f:
    json.dump(report, f, indent=2)
    f.write("\n")
import os
os.replace(tmp, sys.argv[2])
print(f"GPU check on {adapter or 'unknown adapter'}: {len(steps)} steps in {report['seconds']} s")
def num(v, fmt="{:.1f}"):
    return "-" if v is None else fmt.format(v)
builds = [s for s in steps if s["kind"] == "bvh"]
if builds:
    print(f"{'mesh':<14} {'tris':>9} {'lbvh ms':>8} {'prbvh ms':>9} {'coll ms':>8} | {'wide prim':>9} {'shad':>7} {'diff':>7} | {'bin prim':>8} {'shad':>7} {'diff':>7} | {'w/b diff':>8} {'mism':>5}")
    for s in builds:
        if s.get("error"):
            print(f"{s['input']:<14} {s['error']}")
            continue
        w, b = s["wide"], s["binary"]
        ratio = w[2] / b[2] if w[2] and b[2] else None
        print(f"{s['input']:<14} {s['triangles']:>9} {num(s['lbvh_ms'])} {num(s['prbvh_ms']):>9} {num(s['collapse_ms']):>8} | "
              f"{num(w[0]):>9} {num(w[1]):>7} {num(w[2]):>7} | {num(b[0]):>8} {num(b[1]):>7} {num(b[2]):>7} | {num(ratio, '{:.2f}x'):>8} {s['mismatches']:>5}")
    print("(Mrays/s of the device's time per dispatch; ms of the device's time, the collapse on the GPU)")
anims = [s for s in steps if s["kind"] == "animation"]
for s in anims:
    if s.get("error"):
        print(f"animation {s['scene']}: {s['error']}")
        continue
    print(f"{'animation ' + s['scene']:<30} {'form':<7} {'update ms':>9} {'Mrays/s':>9} {'device MB':>9}")
    for r in s["rows"]:
        print(f"{r['strategy']:<30} {r['form']:<7} {num(r['update_ms'], '{:.2f}'):>9} {num(r['mrays'], '{:.3f}'):>9} {num(r['device_bytes'] / 1e6):>9}")
renders = [s for s in steps if s["kind"] == "render"]
if renders:
    print(f"{'scene':<18} {'device':<6} {'form':<7} {'frames':>6} {'build ms':>9} {'update ms':>9} {'render s':>9} {'Mrays/s':>9}")
    for s in renders:
        if s.get("error"):
            print(f"{s['scene']:<18} {s['device']:<6} {s['form']:<7} {s['error']}")
            continue
        print(f"{s['scene']:<18} {s['device']:<6} {s['form']:<7} {s['frames']:>6} {num(s['build_ms']):>9} {num(s['update_ms']):>9} {num(s['render_seconds'], '{:.2f}'):>9} {num(s['mrays']):>9}")
EOF
}
trap 'echo "gpu_check: stopped; the table so far:" >&2; summarise; exit 130' INT TERM

if [ -n "${ARBOR_BIN:-}" ]; then
    bin=$ARBOR_BIN
else
    echo "gpu_check: building (release)" >&2
    cargo build --release -q --bin render -p arbor && cargo build --release -q -p arbor-bench --bin bvh-bench || exit 1
    bin=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])')/release
fi

# bvh-bench --gpu on one input: builds and both forms' trace speeds.
bvh_step() {
    local name=$1; shift
    local json="$out/bvh-$name.json"
    rm -f "$json"
    local limit
    limit=$(step_limit)
    [ "$limit" = 0 ] && { skipped "{\"kind\": \"bvh\", \"input\": \"$name\"}"; return; }
    timeout "$limit" "$bin/bvh-bench" --gpu "$@" --builders lbvh+prbvh --runs 3 --json "$json" >"$out/bvh-$name.log" 2>&1
    local rc=$?
    python3 - "$json" "$name" "$rc" >>"$results" <<'EOF'
import json, sys
path, name, rc = sys.argv[1], sys.argv[2], int(sys.argv[3])
try:
    r = json.load(open(path))
except Exception:
    why = "stopped by its time limit" if rc == 124 else f"bvh-bench exit {rc}"
    print(json.dumps({"kind": "bvh", "input": name, "error": f"{why} (see bvh-{name}.log)"}))
    sys.exit()
row = lambda stage, device: next((x for x in r["rows"] if x["stage"] == stage and x["device"] == device), {})
b = r["builders"][0]
print(json.dumps({
    "kind": "bvh", "input": name, "adapter": r["adapter"], "triangles": r["triangles"],
    "lbvh_ms": row("lbvh", "gpu").get("ms"), "prbvh_ms": row("prbvh", "gpu").get("ms"),
    "lbvh_cpu_ms": row("lbvh", "cpu").get("ms"), "prbvh_cpu_ms": row("prbvh", "cpu").get("ms"),
    "collapse_ms": row("collapse", "gpu").get("ms"), "collapse_cpu_ms": row("collapse", "cpu").get("ms"),
    "wide_sah": b.get("gpu_wide_sah"),
    "wide": [b.get("gpu_primary_mrays"), b.get("gpu_shadow_mrays"), b.get("gpu_diffuse_mrays")],
    "binary": [b.get("gpu_binary_primary_mrays"), b.get("gpu_binary_shadow_mrays"), b.get("gpu_binary_diffuse_mrays")],
    "cpu": [b.get("primary_mrays"), b.get("shadow_mrays"), b.get("diffuse_mrays")],
    "mismatches": b.get("gpu_hit_mismatches"), "exit": rc,
}))
EOF
    summarise >/dev/null
}

# bvh-bench --animated SCENE --gpu: two levels against flattening, per frame.
anim_step() {
    local scene=$1; shift
    local name
    name=$(basename "$scene" .toml)
    local json="$out/anim-$name.json"
    rm -f "$json"
    local limit
    limit=$(step_limit)
    [ "$limit" = 0 ] && { skipped "{\"kind\": \"animation\", \"scene\": \"$name\"}"; return; }
    timeout "$limit" "$bin/bvh-bench" --animated "$scene" --gpu "$@" --json "$json" >"$out/anim-$name.log" 2>&1
    local rc=$?
    python3 - "$json" "$name" "$rc" >>"$results" <<'EOF'
import json, sys
path, name, rc = sys.argv[1], sys.argv[2], int(sys.argv[3])
try:
    r = json.load(open(path))
except Exception:
    why = "stopped by its time limit" if rc == 124 else f"bvh-bench exit {rc}"
    print(json.dumps({"kind": "animation", "scene": name, "error": f"{why} (see anim-{name}.log)"}))
    sys.exit()
print(json.dumps({"kind": "animation", "scene": name, "adapter": r["adapter"], "frames": r["frames"],
                  "instances": r["instances"], "rows": r["rows"], "exit": rc}))
EOF
    summarise >/dev/null
}

# One render: scene, device, form, then render's own options.
render_step() {
    local scene=$1 device=$2 form=$3; shift 3
    local tag
    tag=$(basename "$scene" .toml)-$device-$form
    local report="$out/render-$tag.json"
    rm -f "$report"
    local trace=()
    [ "$form" != "default" ] && trace=(--trace "$form")
    # A frame range writes a sequence: its name takes the frame number.
    local name="$out/$tag.exr"
    case " $* " in *" --frames "*) name="$out/$tag-%04d.exr" ;; esac
    local limit
    limit=$(step_limit)
    [ "$limit" = 0 ] && {
        skipped "{\"kind\": \"render\", \"scene\": \"$(basename "$scene" .toml)\", \"device\": \"$device\", \"form\": \"$form\"}"
        return
    }
    timeout "$limit" "$bin/render" "$scene" -o "$name" --device "$device" "${trace[@]}" \
        --report "$report" --quiet "$@" >"$out/render-$tag.log" 2>&1
    local rc=$?
    python3 - "$report" "$scene" "$device" "$form" "$rc" "$tag" >>"$results" <<'EOF'
import json, sys
path, scene, device, form, rc, tag = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4], int(sys.argv[5]), sys.argv[6]
name = scene.rsplit("/", 1)[-1].removesuffix(".toml")
try:
    r = json.load(open(path))
    frames = [f for f in r.get("frames", []) if f.get("status") == "rendered"]
    assert frames
except Exception:
    why = "stopped by its time limit" if rc == 124 else f"render exit {rc}"
    print(json.dumps({"kind": "render", "scene": name, "device": device, "form": form, "error": f"{why} (see render-{tag}.log)"}))
    sys.exit()
seconds = sum(f["render_seconds"] for f in frames)
rays = sum(f["rays"] for f in frames)
updates = [f["bvh_update_ms"] for f in frames if f.get("bvh_update_ms") is not None]
print(json.dumps({
    "kind": "render", "scene": name, "device": device, "form": form, "adapter": r.get("adapter"),
    "frames": len(frames), "build_ms": (r.get("bvh") or {}).get("build_ms"),
    "update_ms": sum(updates) / len(updates) if updates else None,
    "render_seconds": seconds, "mrays": rays / seconds / 1e6 if seconds > 0 else None, "exit": rc,
}))
EOF
    summarise >/dev/null
}

dragon_mesh=../shared/models/dragon_res2.obj
if [ "$quick" = 1 ]; then
    bvh_inputs=("city-2k:--procedural city:2k --resolution 64" "hairball-2k:--procedural hairball:2k --resolution 64")
    render_opts=(--spp 4)
    frames=(--frames 0..2)
else
    bvh_inputs=("dragon:$dragon_mesh" "city-1M:--procedural city:1M" "hairball-1M:--procedural hairball:1M")
    render_opts=()
    frames=(--frames 0..4)
fi
for entry in "${bvh_inputs[@]}"; do
    name=${entry%%:*}
    # shellcheck disable=SC2086 # the options are words
    bvh_step "$name" ${entry#*:}
done
dragon_scene=bench/scenes/dragon.toml
[ "$quick" = 1 ] && dragon_scene=scenes/cornell-box.toml
for scene in "$dragon_scene" scenes/textured-sky.toml; do
    for run in "gpu wide8" "gpu binary" "cpu default"; do
        # shellcheck disable=SC2086
        render_step "$scene" $run "${render_opts[@]}"
    done
done
animated=scenes/instanced-field.toml
[ "$quick" = 1 ] && animated=scenes/cornell-animated.toml
for run in "gpu wide8" "gpu binary" "cpu default"; do
    # shellcheck disable=SC2086
    render_step "$animated" $run "${frames[@]}" "${render_opts[@]}"
done
anim_step "$animated" --frames 4
summarise

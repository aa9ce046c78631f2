#!/usr/bin/env bash
# How long `render` takes to act on SIGTERM (docs/distributed.md, "Jobs that fail"): the time
# from the signal to the process's exit, for a signal while the scene loads and for signals
# while it renders, on the Cornell box and the dragon scene at 1024x1024.
#
#   bash bench/signal_latency.sh [DEVICE...]     (default: cpu; e.g. `cpu gpu`)
#
# Needs a release build (`cargo build --release --bin render`; RENDER=path picks another) and
# ../shared/models for the dragon. Prints one line per trial: scene, device, when the signal came (seconds after the
# start), the exit code and the seconds from the signal to the exit.
set -euo pipefail
cd "$(dirname "$0")/.."
render=${RENDER:-target/release/render}
[[ -x $render ]] || { echo "build first: cargo build --release --bin render" >&2; exit 1; }
devices=("${@:-cpu}")
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

sed 's/resolution = \[256, 256\]/resolution = [1024, 1024]/' scenes/cornell-box.toml >"$work/cornell.toml"
sed -e 's/resolution = \[512, 512\]/resolution = [1024, 1024]/' \
    -e "s#\.\./\.\./\.\./shared#$PWD/../shared#" bench/scenes/dragon.toml >"$work/dragon.toml"

now() { date +%s.%N; }

# trial SCENE DEVICE DELAY: SIGTERM after DELAY seconds.
trial() {
  local scene=$1 device=$2 delay=$3
  rm -f "$work/out.exr" "$work/out.exr.partial.exr"
  "$render" "$work/$scene.toml" -o "$work/out.exr" --device "$device" --spp 4096 --quiet &
  local pid=$!
  sleep "$delay"
  local sent
  sent=$(now)
  kill -TERM "$pid"
  local code=0
  wait "$pid" || code=$?
  local done
  done=$(now)
  printf '%-8s %-4s signal at %5.2f s: exit %3d after %.3f s\n' "$scene" "$device" "$delay" "$code" \
    "$(echo "$done - $sent" | bc -l)"
}

for device in "${devices[@]}"; do
  for scene in cornell dragon; do
    # While loading (the dragon's OBJ takes a few tenths of a second), then while rendering.
    for delay in 0.05 3 7.5 12; do
      trial "$scene" "$device" "$delay"
    done
  done
done

#!/usr/bin/env bash
# Queues a distributed Arbor render on Slurm: the array of pieces (render-array.sbatch), then the
# merge (render-merge.sbatch), which starts once every piece has succeeded.
#
#   deploy/slurm/submit.sh SCENE OUT_DIR [SBATCH_OPTION...]
#
# SCENE and OUT_DIR must be on a folder every node sees. The ARBOR_* settings the two scripts
# read (see render-array.sbatch) are taken from the environment; SBATCH_OPTIONs (--partition,
# --time, --cpus-per-task, --mem, ...) go to both jobs. Prints the two job ids.
set -euo pipefail

if (($# < 2)); then
  sed -n '2,10s/^# \{0,1\}//p' "$0" >&2
  exit 2
fi
here=$(cd "$(dirname "$0")" && pwd)
[[ -f $1 ]] || { echo "submit.sh: no scene file $1" >&2; exit 2; }
ARBOR_SCENE=$(realpath "$1")
mkdir -p "$2"
ARBOR_OUT=$(realpath "$2")
shift 2
export ARBOR_SCENE ARBOR_OUT

pieces=${ARBOR_PIECES:-16}
count=1
if [[ -n ${ARBOR_FRAMES:-} ]]; then
  [[ $ARBOR_FRAMES =~ ^([0-9]+)\.\.([0-9]+)$ ]] || { echo "submit.sh: ARBOR_FRAMES is not A..B" >&2; exit 2; }
  count=$((BASH_REMATCH[2] - BASH_REMATCH[1]))
fi
tasks=$((pieces * count))
((tasks > 0)) || { echo "submit.sh: nothing to render ($pieces pieces, $count frames)" >&2; exit 2; }
mkdir -p "$ARBOR_OUT"/{pieces,reports,logs}

# --parsable prints `JOBID` or `JOBID;CLUSTER`. --export=ALL, since a site may default to NONE.
array=$(sbatch --parsable --export=ALL --array="0-$((tasks - 1))" \
  --output="$ARBOR_OUT/logs/render-%A_%a.out" "$@" "$here/render-array.sbatch")
array=${array%%;*}
# afterok: only once every task has succeeded. A task that fails for good would otherwise leave
# the merge pending forever; --kill-on-invalid-dep cancels it instead.
merge=$(sbatch --parsable --export=ALL --dependency="afterok:$array" --kill-on-invalid-dep=yes \
  --output="$ARBOR_OUT/logs/merge-%j.out" "$@" "$here/render-merge.sbatch")
merge=${merge%%;*}
echo "render array: job $array ($tasks tasks); merge: job $merge"
echo "logs: $ARBOR_OUT/logs; watch with: squeue -j $array,$merge"

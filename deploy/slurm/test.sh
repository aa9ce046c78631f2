#!/usr/bin/env bash
# Tests deploy/slurm on a one-node Slurm cluster that it starts on this machine (the recipe of
# shared/notes/slurm-single-node.md, with every file in a temporary folder): submit.sh queues a
# 4-tile render of scenes/cornell-box.toml at 8 spp and the merge; one task is interrupted the
# way a time limit interrupts it (SIGTERM to the batch shell) and must requeue and resume; the
# merged EXR must equal a single render byte for byte. Then two frames of an animation, each
# split by sample ranges, must equal their single renders; and a task that exits 2 must fail
# without a retry, with the merge after it cancelled.
#
#   bash deploy/slurm/test.sh            (as root; from anywhere)
#
# ARBOR_RENDER: the render binary (default target/debug/render under the repository root).
# Needs slurm-wlm and munge; without them it skips, or fails under CI=true.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
render=$(realpath -m "${ARBOR_RENDER:-target/debug/render}")
start=$SECONDS
# The settings come from each submission below, not from the caller's environment.
unset ARBOR_SCENE ARBOR_OUT ARBOR_PIECES ARBOR_SPLIT ARBOR_SPP ARBOR_FRAMES ARBOR_CHECKPOINT \
  ARBOR_MAX_REQUEUES ARBOR_FLAGS ARBOR_IMAGE
say() { echo "slurm test [$((SECONDS - start))s]: $*"; }
fail() { say "FAIL: $*" >&2; exit 1; }
skip() {
  [[ ${CI:-} == true ]] && fail "$* (CI=true: a missing prerequisite is a failure)"
  say "SKIP: $*"
  exit 0
}

for tool in munged mungekey slurmctld slurmd sbatch squeue scancel scontrol sinfo; do
  command -v "$tool" >/dev/null ||
    skip "no $tool: apt-get install -y --no-install-recommends slurm-wlm munge"
done
((EUID == 0)) || skip "slurmd must run as root"
[[ -x $render ]] || fail "no render binary at $render (build it, or set ARBOR_RENDER)"
# A second controller on this machine would fight over ports with ours; the test never touches
# a cluster it did not start.
if pgrep -x slurmctld >/dev/null || pgrep -x slurmd >/dev/null; then
  fail "a Slurm daemon is already running here (pgrep -x slurmctld/slurmd); not starting another"
fi

work=$(mktemp -d /tmp/arbor-slurm-test.XXXXXX)
# munged wants every folder above its socket searchable by all.
chmod 755 "$work"
pids=() jobs=()
cleanup() {
  local rc=$?
  trap - EXIT INT TERM
  set +e
  if ((rc != 0)); then
    for f in "$work"/out*/logs/* "$work"/log/*; do
      [[ -f $f ]] && { echo "---- $f"; tail -n 30 "$f"; }
    done
  fi
  if ((${#jobs[@]})); then
    scancel "${jobs[@]}" 2>/dev/null
    for _ in {1..20}; do
      [[ -z $(squeue -h -j "$(IFS=,; echo "${jobs[*]}")" 2>/dev/null) ]] && break
      sleep 0.5
    done
  fi
  # slurmd, slurmctld, munged: the reverse of the order they started in.
  for ((i = ${#pids[@]} - 1; i >= 0; i--)); do
    say "stopping pid ${pids[i]}"
    kill "${pids[i]}" 2>/dev/null
    for _ in {1..20}; do kill -0 "${pids[i]}" 2>/dev/null || break; sleep 0.25; done
    kill -KILL "${pids[i]}" 2>/dev/null
    wait "${pids[i]}" 2>/dev/null
  done
  rm -rf "$work"
  say "$( ((rc == 0)) && echo passed || echo "failed (exit $rc)")"
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

say "work folder $work; render binary $render"
mkdir -p "$work"/{munge,log,ctld,slurmd,out}
mkdir -m 755 "$work/munge-run"
chmod 700 "$work/munge"
mungekey --create --keyfile="$work/munge/key"
munged -F --socket="$work/munge-run/socket" --key-file="$work/munge/key" \
  --pid-file="$work/munge/pid" --seed-file="$work/munge/seed" --log-file="$work/log/munged.log" \
  >"$work/log/munged.out" 2>&1 &
pids+=($!)
say "munged pid $!"
for _ in {1..40}; do
  munge -n --socket="$work/munge-run/socket" >/dev/null 2>&1 && break
  sleep 0.25
done
munge -n --socket="$work/munge-run/socket" >/dev/null || fail "munged does not answer"

host=$(hostname -s)
export SLURM_CONF=$work/slurm.conf
# As in the notes, with these changes: SlurmUser=root, as the state folder is ours; our own
# munged; the node's address, so that the host name need not resolve. cred_expire (120 s by
# default) is also how long a requeued task waits before it may start again, and the scheduler
# runs every second rather than every minute. The node claims 4 CPUs (config_overrides lets it
# claim more than it has), so that all four tasks run at once: Slurm 22.05 answers a signal
# to one array task with "try again later" while other tasks of its array are pending (it
# delivers it, but scancel retries for minutes).
cat >"$SLURM_CONF" <<EOF
ClusterName=arbortest
SlurmctldHost=$host(127.0.0.1)
SlurmUser=root
AuthType=auth/munge
AuthInfo=socket=$work/munge-run/socket,cred_expire=5
SchedulerParameters=sched_interval=1,bf_interval=1
SlurmdParameters=config_overrides
StateSaveLocation=$work/ctld
SlurmdSpoolDir=$work/slurmd
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
KillWait=5
SlurmctldLogFile=$work/log/slurmctld.log
SlurmdLogFile=$work/log/slurmd.log
NodeName=$host NodeAddr=127.0.0.1 CPUs=4 State=UNKNOWN
PartitionName=test Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
slurmctld -D -f "$SLURM_CONF" >"$work/log/slurmctld.out" 2>&1 &
pids+=($!)
say "slurmctld pid $!"
slurmd -D -f "$SLURM_CONF" >"$work/log/slurmd.out" 2>&1 &
pids+=($!)
say "slurmd pid $!"
for _ in {1..60}; do
  [[ $(sinfo -h -o %T 2>/dev/null) == idle ]] && break
  sleep 0.5
done
[[ $(sinfo -h -o %T 2>/dev/null) == idle ]] || fail "the node is not idle: $(sinfo 2>&1)"
say "cluster up: $(sinfo -h -o '%P %D node(s) %T %c cpus')"

# Waits until none of the given jobs is pending or running, for at most $1 seconds.
wait_jobs() {
  local limit=$1 ids
  shift
  ids=$(IFS=,; echo "$*")
  for ((t = 0; t < limit * 2; t++)); do
    [[ -z $(squeue -h -j "$ids" 2>/dev/null) ]] && return 0
    sleep 0.5
  done
  squeue -j "$ids"
  fail "jobs $ids still queued after $limit s"
}

# Runs submit.sh with the settings in the arguments (NAME=VALUE ...); sets $array and $merge.
submit() {
  local line
  line=$(env "$@" ARBOR_RENDER="$render" bash deploy/slurm/submit.sh "$scene" "$out")
  echo "$line"
  [[ $line =~ render\ array:\ job\ ([0-9]+).*merge:\ job\ ([0-9]+) ]] ||
    fail "submit.sh printed no job ids"
  array=${BASH_REMATCH[1]} merge=${BASH_REMATCH[2]}
  jobs+=("$array" "$merge")
}

scene=$root/scenes/cornell-box.toml
out=$work/out
flags=(--device cpu --quiet)
say "submitting 4 tiles at 8 spp, and the merge"
submit ARBOR_PIECES=4 ARBOR_SPP=8 ARBOR_CHECKPOINT=1 ARBOR_FLAGS="${flags[*]}"

# Interrupt task 1 as the time-limit warning would (#SBATCH --signal=B:TERM): SIGTERM to its
# batch shell alone, which passes it on. The render must then be mid-render, with its SIGTERM
# handler, however fast the binary and the machine: it is stopped (SIGSTOP) as soon as it is
# forked, let run in slices of a few milliseconds until it has the handler, and held until the
# shell has passed the signal on.
log1=$out/logs/render-${array}_1.out
pid=''
for ((t = 0; t < 6000; t++)); do
  if [[ -f $log1 ]]; then
    while read -r line; do
      [[ $line =~ render\ pid\ ([0-9]+) ]] && pid=${BASH_REMATCH[1]}
    done <"$log1"
  fi
  [[ -n $pid ]] && break
  sleep 0.01
done
[[ -n $pid ]] || fail "task 1 did not start its render within 60 s"
kill -STOP "$pid" || fail "task 1's render (pid $pid) ended before it could be held"
# Whether process $1 is the render (not the shell that forked it, before its exec) and has its
# SIGTERM handler (signal 15: bit 14 of SigCgt).
name=$(basename "$render" | cut -c1-15)
catches_term() {
  local comm line
  { read -r comm <"/proc/$1/comm"; } 2>/dev/null && [[ $comm == "$name" ]] || return 1
  while read -r line; do
    [[ $line =~ ^SigCgt:[[:space:]]*([0-9a-f]+) ]] && (((16#${BASH_REMATCH[1]} >> 14) & 1)) &&
      return 0
  done <"/proc/$1/status"
  return 1
}
for ((t = 0; t < 5000; t++)); do
  catches_term "$pid" && break
  kill -CONT "$pid" || fail "task 1's render (pid $pid) ended before it caught SIGTERM"
  sleep 0.002
  kill -STOP "$pid" || fail "task 1's render (pid $pid) ended before it caught SIGTERM"
done
catches_term "$pid" || fail "render $pid of task 1 never caught SIGTERM"
say "task 1's render (pid $pid) is held; SIGTERM to its batch shell"
scancel --batch --signal=TERM "${array}_1" || fail "scancel could not signal task 1"
for ((t = 0; t < 100; t++)); do
  grep -q 'got SIGTERM' "$log1" && break
  sleep 0.1
done
kill -CONT "$pid"
grep -q 'got SIGTERM' "$log1" || fail "task 1's batch shell did not get the SIGTERM"

wait_jobs 150 "$array" "$merge"
say "jobs done"
grep -q 'exit 75 (interrupted, state written): requeueing' "$log1" ||
  fail "task 1 was not interrupted and requeued: $(cat "$log1")"
grep -q '^arbor-render.*restart 1 ' "$log1" || fail "task 1 did not run again: $(cat "$log1")"
# The report of the last run: it carried on from the state, not from scratch; or, where the
# signal came while the scene still loaded (nothing written then), it started afresh.
status=resumed
grep -q 'while loading the scene' "$log1" && status=rendered
grep -q "\"status\": \"$status\"" "$out/reports/piece-0001-of-0004.json" ||
  fail "task 1's second run was not $status: $(cat "$out/reports/piece-0001-of-0004.json")"
say "task 1 was interrupted, requeued itself and was $status on its second run; its log:"
sed 's/^/    /' "$log1"
image=$out/image.exr
[[ -f $image ]] || fail "no merged image $image"
for i in 0 1 2 3; do
  [[ -s $out/reports/piece-000$i-of-0004.json ]] || fail "no report of task $i"
done

say "rendering the reference: one process, no split"
"$render" "$scene" -o "$work/single.exr" --spp 8 "${flags[@]}"
cmp "$image" "$work/single.exr" || fail "the merged image differs from the single render"
say "merged == single render, byte for byte ($(stat -c %s "$image") bytes)"
# The comparison must be able to fail: another seed gives another image.
"$render" "$scene" -o "$work/seed1.exr" --spp 8 --seed 1 "${flags[@]}"
cmp -s "$image" "$work/seed1.exr" && fail "cmp finds no difference from a render with seed 1"
say "and differs from a render with another seed, as it must"

say "frames 10 and 11 of scenes/cornell-animated.toml, each split in 2 sample ranges of 4 spp"
scene=$root/scenes/cornell-animated.toml
out=$work/out-frames
submit ARBOR_SPLIT=samples ARBOR_PIECES=2 ARBOR_SPP=4 ARBOR_FRAMES=10..12 ARBOR_FLAGS="${flags[*]}"
wait_jobs 120 "$array" "$merge"
"$render" "$scene" -o "$work/single-%04d.exr" --frames 10..12 --spp 4 "${flags[@]}"
for f in 0010 0011; do
  [[ -f $out/frame-$f.exr ]] || fail "no merged frame $out/frame-$f.exr"
  cmp "$out/frame-$f.exr" "$work/single-$f.exr" || fail "frame $f differs from the single render"
done
say "both frames == single render, byte for byte"

say "a task that exits 2 (bad input) fails once, and the merge behind it is cancelled"
scene=$work/bad.toml
echo 'this is not a scene' >"$scene"
out=$work/out-bad
submit ARBOR_PIECES=1 ARBOR_FLAGS="${flags[*]}"
wait_jobs 60 "$array" "$merge"
grep -q 'exit 2: bad input; not retried' "$out/logs/render-${array}_0.out" ||
  fail "the bad task did not report exit 2: $(cat "$out"/logs/*)"
grep -q 'restart 1 ' "$out/logs/render-${array}_0.out" && fail "the bad task was retried"
[[ -e $out/logs/merge-$merge.out ]] && fail "the merge ran after a failed task"
say "ok"

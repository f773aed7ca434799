#!/bin/bash
# Integration test: a real single-node Slurm on this machine runs a recording job as a job array
# plus its merge (scripts/slurm/submit-recording.sh), and the merged output equals one process's.
#
#   tests/slurm/slurm_test.sh EVKIT_BINARY SOURCE_DIR
#
# It starts its own munged (as the munge user, with its own key and socket), slurmctld and slurmd
# (a slurm.conf in a temporary folder: free non-default ports, its own state and spool folders,
# proctrack/linuxproc, task/none), and stops every daemon it started by its pid on exit, whatever
# happens. Exit 77 (ctest: skipped) with the reason when Slurm cannot run here.
set -uo pipefail
evkit=$(realpath "$1")
source_dir=$(realpath "$2")
skip() {
  echo "SKIP: $*"
  exit 77
}
fail() {
  echo "FAIL: $*"
  for f in "${tmp:-/nonexistent}"/log/*.log; do
    [ -f "$f" ] && { echo "--- $f"; tail -n 30 "$f"; }
  done
  exit 1
}

for tool in munged slurmctld slurmd sbatch squeue sinfo runuser; do
  command -v "$tool" >/dev/null || skip "$tool is not installed (Debian: munge slurmctld slurmd slurm-client)"
done
[ "$(id -u)" -eq 0 ] || skip "slurmd must run as root to start jobs (run the tests as root)"
id munge >/dev/null 2>&1 || skip "no 'munge' user (Debian's munge package creates it)"

tmp=$(mktemp -d /tmp/evkit-slurm-XXXXXX)
chmod 0755 "$tmp"
pids=()
cleanup() {
  for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null; done
  for pid in "${pids[@]}"; do
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$pid" 2>/dev/null
  done
  rm -rf "$tmp"
}
trap cleanup EXIT
mkdir -p "$tmp"/{munge,state,spool,log,work}
mkdir -p /run/munge && chown munge:munge /run/munge

# munged: its own key and socket, run as the munge user.
head -c 1024 /dev/urandom >"$tmp/munge/munge.key"
chown -R munge:munge "$tmp/munge"
chmod 0700 "$tmp/munge"
chmod 0400 "$tmp/munge/munge.key"
socket=$tmp/munge/munge.socket
runuser -u munge -- munged --force --key-file="$tmp/munge/munge.key" --socket="$socket" \
  --pid-file="$tmp/munge/munged.pid" --log-file="$tmp/munge/munged.log" \
  --seed-file="$tmp/munge/munged.seed" || skip "munged did not start: $(tail -n 3 "$tmp/munge/munged.log" 2>/dev/null)"
for _ in $(seq 50); do [ -s "$tmp/munge/munged.pid" ] && break; sleep 0.1; done
[ -s "$tmp/munge/munged.pid" ] || skip "munged wrote no pid file"
pids+=("$(cat "$tmp/munge/munged.pid")")
cp "$tmp/munge/munged.log" "$tmp/log/munged.log" 2>/dev/null || true

# Two free ports, away from Slurm's defaults (6817, 6818).
read -r ctld_port slurmd_port < <(python3 -c '
import socket
s = [socket.socket() for _ in range(2)]
for x in s: x.bind(("127.0.0.1", 0))
print(*(x.getsockname()[1] for x in s))')
host=$(hostname -s)
cpus=$(nproc)
cat >"$tmp/slurm.conf" <<EOF
ClusterName=evkittest
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
AuthType=auth/munge
AuthInfo=socket=$socket
CredType=cred/munge
SlurmUser=root
SlurmdUser=root
StateSaveLocation=$tmp/state
SlurmdSpoolDir=$tmp/spool
SlurmctldPidFile=$tmp/slurmctld.pid
SlurmdPidFile=$tmp/slurmd.pid
SlurmctldLogFile=$tmp/log/slurmctld.log
SlurmdLogFile=$tmp/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MpiDefault=none
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
SlurmdTimeout=30
NodeName=$host NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=1000 State=UNKNOWN
PartitionName=evkit Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF=$tmp/slurm.conf

slurmctld -f "$SLURM_CONF" || fail "slurmctld did not start"
for _ in $(seq 50); do [ -s "$tmp/slurmctld.pid" ] && break; sleep 0.1; done
[ -s "$tmp/slurmctld.pid" ] || fail "slurmctld wrote no pid file"
pids+=("$(cat "$tmp/slurmctld.pid")")
slurmd -f "$SLURM_CONF" -N "$host" || fail "slurmd did not start"
for _ in $(seq 50); do [ -s "$tmp/slurmd.pid" ] && break; sleep 0.1; done
[ -s "$tmp/slurmd.pid" ] || fail "slurmd wrote no pid file"
pids+=("$(cat "$tmp/slurmd.pid")")

state=""
for _ in $(seq 120); do
  state=$(sinfo -h -n "$host" -o %T 2>/dev/null | head -n 1)
  [ "$state" = "idle" ] && break
  sleep 0.5
done
[ "$state" = "idle" ] || fail "the node did not come up (state '$state')"
echo "slurm: node $host idle (slurmctld :$ctld_port, slurmd :$slurmd_port)"

# A small recording, one process's result, then the same job as a 3-task array and its merge.
cd "$tmp/work" || fail "no work folder"
"$evkit" synth --recording --preset planes --size 48x36 --blur-px 5 --exposure-us 40000 \
  --frames 3 --frame-interval-us 50000 --supersample 1 --out rec 2>/dev/null || fail "evkit synth failed"
run_job() {  # METHOD [settings...]: reference and Slurm run, compared
  local name=$1
  shift
  local args=(--calib rec/calib.txt --ground-truth rec/gt --latent 3 --method "$@")
  "$evkit" deblur --recording rec/recording.h5 --frames all "${args[@]}" --out "ref-$name" \
    2>"ref-$name.log" || fail "$name: the single-process run failed: $(tail -n 2 "ref-$name.log")"
  local submitted
  submitted=$(EVKIT="$evkit" "$source_dir/scripts/slurm/submit-recording.sh" rec/recording.h5 \
    "$tmp/work/slurm-$name" 3 "${args[@]}") || fail "$name: submission failed: $submitted"
  echo "$name: $submitted"
  local merge=${submitted##*merge job }
  merge=${merge%% *}
  for _ in $(seq 480); do
    [ -z "$(squeue -h -j "$merge" 2>/dev/null)" ] && [ -z "$(squeue -h 2>/dev/null)" ] && break
    sleep 0.5
  done
  [ -z "$(squeue -h 2>/dev/null)" ] && echo "$name: the array and the merge finished" ||
    fail "$name: jobs still queued after 240 s: $(squeue -h)"
  [ -f "slurm-$name/frames.csv" ] || fail "$name: the merge wrote no frames.csv: $(cat evkit-*.out 2>/dev/null | tail -n 5)"
  cut -d, -f1-5,7- "ref-$name/frames.csv" >"ref-$name.csv"
  cut -d, -f1-5,7- "slurm-$name/frames.csv" >"slurm-$name.csv"
  diff "ref-$name.csv" "slurm-$name.csv" || fail "$name: frames.csv differs from the single-process run"
  (cd "ref-$name/frames" && find . -name '*.png' -o -name trajectory.txt) | sort >"files-$name"
  [ -s "files-$name" ] || fail "$name: no frame outputs"
  while read -r f; do
    cmp -s "ref-$name/frames/$f" "slurm-$name/frames/$f" || fail "$name: $f differs"
  done <"files-$name"
  cmp -s "ref-$name/latent.avi" "slurm-$name/latent.avi" || fail "$name: latent.avi differs"
  echo "$name: merged Slurm output equals the single-process run ($(wc -l <"files-$name") files, 3 frames)"
}
run_job edi edi
run_job benerf benerf --set iterations=60 --set table=10 --set levels=2 --set rays=256
grep -h "shard" evkit-deblur-*.out | head -n 6
echo "PASS"

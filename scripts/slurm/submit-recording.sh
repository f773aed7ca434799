#!/bin/bash
# Deblurs a whole recording on a Slurm cluster: an array of SHARDS tasks, then the merge.
#
#   scripts/slurm/submit-recording.sh REC.aedat4 OUT SHARDS [evkit deblur options] [-- evkit video options]
#   scripts/slurm/submit-recording.sh rec.aedat4 /scratch/rec-sharp 16 --method benerf --set budget=fast -- --video latent.mp4
#
# Extra sbatch options (partition, account, time, CPUs per task) go in $SBATCH_OPTIONS. Prints the
# two job ids; `squeue -u $USER` follows them, OUT/frames.csv and OUT/latent.avi are the result.
set -euo pipefail
if [ $# -lt 3 ]; then
  echo "usage: $0 RECORDING OUT SHARDS [evkit deblur options] [-- evkit video options]" >&2
  exit 2
fi
recording=$1 out=$2 shards=$3
shift 3
deblur_args=() video_args=()
while [ $# -gt 0 ]; do
  if [ "$1" = "--" ]; then
    shift
    video_args=("$@")
    break
  fi
  deblur_args+=("$1")
  shift
done
if ! [[ "$shards" =~ ^[1-9][0-9]*$ ]]; then
  echo "$0: SHARDS must be a positive integer, not '$shards'" >&2
  exit 2
fi
here=$(cd "$(dirname "$0")" && pwd)
# shellcheck disable=SC2086  # SBATCH_OPTIONS holds several options
array=$(sbatch --parsable ${SBATCH_OPTIONS:-} --array=0-$((shards - 1)) \
  "$here/deblur-recording.sbatch" "$recording" "$out" "${deblur_args[@]}")
array=${array%%;*}
# shellcheck disable=SC2086
merge=$(sbatch --parsable ${SBATCH_OPTIONS:-} --dependency=afterok:"$array" \
  "$here/merge-recording.sbatch" "$out" "${video_args[@]}")
merge=${merge%%;*}
echo "array job $array ($shards shards), merge job $merge (after the array succeeds) -> $out"

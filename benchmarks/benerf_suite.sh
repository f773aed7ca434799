#!/usr/bin/env bash
# The deblurring comparison on the synthetic suite: blurry, EDI and BeNeRF at one budget, per scene,
# with PSNR/SSIM of the mid frame, the rotation error of the exposure and the wall time.
#   bash benchmarks/benerf_suite.sh EVKIT SUITE_DIR OUT_DIR [benerf settings...]
# e.g. bash benchmarks/benerf_suite.sh build/cli/evkit suite out budget=fast
set -euo pipefail
evkit=$1 suite=$2 out=$3
shift 3
sets=()
for kv in "$@"; do sets+=(--set "benerf.$kv"); done
mkdir -p "$out"
for scene in "$suite"/*/; do
  name=$(basename "$scene")
  [ -d "$out/$name" ] && continue  # finished earlier
  "$evkit" compare "$scene" --methods blurry,edi,benerf "${sets[@]}" --latent 1 --out "$out/$name.partial" > "$out/$name.log" 2>&1
  mv "$out/$name.partial" "$out/$name"
done
/usr/bin/python3 "$(dirname "$0")/benerf_report.py" "$suite" "$out"

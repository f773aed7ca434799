#!/usr/bin/env bash
# One BeNeRF frame at the default threads=auto while another program's load leaves or comes, for
# BENCHMARKS.md "Beside another program" (time it as a whole, e.g. against another build):
#   bash benchmarks/beside_load.sh EVKIT OBS leaves|comes OUT [deblur options...]
# leaves: a busy process starts 0.5 s before the frame and is killed 3 s later;
# comes: a busy process starts 2 s into the frame and runs to its end.
set -u
if [ $# -lt 4 ] || { [ "$3" != leaves ] && [ "$3" != comes ]; }; then
  echo "usage: $0 EVKIT OBS leaves|comes OUT [deblur options...]" >&2
  exit 2
fi
evkit=$1 obs=$2 mode=$3 out=$4
shift 4
busy=(python3 -c "while True: pass")
if [ "$mode" = leaves ]; then
  "${busy[@]}" &
  spinner=$!
  sleep 0.5
  (sleep 3 && kill "$spinner" 2>/dev/null) &
  killer=$!
else
  (sleep 2 && exec "${busy[@]}") &
  spinner=$!
  killer=
fi
"$evkit" deblur "$obs" --method benerf --set budget=fast --out "$out" "$@" > /dev/null
status=$?
kill "$spinner" 2>/dev/null
wait "$spinner" 2>/dev/null
[ -n "$killer" ] && wait "$killer" 2>/dev/null
exit $status

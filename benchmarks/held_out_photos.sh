#!/usr/bin/env bash
# The natural scenes' layouts with photographs that no suite uses, for BENCHMARKS.md "Outside the
# suites: photographs not in them": 24 observations (shakes, blurs and seeds of no suite; the first
# eleven at 22, 35 and 48 px of blur, the other thirteen at 25 and 40 px; 11 with the noisy
# suite's events), EDI and BeNeRF `fast` on each, then a table of PSNR at mid-exposure:
#   bash benchmarks/held_out_photos.sh EVKIT OUT [--unknown-contrast] [--suite-photos|--more-shakes|--new-shakes]
# The photographs are python3-skimage's other data images, each linked under the file name of the
# suite photograph it stands in for ($EVKIT_PHOTOS names another skimage data folder). With
# --suite-photos, twelve other shakes (seeds 801-812, 25 and 40 px, four in colour) on the suite's
# own photographs instead, into OUT/suite-photos. With --more-shakes, fourteen more shakes of the
# same layouts and photographs (seeds 901-914, 36-46 px, six noisy), measured after the
# registration's bar was set (BENCHMARKS.md, "What the registration's misfit measures"), into
# OUT/more-shakes. With --new-shakes, ten more (seeds 951-960, 30-50 px, seven noisy), measured
# after the refit on the points that fired (BENCHMARKS.md, "Where few events fired"), into
# OUT/new-shakes. Runs that finished are kept; remove OUT/runs to repeat them.
set -u
usage() { echo "usage: $0 EVKIT OUT [--unknown-contrast] [--suite-photos|--more-shakes|--new-shakes]" >&2; exit 2; }
[ $# -ge 2 ] || usage
evkit=$1 out=$2 unknown='' suite_photos='' more_shakes='' new_shakes=''
shift 2
for option in "$@"; do
  case $option in
    --unknown-contrast) unknown=1 ;;
    --suite-photos) suite_photos=1 ;;
    --more-shakes) more_shakes=1 ;;
    --new-shakes) new_shakes=1 ;;
    *) usage ;;
  esac
done
data=${EVKIT_PHOTOS:-/usr/lib/python3/dist-packages/skimage/data}
[ $(( ${suite_photos:-0} + ${more_shakes:-0} + ${new_shakes:-0} )) -gt 1 ] && usage
[ -n "$suite_photos" ] && out=$out/suite-photos
[ -n "$more_shakes" ] && out=$out/more-shakes
[ -n "$new_shakes" ] && out=$out/new-shakes
mkdir -p "$out/photos" "$out/obs" "$out/runs" || exit 1
# suite file name -> the photograph that stands in for it
while read -r suite other; do
  [ -f "$data/$other" ] || { echo "$0: $data/$other: no such photograph" >&2; exit 1; }
  ln -sfn "$data/$other" "$out/photos/$suite"
done <<'EOF'
astronaut.png motorcycle_right.png
hubble_deep_field.jpg motorcycle_right.png
coffee.png ihc.png
brick.png moon.png
coins.png moon.png
chelsea.png retina.jpg
grass.png microaneurysms.png
camera.png phantom.png
gravel.png cell.png
rocket.jpg page.png
text.png page.png
EOF
noise=(--sigma 0.03 --shot-noise-hz 1 --leak-hz 0.1)
status=0
# The photographs' folder (none: the suite's own), and the observations: scene, blur (px), seed,
# share of the image motion from rotation, noise (n) or not (-), colour (c) or grey (-).
photos=(--photos "$out/photos")
if [ -n "$suite_photos" ]; then
  photos=()
  frames="coffee_astronaut 40 801 0.6 - c
cat_bricks 25 802 0.3 - -
cameraman_grass 25 803 0.6 n -
rocket_layers 40 804 0.5 - -
four_layers 40 805 0.3 n -
slanted_bricks 25 806 0.7 - -
gravel_ground 40 807 0.4 n -
coffee_plane 25 808 0.5 - c
astronaut_plane 25 809 0.4 n c
hubble_rocket 40 810 0.7 - -
text_coins 40 811 0.6 n -
motorcycle 25 812 0.4 - c"
elif [ -n "$new_shakes" ]; then
  frames="four_layers 40 951 0.5 n -
four_layers 50 952 0.3 n -
four_layers 30 953 0.6 - -
cameraman_grass 44 954 0.4 n -
cat_bricks 42 955 0.5 n -
rocket_layers 46 956 0.4 n -
text_coins 40 957 0.5 n -
hubble_rocket 48 958 0.6 n -
four_layers 44 959 0.4 - -
cat_bricks 50 960 0.3 - -"
elif [ -n "$more_shakes" ]; then
  frames="coffee_astronaut 45 901 0.4 - -
cat_bricks 44 902 0.5 n -
cameraman_grass 46 903 0.6 - -
rocket_layers 42 904 0.3 n -
four_layers 44 905 0.6 - -
slanted_bricks 46 906 0.5 n -
gravel_ground 42 907 0.4 - -
coffee_plane 44 908 0.7 n -
astronaut_plane 46 909 0.3 - -
hubble_rocket 42 910 0.5 n -
text_coins 45 911 0.4 - -
cameraman_grass 36 912 0.5 n -
cat_bricks 36 913 0.4 - -
four_layers 36 914 0.5 n -"
else
  frames="coffee_astronaut 35 601 0.5 n -
cat_bricks 48 602 0.6 - -
cameraman_grass 22 603 0.7 n -
rocket_layers 35 604 0.4 - -
four_layers 48 605 0.5 n -
slanted_bricks 22 606 0.6 - -
gravel_ground 35 607 0.7 n -
coffee_plane 48 608 0.4 - -
astronaut_plane 22 609 0.5 n -
hubble_rocket 35 610 0.6 - -
text_coins 48 611 0.7 n -
coffee_astronaut 25 701 0.3 - -
cat_bricks 40 702 0.5 n -
cameraman_grass 40 703 0.4 - -
rocket_layers 25 704 0.6 n -
four_layers 25 705 0.7 - -
slanted_bricks 40 706 0.3 n -
gravel_ground 25 707 0.5 - -
coffee_plane 40 708 0.6 n -
astronaut_plane 40 709 0.7 - -
hubble_rocket 25 710 0.4 n -
text_coins 25 711 0.5 - -
cat_bricks 25 713 0.6 - -
four_layers 40 714 0.4 n -"
fi
while read -r scene blur seed share noisy colour; do
  name=${scene}_blur${blur}
  extra=()
  if [ "$noisy" = n ]; then name=${name}_noisy extra=("${noise[@]}"); fi
  if [ "$colour" = c ]; then name=${name}_colour extra+=(--colour); fi
  obs=$out/obs/$name
  if [ ! -d "$obs" ]; then
    "$evkit" synth --preset "$scene" --blur-px "$blur" --seed "$seed" --rotation-share "$share" \
      --share-of-image-motion --preroll-us 30000 "${extra[@]}" "${photos[@]}" \
      --out "$obs" > /dev/null || { status=1; continue; }
  fi
  input=$obs tag=given
  if [ -n "$unknown" ]; then  # the same folder without contrast.txt
    input=$out/obs-unknown/$name tag=unknown
    mkdir -p "$input"
    for f in "$obs"/*; do [ "${f##*/}" = contrast.txt ] || ln -sfn "$(realpath "$f")" "$input/"; done
  fi
  for method in edi benerf; do
    run=$out/runs/$name/${method}_$tag
    [ -f "$run/summary.json" ] && continue
    opts=()
    [ "$method" = benerf ] && opts=(--set budget=fast)
    "$evkit" deblur "$input" --method "$method" "${opts[@]}" --out "$run" > /dev/null || status=1
  done
done <<< "$frames"
python3 - "$out/runs" "${unknown:+unknown}" <<'EOF' || status=1
import json, os, sys
runs, tag = sys.argv[1], sys.argv[2] or "given"
print("| observation | EDI | BeNeRF `fast` | BeNeRF - EDI | wall (s) | representation |")
print("|---|---:|---:|---:|---:|---|")
edi_sum = benerf_sum = count = 0
for name in sorted(os.listdir(runs)):
    try:
        edi = json.load(open(f"{runs}/{name}/edi_{tag}/summary.json"))
        ben = json.load(open(f"{runs}/{name}/benerf_{tag}/summary.json"))
    except OSError:
        continue
    e, b, p = edi["metrics"]["psnr_mid"], ben["metrics"]["psnr_mid"], ben["parameters"]
    if p.get("representation_pixels"):
        rep = "grid, " + ("pixel depth" if p.get("representation_pixel_depth")
                          else "tiles" if p.get("representation_depth") else "plane")
    else:
        rep = "hash field"
    print(f"| {name} | {e:.2f} | {b:.2f} | {b - e:+.2f} | {ben['wall_time_s']:.1f} | {rep} |")
    edi_sum, benerf_sum, count = edi_sum + e, benerf_sum + b, count + 1
if count:
    print(f"| mean of {count} | {edi_sum / count:.2f} | {benerf_sum / count:.2f} | "
          f"{(benerf_sum - edi_sum) / count:+.2f} | | |")
EOF
exit $status

#!/usr/bin/env bash
# Installs evkit's build and test dependencies from Debian 12 packages (idempotent).
# Nothing is downloaded outside apt. Run as root (or with sudo available).
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config
  libeigen3-dev libboost-program-options-dev
  libhdf5-dev hdf5-filter-plugin hdf5-filter-plugin-blosc-serial zlib1g-dev libblosc-dev libbz2-dev
  libopencv-dev libopencv-contrib-dev opencv-data
  liblz4-dev libzstd-dev libflatbuffers-dev flatbuffers-compiler
  libgtest-dev libgmock-dev libbenchmark-dev
  clang libclang-rt-14-dev
  python3 python3-h5py python3-numpy python3-lz4
  python3-dev pybind11-dev python3-pytest python3-matplotlib  # the Python module, its tests, examples
  slurmctld slurmd slurm-client munge  # the Slurm integration test (a single node on localhost)
  python3-skimage  # its CC0 / public-domain photographs: the natural suite's scenes
)

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then sudo_cmd=(sudo); fi
echo "install-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -qq
"${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "install-deps: done"

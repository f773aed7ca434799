#!/usr/bin/env bash
# The README's first command: install what is missing, build evkit (Release), run the main job on
# its built-in default. Output goes to ./evkit-demo.
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/install-deps.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release -DEVKIT_BUILD_TESTS=OFF -DEVKIT_BUILD_BENCHMARKS=OFF -DCMAKE_UNITY_BUILD=ON
cmake --build build -j "$(nproc)"
./build/cli/evkit demo --out evkit-demo

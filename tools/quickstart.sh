#!/usr/bin/env bash
# Install dependencies, build (Release) and run the main job: the paper's homogeneous cooling
# system (scenes/hcs.toml), from the peers' initial state. Outputs go to runs/hcs/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/install_deps.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build build -j "$(nproc)" --target cfddem
build/bin/cfddem run scenes/hcs.toml "$@"

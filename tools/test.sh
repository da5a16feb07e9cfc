#!/usr/bin/env bash
# Install dependencies, build (Release) and run the whole test suite. CI runs exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/install_deps.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release -DCFDDEM_WERROR=ON
cmake --build build -j "$(nproc)"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
cd build && ctest --output-on-failure -j "$(nproc)"
# CFDDEM_SANITIZE=1: also build the asan-ubsan preset and run the suite under AddressSanitizer +
# UndefinedBehaviorSanitizer (about 2 min of tests on 2 cores, plus the build).
if [ "${CFDDEM_SANITIZE:-0}" = 1 ]; then
  cd ..
  cmake --preset asan-ubsan
  cmake --build --preset asan-ubsan -j "$(nproc)"
  ctest --preset asan-ubsan -j "$(nproc)"
fi

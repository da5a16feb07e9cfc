#!/usr/bin/env bash
# Install dependencies, build (Release) and run the whole test suite. CI runs exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/install_deps.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release -DCFDDEM_WERROR=ON
cmake --build build -j "$(nproc)"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
cd build && ctest --output-on-failure -j "$(nproc)"
# Then the asan-ubsan preset: the suite again under AddressSanitizer + UndefinedBehaviorSanitizer
# (about 3 min of tests on 2 cores, plus the build). CFDDEM_SANITIZE=0 skips it.
if [ "${CFDDEM_SANITIZE:-1}" = 1 ]; then
  cd ..
  cmake --preset asan-ubsan
  cmake --build --preset asan-ubsan -j "$(nproc)"
  ctest --preset asan-ubsan -j "$(nproc)"
fi

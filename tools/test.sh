#!/usr/bin/env bash
# Install dependencies, build (Release) and run the tests. CI runs exactly this.
#   1. the unit suite (ctest -L unit: a few seconds per test, about 1 min on 2 cores),
#   2. the validation suite (ctest -L validation: end-to-end runs, MPI runs, Python tools),
#   3. the unit suite again under AddressSanitizer + UndefinedBehaviorSanitizer (the asan-ubsan
#      preset, its own build); CFDDEM_SANITIZE=0 skips it.
# Every test carries one of the two labels (docs/testing.md).
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/install_deps.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release -DCFDDEM_WERROR=ON
cmake --build build -j "$(nproc)"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
(cd build && ctest --output-on-failure -j "$(nproc)" -L unit)
(cd build && ctest --output-on-failure -j "$(nproc)" -L validation)
if [ "${CFDDEM_SANITIZE:-1}" = 1 ]; then
  cmake --preset asan-ubsan
  cmake --build --preset asan-ubsan -j "$(nproc)"
  ctest --preset asan-ubsan -j "$(nproc)" -L unit
fi

#!/usr/bin/env bash
# Strong and weak scaling of the 1e5 riser (and a short strong run of the 1e5 bed) on a
# many-core node in one go, the way docs/performance.md "Scaling on 16 cores" was measured.
#
# usage: tools/device_scaling.sh OUT BINARY [LAUNCHER]
#   OUT       folder for the CSVs, plots, meta files and the run folders (run.json per run)
#   BINARY    the cfddem to run; LAUNCHER defaults to mpirun (orterun on the bundled device)
#
# Stages, each written as it goes (a run cut short still leaves the rows before it):
#   1. strong: tools/scaling_results/model/scenes/riser_1e5.toml, 10 fluid steps (1 ms), every
#      scheme, 1-16 cores as ranks only, threads only and 4-thread hybrids;
#   2. weak: the riser at 6.25e4 particles per core (1e6 at 16 cores), 10 fluid steps, ranks
#      only and hybrids, lateral cell counts multiples of 16 (--cell-multiple: counts such as
#      270 = 2 x 135 stop the gas's multigrid after one level, and its coarse level, solved on
#      rank 0 alone, then held the 2026-12-04 run at 0.07 efficiency on 16 ranks);
#   3. strong: the 1e5 fluidized bed, 5 fluid steps, 1, 2, 4 and 16 cores, ranks and threads.
set -u
out=$1
bin=$2
launcher=${3:-mpirun}
py=${PYTHON:-python3}
here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$out"
lscpu > "$out/lscpu.txt" 2>&1 || true
nproc > "$out/nproc.txt"
common=(--binary "$bin" --launcher "$launcher" --binding none --timeout 150)
note="device node, $(nproc) cores: $(lscpu 2>/dev/null | sed -n 's/^Model name: *//p' | head -1)"

stage() { echo "== $(date -u +%T) $*" | tee -a "$out/stages.log"; }

stage strong riser 1e5
"$py" "$here/scaling.py" strong --scene "$here/scaling_results/model/scenes/riser_1e5.toml" \
  --cores 1 2 4 8 16 --layouts ranks-only threads-only hybrid --end-time 1e-3 \
  --note "$note" --out "$out/strong_riser" "${common[@]}" 2>&1 | tail -5

stage weak riser 6.25e4 per core
"$py" "$here/scaling.py" weak --base riser --particles-per-core 6.25e4 --cell-multiple 16 \
  --cores 1 2 4 8 16 --layouts ranks-only hybrid --end-time 1e-3 \
  --note "$note" --out "$out/weak_riser" "${common[@]}" 2>&1 | tail -5

stage strong bed 1e5
"$py" "$here/scaling.py" strong --scene "$here/scaling_results/model/scenes/fluidized_bed_1e5.toml" \
  --cores 1 2 4 16 --layouts ranks-only threads-only --end-time 5e-4 \
  --note "$note" --out "$out/strong_bed" "${common[@]}" 2>&1 | tail -5
stage done

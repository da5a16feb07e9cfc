#!/bin/bash
# Two cfddem binaries, run side by side on short scenes (every scheme; with and without a gas;
# walls and periodic boxes), on 1 rank and on 2, fresh and restarted from the first binary's
# checkpoints on the same and the other rank count; each pair of run directories compared bit
# for bit, timing aside (tools/compare_runs.py). For a change that must not change results: a
# refactor, a faster search, a new build. A run that fails must fail alike in both.
# Usage: tools/compare_binaries.sh OLD_BIN NEW_BIN [WORK_DIR]   (exit 1 on any difference)
# About 3 minutes on 2 cores.
set -u
if [ $# -lt 2 ]; then
  echo "usage: $0 OLD_BIN NEW_BIN [WORK_DIR]" >&2
  exit 2
fi
OLD=$(realpath "$1")
NEW=$(realpath "$2")
HERE=$(cd "$(dirname "$0")" && pwd)
SRC=$HERE/../scenes
W=${3:-$(mktemp -d /tmp/compare_binaries.XXXXXX)}
PY=${PYTHON:-/usr/bin/python3}
export OMPI_ALLOW_RUN_AS_ROOT=${OMPI_ALLOW_RUN_AS_ROOT:-1}
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=${OMPI_ALLOW_RUN_AS_ROOT_CONFIRM:-1}
rm -rf "$W" && mkdir -p "$W/old" "$W/new" "$W/ck"
echo "comparing $OLD against $NEW in $W"
fail=0 total=0

HCS="$SRC/hcs_small.toml run.end_time=0.004 output.interval=2e-4 output.snapshot_interval=2e-3 output.checkpoint_interval=2e-3"
FRIC="dem.friction=0.5 domain.hi=[0.64e-3,0.64e-3,0.64e-3] run.end_time=0.002 output.snapshot_interval=1e-3 output.checkpoint_interval=1e-3"
BOX="$SRC/box_gravity.toml run.end_time=0.004 output.interval=2e-4 output.snapshot_interval=2e-3 output.checkpoint_interval=2e-3"
RISER="$SRC/riser.toml domain.hi=[2.4e-3,4.0e-3,2.4e-3] particles.count=800 particles.temperature=1e-4 fluid.cells=[12,20,12] output.interval=2e-4 output.snapshot_interval=1e-3 output.checkpoint_interval=1e-3 run.end_time=2e-3"
SETTLE="$SRC/settling.toml run.end_time=2e-3 output.interval=2e-4 output.snapshot_interval=1e-3 output.checkpoint_interval=1e-3"
HCSGAS="$SRC/hcs_gas.toml run.end_time=6e-4 output.interval=2e-4 output.snapshot_interval=4e-4 output.checkpoint_interval=4e-4"

# name|scene and settings
CASES=(
  "hcs_explicit|$HCS"
  "hcs_explicit_friction|$HCS $FRIC"
  "hcs_orb|$HCS dem.scheme=orb"
  "hcs_orb_friction|$HCS dem.scheme=orb $FRIC"
  "hcs_islands|$HCS dem.scheme=islands dem.nsubit=10"
  "hcs_islands_friction|$HCS dem.scheme=islands dem.nsubit=10 $FRIC"
  "hcs_islands_auto|$HCS dem.scheme=islands dem.nsubit=auto"
  "box_explicit|$BOX"
  "box_orb|$BOX dem.scheme=orb"
  "box_islands|$BOX dem.scheme=islands dem.nsubit=10"
  "riser_explicit|$RISER"
  "riser_orb|$RISER dem.scheme=orb dem.nsubit=10"
  "riser_islands|$RISER dem.scheme=islands dem.nsubit=10"
  "settling_explicit|$SETTLE"
  "settling_islands|$SETTLE dem.scheme=islands dem.nsubit=10"
  "hcsgas_explicit|$HCSGAS"
)

launch() { # ranks bin args...
  local np=$1 bin=$2
  shift 2
  if [ "$np" = 1 ]; then "$bin" run "$@"; else mpirun -np "$np" --oversubscribe "$bin" run "$@"; fi
}

check() { # label dir
  total=$((total + 1))
  echo "== $1"
  if [ -f "$W/old/$2.rc" ] || [ -f "$W/new/$2.rc" ]; then
    # A run refused (e.g. a restart across rank counts a scheme does not take): both alike?
    # The logs with process ids, addresses and the binary's path taken out.
    norm() { sed -E -e "s#$OLD|$NEW#BIN#g" -e 's/0x[0-9a-f]+|[0-9]+//g' "$1"; }
    if cmp -s "$W/old/$2.rc" "$W/new/$2.rc" && cmp -s <(norm "$W/old/$2.log") <(norm "$W/new/$2.log"); then
      echo "  both exited $(cat "$W/old/$2.rc") alike: $(grep -m1 -iE 'error|signal' "$W/old/$2.log" | cut -c1-120)"
    else
      echo "  DIFFERENT exit: old $(cat "$W/old/$2.rc" 2>/dev/null) new $(cat "$W/new/$2.rc" 2>/dev/null)"; fail=$((fail + 1))
    fi
    return
  fi
  if [ ! -d "$W/old/$2" ] || [ ! -d "$W/new/$2" ]; then
    echo "  MISSING run directory"; fail=$((fail + 1)); return
  fi
  "$PY" "$HERE/compare_runs.py" "$W/old/$2" "$W/new/$2" || fail=$((fail + 1))
}

for c in "${CASES[@]}"; do
  name=${c%%|*}
  read -r -a args <<<"${c#*|}"
  scene=${args[0]}
  sets=("${args[@]:1}")
  for np in 1 2; do
    d="${name}_np$np"
    for side in old new; do
      bin=$OLD; [ $side = new ] && bin=$NEW
      (cd "$W/$side" && launch $np "$bin" "$scene" --out "$d" "${sets[@]}" --threads 1 --quiet \
        >"$d.log" 2>&1) || echo $? >"$W/$side/$d.rc"
    done
    check "$name, $np rank(s)" "$d"
    # Restart both from the old binary's first checkpoint (the same file), on the same rank count, and
    # on the other one (a 1-rank checkpoint on 2 ranks and back).
    ck=$(ls "$W/old/$d"/checkpoint_*.h5 2>/dev/null | head -1)
    [ -n "$ck" ] || continue
    cp "$ck" "$W/ck/$d.h5"
    for rnp in 1 2; do
      r="${d}_restart_np$rnp"
      for side in old new; do
        bin=$OLD; [ $side = new ] && bin=$NEW
        (cd "$W/$side" && launch $rnp "$bin" "$scene" --out "$r" --restart "$W/ck/$d.h5" \
          "${sets[@]}" --threads 1 --quiet >"$r.log" 2>&1) || echo $? >"$W/$side/$r.rc"
      done
      check "$name, checkpoint of $np rank(s) restarted on $rnp" "$r"
    done
  done
done
echo "== $((total - fail)) of $total comparisons identical"
[ $fail = 0 ]

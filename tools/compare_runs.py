#!/usr/bin/python3
"""Compare two cfddem run directories bit for bit, timing aside.

Usage: compare_runs.py A B [-v]   (tools/compare_binaries.sh runs it on every pair)
- diagnostics.csv, profiles.csv: byte-equal once the wall_seconds column is dropped.
- *.h5 (snapshots, checkpoints): every dataset and attribute byte-equal, except a `rows`-like
  dataset's wall_seconds column (checkpoints carry the diagnostics rows) and timing attributes.
- run.json: every key equal except the timing ones (seconds, rates, waits).
Prints one line per file; exit 1 on any difference.
"""
import csv
import io
import json
import os
import sys

import h5py
import numpy as np

A, B = sys.argv[1], sys.argv[2]
VERBOSE = len(sys.argv) > 3
bad = []


def csv_sans_wall(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    if not rows:
        return ""
    keep = [i for i, c in enumerate(rows[0]) if c != "wall_seconds"]
    out = io.StringIO()
    for r in rows:
        out.write(",".join(r[i] for i in keep if i < len(r)) + "\n")
    return out.getvalue(), (rows[0].index("wall_seconds") if "wall_seconds" in rows[0] else None)


WALL_COL = {}


def h5_items(path):
    items = {}

    def visit(name, obj):
        for k, v in obj.attrs.items():
            items[f"{name}@{k}"] = np.asarray(v)
        if isinstance(obj, h5py.Dataset):
            items[name] = obj[()]

    with h5py.File(path, "r") as f:
        for k, v in f.attrs.items():
            items[f"/@{k}"] = np.asarray(v)
        f.visititems(visit)
    return items


TIMING_WORDS = ("second",)  # run.json: loop_seconds, phase_seconds.*, ..._per_second, ...


def is_timing(key):
    k = key.lower()
    return any(w in k for w in TIMING_WORDS)


def cmp_h5(name):
    a, b = h5_items(os.path.join(A, name)), h5_items(os.path.join(B, name))
    diffs = []
    if sorted(a) != sorted(b):
        diffs.append(f"keys differ: {sorted(set(a) ^ set(b))}")
    skipped = []
    checksum = False
    for k in sorted(set(a) & set(b)):
        x, y = np.asarray(a[k]), np.asarray(b[k])
        if x.dtype != y.dtype or x.shape != y.shape:
            diffs.append(f"{k}: dtype/shape {x.dtype}{x.shape} vs {y.dtype}{y.shape}")
            continue
        if x.dtype.kind == "O":
            same = list(x.ravel()) == list(y.ravel())
        else:
            same = x.tobytes() == y.tobytes()
        if same:
            continue
        # The diagnostics rows kept in a checkpoint: all but the wall_seconds column.
        # (stored flat, a row after the other).
        col, nc = WALL_COL.get("diag"), WALL_COL.get("ncols", 0)
        if (col is not None and x.size % nc == 0 and x.dtype.kind == "f"
                and np.delete(x.reshape(-1, nc), col, 1).tobytes()
                == np.delete(y.reshape(-1, nc), col, 1).tobytes()):
            skipped.append(f"{k}[:,wall_seconds]")
            continue
        if k == "/@checksum":  # the file's checksum covers the rows' wall_seconds too
            checksum = True
            continue
        diffs.append(f"{k} differs")
    if checksum:
        # Only wall_seconds may differ: then the checksum alone differs with it.
        if any("wall_seconds" in k for k in skipped) and not diffs:
            skipped.append("/@checksum")
        else:
            diffs.append("/@checksum differs")
    return diffs, skipped


def cmp_json(name):
    a = json.load(open(os.path.join(A, name)))
    b = json.load(open(os.path.join(B, name)))
    diffs, skipped = [], []

    def walk(x, y, path):
        if isinstance(x, dict) and isinstance(y, dict):
            if list(x) != list(y):
                diffs.append(f"{path}: keys {list(x)} vs {list(y)}")
            for k in x:
                if k in y:
                    walk(x[k], y[k], f"{path}.{k}")
            return
        if x != y:
            (skipped if is_timing(path) or ".phase_seconds" in path else diffs).append(path)

    walk(a, b, "")
    return diffs, skipped


def listing(s):
    return ": " + " ".join(s) if VERBOSE else ""


names = sorted(set(os.listdir(A)) | set(os.listdir(B)))
for n in names:
    if not (os.path.exists(os.path.join(A, n)) and os.path.exists(os.path.join(B, n))):
        bad.append(n)
        print(f"  {n}: only in one directory")
        continue
    if n.endswith(".csv"):
        (ta, ca), (tb, cb) = csv_sans_wall(os.path.join(A, n)), csv_sans_wall(os.path.join(B, n))
        if n == "diagnostics.csv" and ca is not None:
            with open(os.path.join(A, n)) as f:
                WALL_COL.update(diag=ca, ncols=len(f.readline().split(",")))
        ok = ta == tb
        print(f"  {n}: {'identical' if ok else 'DIFFERENT'} (sans wall_seconds)")
        if not ok:
            bad.append(n)
for n in names:
    if n in bad or not os.path.exists(os.path.join(A, n)):
        continue
    if n.endswith(".h5"):
        d, s = cmp_h5(n)
    elif n.endswith(".json"):
        d, s = cmp_json(n)
    else:
        continue
    print(f"  {n}: {'identical' if not d else 'DIFFERENT ' + '; '.join(d[:6])}"
          + (f" (timing aside: {len(s)}{listing(s)})" if s else ""))
    if d:
        bad.append(n)
sys.exit(1 if bad else 0)

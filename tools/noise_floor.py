"""The chaos floor of a trade measurement: how far two explicit runs drift apart when their
initial states differ by round-off alone.

A granular gas is chaotic: a relative change of 1e-12 in the initial positions grows by a factor
of order e per mean free time, so after a few collision times two explicit runs differ by the
ensemble's own fluctuation. An adaptive scheme's error measured against one explicit reference
cannot be told from that spread, whatever the scheme does. This module

  1. writes the scene's initial state as a particle CSV (from the scene's own file, or from the
     t = 0 snapshot of a short run for a generated scene) and a copy of the scene that reads it;
  2. writes K - 1 copies of that state whose positions are moved by
     delta = rel * L_axis * u,  u ~ uniform(-1, 1) per coordinate, one seed per copy
     (L_axis the domain's extent; rel = 1e-12 by default, a few hundred ulps of a position);
  3. reduces the perturbed runs to a floor per observable and per time window: the largest
     relative error of a perturbed run against the reference, with the same error definition
     as the scheme's (mean |O - O_ref| / mean |O_ref| over the window's rows).

Uses only numpy, h5py (to read a snapshot) and tomllib (Python 3.11).
"""
import csv
import glob
import os
import subprocess
import sys
import tomllib

import numpy as np

# Generator keys that a particle file replaces (the scene parser refuses both at once).
GENERATOR_KEYS = ("count", "diameter", "density", "temperature", "velocity", "placement",
                  "region_lo", "region_hi", "seed", "allow_overlap")


def _toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)  # repr round-trips a double exactly
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"noise_floor: cannot write TOML value {v!r}")


def _flatten(table, prefix=""):
    for k, v in table.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            yield from _flatten(v, key + ".")
        else:
            yield key, v


def write_scene_with_file(scene, csv_path, out_path):
    """The scene with its particle generator (or file) replaced by csv_path (absolute), as dotted
    top-level keys. Every other key is kept with its exact value."""
    with open(scene, "rb") as f:
        table = tomllib.load(f)
    lines = [f"# {os.path.basename(scene)} with its initial state read from a file (noise floor)"]
    for key, v in _flatten(table):
        if key == "particles.file" or (key.startswith("particles.")
                                       and key.split(".", 1)[1] in GENERATOR_KEYS):
            continue
        lines.append(f"{key} = {_toml_value(v)}")
    lines.append(f"particles.file = {_toml_value(os.path.abspath(csv_path))}")
    with open(out_path, "w") as f:
        f.write("\n".join(lines) + "\n")


def generator_override(arg):
    """True for a command-line override that the particle file replaces."""
    key = arg.split("=", 1)[0].strip()
    return key == "particles.file" or (key.startswith("particles.")
                                       and key.split(".", 1)[1] in GENERATOR_KEYS)


def read_particle_csv(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    cols = ["x", "y", "z", "vx", "vy", "vz", "diameter", "density"]
    missing = [c for c in cols if c not in rows[0]]
    if missing:
        sys.exit(f"noise_floor: {path}: missing columns {missing}")
    return {c: np.array([float(r[c]) for r in rows]) for c in cols}


def write_particle_csv(state, path):
    cols = ["x", "y", "z", "vx", "vy", "vz", "diameter", "density"]
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        f.write(",".join(cols) + "\n")
        for i in range(len(state["x"])):
            f.write(",".join(repr(float(state[c][i])) for c in cols) + "\n")
    os.replace(tmp, path)


def initial_state(binary, scene, overrides, workdir):
    """The scene's initial particle state as CSV columns. A scene with particles.file is read
    directly (path relative to the scene); a generated scene is run to its first output row with
    a t = 0 snapshot, which is read back (ids sorted, so the order is the generator's)."""
    with open(scene, "rb") as f:
        table = tomllib.load(f)
    pfile = table.get("particles", {}).get("file")
    for o in overrides:
        if o.split("=", 1)[0].strip() == "particles.file":
            pfile = o.split("=", 1)[1].strip().strip('"').strip("'")
    if pfile:
        path = pfile if os.path.isabs(pfile) else os.path.join(os.path.dirname(scene), pfile)
        return read_particle_csv(path)
    import h5py  # only needed for generated scenes

    out = os.path.join(workdir, "initial_state")
    interval = table.get("output", {}).get("interval", 1e-4)
    cmd = [binary, "run", scene, *overrides, f"run.end_time={interval}",
           f"output.snapshot_interval={interval}", "--threads", "1", "--quiet", "--overwrite",
           "--out", out]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        sys.exit(f"noise_floor: {' '.join(cmd)} failed:\n{res.stderr}")
    snaps = sorted(glob.glob(os.path.join(out, "snapshot_*.h5")))
    if not snaps:
        sys.exit(f"noise_floor: no snapshot written in {out}")
    density = float(table.get("particles", {}).get("density", 0.0))
    for o in overrides:
        if o.split("=", 1)[0].strip() == "particles.density":
            density = float(o.split("=", 1)[1])
    with h5py.File(snaps[0], "r") as h:
        if float(h.attrs["time"]) != 0.0:
            sys.exit(f"noise_floor: {snaps[0]} is not the t = 0 snapshot")
        p = h["particles"]
        order = np.argsort(p["id"][:])
        x, v, d = p["position"][:][order], p["velocity"][:][order], p["diameter"][:][order]
    return {"x": x[:, 0], "y": x[:, 1], "z": x[:, 2], "vx": v[:, 0], "vy": v[:, 1],
            "vz": v[:, 2], "diameter": d, "density": np.full(len(d), density)}


def perturbed(state, lo, hi, periodic, rel, seed):
    """A copy of state with every position coordinate moved by rel * L * u, u ~ U(-1, 1); a
    coordinate pushed across a periodic face is wrapped, one pushed into a wall is mirrored."""
    rng = np.random.default_rng(seed)
    out = {k: v.copy() for k, v in state.items()}
    for a, c in enumerate("xyz"):
        L = hi[a] - lo[a]
        x = out[c] + rel * L * rng.uniform(-1.0, 1.0, len(out[c]))
        if periodic[a]:
            x = lo[a] + np.mod(x - lo[a], L)
        else:
            x = np.where(x < lo[a], 2 * lo[a] - x, x)
            x = np.where(x > hi[a], 2 * hi[a] - x, x)
        out[c] = x
    return out


def domain_of(scene, overrides):
    with open(scene, "rb") as f:
        dom = tomllib.load(f)["domain"]
    lo, hi, per = dom["lo"], dom["hi"], dom.get("periodic", [False] * 3)
    for o in overrides:
        k, _, v = o.partition("=")
        k = k.strip()
        if k in ("domain.lo", "domain.hi", "domain.periodic"):
            val = tomllib.loads(f"v = {v}")["v"]
            {"domain.lo": lo, "domain.hi": hi, "domain.periodic": per}[k][:] = val
    return lo, hi, per


def windows(t_end, n):
    """n equal windows over (0, t_end]; the row at t = 0 (identical in every run) is left out."""
    edges = np.linspace(0.0, t_end, n + 1)
    return list(zip(edges[:-1], edges[1:]))


def window_error(t, o, t_ref, o_ref, w):
    """mean |O - O_ref| / mean |O_ref| over the rows of O inside window w = (a, b], O_ref
    interpolated linearly to O's times; nan when the window holds no row."""
    keep = (t > w[0]) & (t <= w[1] * (1 + 1e-12)) & (t <= t_ref[-1] * (1 + 1e-12))
    if not np.any(keep):
        return float("nan")
    o_at = np.interp(t[keep], t_ref, o_ref)
    den = np.mean(np.abs(o_at))
    num = np.mean(np.abs(o[keep] - o_at))
    if den == 0.0:
        return 0.0 if num == 0.0 else float("inf")
    return float(num / den)


def verdict(error, floor):
    """The scheme's error against the chaos floor: indistinguishable when it does not exceed the
    largest error that round-off alone produced in the same window."""
    if not np.isfinite(error):
        return "no rows in window"
    if error <= floor:
        return "indistinguishable from chaos"
    return f"scheme error {100 * error:.3g}% above the floor {100 * floor:.3g}%"

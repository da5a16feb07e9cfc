#!/usr/bin/python3
"""Side-by-side speed of cfddem's explicit DEM scheme against LAMMPS and LIGGGHTS on one core.

Cases (the peers' scenes, shared/peers/RESULTS.md):
  hcs1222     1222 particles, phi 0.01, periodic 4 mm box (scenes/hcs.toml), 30 ms = 207297 steps
  dilute100k  100000 particles, phi 0.01, L = 17.36466 mm, seed 2, 5000 steps
  dense100k   100000 particles, phi 0.30, L = 5.588464 mm, seed 3, 5000 steps
Same physics in all codes: d = 100 um, rho = 1000, k_n = 10 N/m, e = 0.8, frictionless, dt =
tau/50 = 1.447203e-7 s, Verlet skin 25 um (0.25 d) rebuilt when a particle has moved skin/2.
Every code reads the same initial state: a LAMMPS data file made by tools/peers/make_gas.py
(the peers' generator, same seeds), converted for cfddem by tools/lammps_data_to_csv.py.

Speed = particles x steps / loop time (setup excluded): cfddem's run.json particle_steps_per_second,
the peers' "Loop time of" line. One MPI rank / one thread each; runs are strictly sequential,
interleaved code by code within each repetition. Reported: the median over --reps runs and the
ratio cfddem / faster peer. Outputs in --out: timings.csv (case, code, rep, loop_s,
particle_steps_per_s, ...), machine.json, summary.md, logs/, data/ (generated once, reused).

usage: /usr/bin/python3 tools/peer_compare.py [--cases hcs1222,dilute100k,dense100k] [--reps 3]
           [--steps-hcs 207297] [--steps-100k 5000] [--out runs/peer_compare]
           [--codes cfddem,lammps,liggghts] [--cfddem PATH]
"""
import argparse
import csv
import datetime
import json
import math
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tools"))
sys.path.insert(0, str(REPO / "tools" / "peers"))
import lammps_data_to_csv  # noqa: E402
import make_gas  # noqa: E402

# Physics shared by all codes.
DIAMETER, DENSITY, K_N, E_N = 100e-6, 1000.0, 10.0, 0.8
MASS = DENSITY * math.pi * DIAMETER ** 3 / 6.0
DT = math.sqrt(MASS / K_N) / 50.0          # 1.447203e-7 s; the peers' inputs carry this value
PEER_DT = "1.447203e-07"
SKIN = 2.5e-5                              # 0.25 d
STEPS_30MS = 207297
THERMO_HCS = 691                           # 0.1000 ms
THERMO_100K = 1000

CASES = {
    # name: (N, L, seed, scene or None)
    "hcs1222": (1222, 4.0e-3, 1, REPO / "scenes" / "hcs.toml"),
    "dilute100k": (100000, 0.01736466, 2, None),
    "dense100k": (100000, 0.005588464, 3, None),
}
PEERS = {"lammps": ("lmp", REPO / "tools" / "peers" / "hcs.lammps"),
         "liggghts": ("liggghts", REPO / "tools" / "peers" / "hcs.liggghts")}
LOOP_RE = re.compile(r"^Loop time of\s+(\S+)\s+on\s+(\d+)\s+procs\s+for\s+(\d+)\s+steps\s+with\s+"
                     r"(\d+)\s+atoms")


def sh(cmd, **kw):
    return subprocess.run(cmd, capture_output=True, text=True, **kw)


def machine_info(codes):
    info = {"date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "host": platform.node(), "kernel": platform.release()}
    lscpu = sh(["lscpu"]).stdout if shutil.which("lscpu") else ""
    for line in lscpu.splitlines():
        key, _, val = line.partition(":")
        if key.strip() in ("Model name", "CPU(s)", "Thread(s) per core", "L2 cache", "L3 cache"):
            info["cpu_" + key.strip().lower().replace("(s)", "s").replace(" ", "_")] = val.strip()
    r = sh(["git", "-C", str(REPO), "rev-parse", "HEAD"])
    info["git_commit"] = r.stdout.strip() if r.returncode == 0 else "unknown"
    r = sh(["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"])
    info["git_dirty"] = bool(r.stdout.strip()) if r.returncode == 0 else None
    for code in codes:
        if code in PEERS and shutil.which(PEERS[code][0]):
            r = sh(["dpkg-query", "-W", "-f=${Version}", code]) if shutil.which("dpkg-query") \
                else None
            info[code + "_package"] = r.stdout.strip() if r is not None and r.returncode == 0 \
                else "unknown"
    return info


def prepare_case(case, data_dir, steps):
    """Data file for the peers, CSV + scene for cfddem. Generated once and reused."""
    n, box, seed, scene = CASES[case]
    data = data_dir / f"{case}.data"
    if not data.exists():
        t0 = time.time()
        print(f"[data] generating {data.name} (N={n}, L={box} m, seed {seed}) ...", flush=True)
        tmp = data.with_suffix(".data.tmp")
        make_gas.make(n, box, str(tmp), seed)
        tmp.replace(data)
        print(f"[data] {data.name} done in {time.time() - t0:.0f} s", flush=True)
    csv_path = data_dir / f"{case}.csv"
    if not csv_path.exists():
        lammps_data_to_csv.convert(str(data), str(csv_path))
    thermo = THERMO_HCS if case == "hcs1222" else THERMO_100K
    if scene is not None:
        # The repository scene must hold this very state (it was converted from the same file).
        repo_csv = scene.parent / "data" / "hcs1222.csv"
        if repo_csv.read_text() != csv_path.read_text():
            print(f"[data] WARNING: {repo_csv} differs from {csv_path} (the peers' seed-1 state); "
                  "cfddem and the peers do not start from the same particles", flush=True)
        scene_path = scene
    else:
        scene_path = data_dir / f"{case}.toml"
        scene_path.write_text(
            f'# {case}: written by tools/peer_compare.py\nname = "{case}"\n'
            "gravity = [0.0, 0.0, 0.0]\n\n[domain]\nlo = [0.0, 0.0, 0.0]\n"
            f"hi = [{box!r}, {box!r}, {box!r}]\nperiodic = [true, true, true]\n\n"
            f'[particles]\nfile = "{csv_path.name}"\n\n'
            '[dem]\nscheme = "explicit"\nspring_constant = 10.0\nrestitution = 0.8\n'
            "friction = 0.0\ndt_factor = 0.02\n\n"
            f"[run]\nend_time = {steps * DT!r}\n\n[output]\ninterval = {thermo * DT!r}\n")
    overrides = ["dem.dt_factor=0.02", f"dem.neighbor_skin={SKIN!r}", f"dem.spring_constant={K_N}",
                 f"dem.restitution={E_N}", "dem.friction=0.0", f"run.end_time={steps * DT!r}",
                 f"output.interval={thermo * DT!r}"]
    return {"data": data, "scene": scene_path, "overrides": overrides, "n": n, "steps": steps,
            "thermo": thermo}


def check_cfddem_dt(cfddem, prep):
    r = sh([str(cfddem), "check", str(prep["scene"]), *prep["overrides"]])
    if r.returncode != 0:
        sys.exit(f"cfddem check failed:\n{r.stdout}{r.stderr}")
    m = re.search(r"^dt_s\s+(\S+)", r.stdout, re.M)
    if not m:
        sys.exit(f"cfddem check printed no dt_s line:\n{r.stdout}")
    if f"{float(m.group(1)):.6e}" != f"{float(PEER_DT):.6e}":
        sys.exit(f"cfddem dt {m.group(1)} s differs from the peers' {PEER_DT} s")
    m = re.search(r"^steps\s+(\d+)", r.stdout, re.M)
    if m and int(m.group(1)) != prep["steps"]:
        sys.exit(f"cfddem would run {m.group(1)} steps, not {prep['steps']}")
    return m and int(m.group(1))


def last_temperature_csv(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return float(rows[-1]["granular_temperature"]) if rows else float("nan")


def run_cfddem(cfddem, prep, out):
    out.mkdir(parents=True, exist_ok=True)
    cmd = [str(cfddem), "run", str(prep["scene"]), *prep["overrides"], "--threads", "1",
           "--out", str(out), "--quiet", "--overwrite"]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    r = sh(cmd, env=env)
    (out / "stderr.txt").write_text(r.stdout + r.stderr)
    if r.returncode != 0:
        raise RuntimeError(f"cfddem failed (rc {r.returncode}): {r.stderr.strip()[-400:]}")
    j = json.loads((out / "run.json").read_text())
    return {"loop_s": j["loop_seconds"], "pss": j["particle_steps_per_second"],
            "steps": j["steps"], "builds": j.get("neighbor_builds", ""),
            "T_end": last_temperature_csv(out / "diagnostics.csv")}


def run_peer(code, prep, log):
    exe, script = PEERS[code]
    log.parent.mkdir(parents=True, exist_ok=True)
    cmd = [exe, "-in", str(script), "-var", "data", str(prep["data"]), "-var", "nsteps",
           str(prep["steps"]), "-var", "nthermo", str(prep["thermo"]), "-var", "skin", repr(SKIN),
           "-screen", "none", "-log", str(log)]
    env = dict(os.environ, OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1",
               OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    r = sh(cmd, env=env)
    text = log.read_text() if log.exists() else ""
    if r.returncode != 0:
        raise RuntimeError(f"{exe} failed (rc {r.returncode}): {(r.stdout + r.stderr)[-400:]}")
    loop = None
    for line in text.splitlines():
        m = LOOP_RE.match(line)
        if m:
            loop, steps, atoms = float(m.group(1)), int(m.group(3)), int(m.group(4))
            break
    if loop is None:
        raise RuntimeError(f"no 'Loop time of' line in {log}")
    builds = re.search(r"^Neighbor list builds\s*=\s*(\d+)", text, re.M)
    curve = thermo_curve(text)
    return {"loop_s": loop, "pss": atoms * steps / loop, "steps": steps,
            "builds": builds.group(1) if builds else "", "T_end": curve[-1][1], "curve": curve}


def thermo_curve(text):
    """(t, T) rows of the thermo table (columns step, time, T) of a peer log."""
    rows, on = [], False
    for line in text.splitlines():
        w = line.split()
        if w[:1] == ["Step"]:
            on = True
            continue
        if on:
            if line.startswith("Loop time"):
                break
            try:
                rows.append((float(w[1]), float(w[2])))
            except (ValueError, IndexError):
                pass
    return rows or [(float("nan"), float("nan"))]


def write_curve(path, curve, source):
    t0 = curve[0][1]
    with open(path, "w") as f:
        f.write(f"# source {source}\n# t[s] T[m2/s2] T/T0\n")
        for t, temp in curve:
            f.write(f"{t:.6e} {temp:.8e} {temp / t0:.8f}\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default="hcs1222,dilute100k,dense100k")
    ap.add_argument("--codes", default="cfddem,lammps,liggghts")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--steps-hcs", type=int, default=STEPS_30MS)
    ap.add_argument("--steps-100k", type=int, default=5000)
    ap.add_argument("--out", default=str(REPO / "runs" / "peer_compare"))
    ap.add_argument("--cfddem", default=None, help="cfddem binary (default: build/bin/cfddem, "
                    "else build-*/bin/cfddem, newest first)")
    a = ap.parse_args()

    cases = [c.strip() for c in a.cases.split(",") if c.strip()]
    for c in cases:
        if c not in CASES:
            sys.exit(f"unknown case {c!r}; known: {', '.join(CASES)}")
    codes = []
    cfddem = cfddem_src = None
    for code in [c.strip() for c in a.codes.split(",") if c.strip()]:
        if code == "cfddem":
            cands = [Path(a.cfddem)] if a.cfddem else sorted(
                REPO.glob("build*/bin/cfddem"), key=lambda p: (p.parent.parent.name != "build",
                                                               -p.stat().st_mtime))
            cfddem = next((p.resolve() for p in cands if p.exists()), None)
            if cfddem is None:
                print("cfddem binary not found (build it, or pass --cfddem): comparing the peers "
                      "only", flush=True)
                continue
        elif code in PEERS:
            if shutil.which(PEERS[code][0]) is None:
                print(f"{code}: `{PEERS[code][0]}` not on PATH: comparing without it", flush=True)
                continue
        else:
            sys.exit(f"unknown code {code!r}")
        codes.append(code)
    if not codes:
        sys.exit("nothing to run")

    out = Path(a.out).resolve()
    (out / "data").mkdir(parents=True, exist_ok=True)
    if cfddem:
        # Run a private copy: others may relink the build tree while this comparison runs.
        snap = out / "cfddem.bin"
        shutil.copy2(cfddem, snap)
        print(f"# cfddem: {cfddem} (built {time.ctime(cfddem.stat().st_mtime)}), run as {snap}",
              flush=True)
        cfddem_src, cfddem = cfddem, snap
    info = machine_info(codes)
    info.update({"cfddem": str(cfddem_src) if cfddem else None, "codes": codes, "cases": cases,
                 "reps": a.reps, "dt_s": DT, "skin_m": SKIN, "threads_or_ranks": 1})
    (out / "machine.json").write_text(json.dumps(info, indent=2) + "\n")
    print(f"# {info.get('cpu_model_name', '?')}, {info['date']}, commit {info['git_commit'][:12]}"
          f"{' (dirty tree)' if info.get('git_dirty') else ''}", flush=True)

    preps = {}
    for case in cases:
        steps = a.steps_hcs if case == "hcs1222" else a.steps_100k
        preps[case] = prepare_case(case, out / "data", steps)
        if cfddem:
            check_cfddem_dt(cfddem, preps[case])
    if cfddem:
        print(f"# cfddem dt = {PEER_DT} s (checked with `cfddem check`), skin {SKIN} m", flush=True)

    rows = []
    with open(out / "timings.csv", "w", newline="") as fcsv:
        w = csv.writer(fcsv)
        w.writerow(["case", "code", "rep", "loop_s", "particle_steps_per_s", "particles", "steps",
                    "neighbor_builds", "T_end", "load1_before"])
        for case in cases:
            prep = preps[case]
            for rep in range(1, a.reps + 1):
                for code in codes:
                    tag = f"{case}.{code}.rep{rep}"
                    load1 = os.getloadavg()[0]   # other work on the machine makes timings noisy
                    try:
                        if code == "cfddem":
                            r = run_cfddem(cfddem, prep, out / "logs" / tag)
                        else:
                            r = run_peer(code, prep, out / "logs" / f"{tag}.log")
                            if rep == 1:
                                write_curve(out / f"T_{case}_{code}.dat", r["curve"],
                                            f"{tag}.log")
                    except (RuntimeError, OSError) as e:
                        print(f"{tag}: FAILED: {e}", flush=True)
                        continue
                    row = {"case": case, "code": code, "rep": rep, **r}
                    rows.append(row)
                    w.writerow([case, code, rep, f"{r['loop_s']:.6g}", f"{r['pss']:.6e}",
                                prep["n"], r["steps"], r["builds"], f"{r['T_end']:.10e}", f"{load1:.2f}"])
                    fcsv.flush()
                    print(f"{tag:<28} loop {r['loop_s']:9.3f} s  {r['pss']:.3e} particle-steps/s"
                          f"  builds {r['builds']}  T_end {r['T_end']:.8e}  load {load1:.2f}", flush=True)

    # Summary: medians and ratio cfddem / faster peer.
    lines = ["| case | code | runs | loop s (median) | particle-steps/s (median) | vs faster peer |",
             "|---|---|---|---|---|---|"]
    print("\nMedians (particle-steps/s = particles x steps / loop time; 1 core each)")
    print(f"{'case':<12} {'code':<9} {'runs':>4} {'loop_s':>9} {'p-steps/s':>11} {'ratio':>7}")
    for case in cases:
        med = {}
        for code in codes:
            rs = [r for r in rows if r["case"] == case and r["code"] == code]
            if rs:
                med[code] = (len(rs), statistics.median(r["loop_s"] for r in rs),
                             statistics.median(r["pss"] for r in rs))
        peers = [c for c in med if c != "cfddem"]
        best = max(peers, key=lambda c: med[c][2]) if peers else None
        for code, (k, loop, pss) in med.items():
            ratio = ""
            if code == "cfddem" and best:
                ratio = f"{pss / med[best][2]:.2f}x {best}"
            print(f"{case:<12} {code:<9} {k:>4} {loop:>9.3f} {pss:>11.3e} {ratio:>7}")
            lines.append(f"| {case} | {code} | {k} | {loop:.3f} | {pss:.3e} | {ratio} |")
        tends = {c: statistics.median(r["T_end"] for r in rows
                                      if r["case"] == case and r["code"] == c) for c in med}
        if "cfddem" in tends and peers:
            ref = tends[best]
            dev = abs(tends["cfddem"] - ref) / ref if ref else float("nan")
            print(f"{'':<12} T_end: cfddem {tends['cfddem']:.8e}, {best} {ref:.8e} "
                  f"(relative difference {dev:.2e})")
    (out / "summary.md").write_text(
        f"# Peer comparison, {info['date']}\n\nCPU: {info.get('cpu_model_name', '?')}; "
        f"commit {info['git_commit']}{' (dirty)' if info.get('git_dirty') else ''}; "
        f"{a.reps} reps; 1 core per code.\n\n" + "\n".join(lines) + "\n")
    print(f"\nwrote {out}/timings.csv, summary.md, machine.json")


if __name__ == "__main__":
    main()

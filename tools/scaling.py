#!/usr/bin/python3
"""Strong and weak scaling of cfddem over MPI ranks x TBB threads, scheme by scheme.

  tools/scaling.py strong (--scene FILE | --base riser|fluidized_bed --particles N) [options]
  tools/scaling.py weak   --base riser|fluidized_bed --particles-per-core N [options]

strong  one fixed scene; every core count c of --cores is run in each --layouts:
          ranks-only    c ranks x 1 thread
          threads-only  1 rank  x c threads
          hybrid        c/T ranks x T threads, T = --hybrid-threads (default 4; several
                        values give one layout each, named hybrid-<T>t); a core count that
                        gives no distinct hybrid layout (c < 2T or c % T != 0) is left out
        1 core (1 x 1) is run once per scheme and is the reference of every layout.
weak    particles and fluid cells per core fixed: for c cores the scene is
        tools/scaled_scene.py --base B --particles (N x c) (the domain grows; --grow xz|xyz),
        run in the same layouts.

Each configuration runs, sequentially, for each scheme of --schemes (default explicit orb
islands; a scheme that `cfddem check` refuses, e.g. islands on an older binary, is reported
and left out):

  [env OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1]   (only when run as root)
  mpirun -np R --bind-to none [--oversubscribe] cfddem run SCENE dem.scheme=S [--set ...]
         --threads T --quiet --out OUT/runs/<mode>_<scheme>_c<c>_<R>x<T>

(--oversubscribe when R exceeds the node's cores, --node-cores, default os.cpu_count();
--binding core instead launches with --map-by ppr:R:node:pe=T --bind-to core, which needs
R x T <= node cores.) run.json gives the numbers; a configuration cfddem refuses (exit 2, e.g.
a scene the distributed code does not support yet) or that fails is a CSV row with its status
and the first error line, never a crash of this script.

CSV (OUT/<mode>.csv), one row per (scheme, layout, cores):
  mode, scheme, layout, cores, ranks, threads, particles, fluid_cells, step_unit,
  wall_per_step_s   loop_seconds / fluid_steps with a gas ("fluid_step", dt_f of simulated
                    time); without a gas loop_seconds per output.interval of simulated time
                    ("output_interval")
  particle_steps_per_second (run.json),
  speedup           strong: T(1) / T(c); weak: scaled speed-up c T(1) / T(c)
  efficiency        strong: T(1) / (c T(c)); weak: T(1) / T(c)   (T = wall_per_step_s, T(1)
                    from the same scheme on 1 core)
  speedup_vs_explicit T_explicit / T_scheme at the same (layout, cores): the adaptive scheme's
                    speed-up over the explicit baseline
  loop_seconds, mpi_wait_seconds (when run.json has it), fluid_seconds, load_1min (the node's
  load average when the run started), status (ok | refused | failed | timeout | skipped),
  note, command.
OUT/<mode>_meta.json records the machine (host, cpu model, cores, load average at start and
end), the date, the binary (path, sha256, cfddem version; the source commit when the binary sits
in build/bin of a git checkout), --note and this command line.
Plot (OUT/<mode>.png): time per step (log-log, ideal line), speed-up and efficiency vs cores,
one line per scheme and layout.

Options: --end-time T (run.end_time), --set KEY=VALUE (any scene key, all runs),
--scheme-set SCHEME:KEY=VALUE (one scheme only, e.g. orb:dem.nsubit=35), --repeat N (min of N
runs), --timeout S per run, --dry-run (print the commands, run nothing), --plot-only CSV.

Examples (a 16-core node):
  tools/scaling.py strong --base riser --particles 1e6 --cores 1 2 4 8 16 \
      --layouts ranks-only threads-only hybrid --end-time 1e-3 --out runs/strong_riser_1e6
  tools/scaling.py weak --base riser --particles-per-core 6.25e4 --cores 1 2 4 8 16 \
      --end-time 1e-3 --out runs/weak_riser
"""
import argparse
import csv
import datetime
import hashlib
import json
import math
import os
import platform
import shlex
import socket
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import scaled_scene  # noqa: E402

ROOT_ENV = {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1"}
FIELDS = ["mode", "scheme", "layout", "cores", "ranks", "threads", "particles", "fluid_cells",
          "step_unit", "wall_per_step_s", "particle_steps_per_second", "speedup", "efficiency",
          "speedup_vs_explicit", "loop_seconds", "mpi_wait_seconds", "fluid_seconds", "load_1min",
          "status", "note", "command"]


def default_binary():
    for p in (os.path.join(os.path.dirname(HERE), "build", "bin", "cfddem"),):
        if os.access(p, os.X_OK):
            return p
    return "cfddem"


def layouts_for(cores, names, hybrid_threads):
    """[(layout, ranks, threads)] for one core count; 1 core is the single layout '1x1'."""
    if cores == 1:
        return [("serial", 1, 1)]
    out = []
    for name in names:
        if name == "ranks-only":
            out.append((name, cores, 1))
        elif name == "threads-only":
            out.append((name, 1, cores))
        elif name == "hybrid":
            ts = [hybrid_threads] if isinstance(hybrid_threads, int) else list(hybrid_threads)
            for t in ts:
                if cores % t == 0 and cores // t >= 2 and t >= 2:
                    out.append((name if len(ts) == 1 else f"hybrid-{t}t", cores // t, t))
        else:
            raise ValueError(name)
    return out


def launch_cmd(a, ranks, threads, scene, overrides, out_dir):
    cmd = []
    if a.launcher:
        cmd += [a.launcher, "-np", str(ranks)]
        if a.binding == "core":
            cmd += ["--map-by", f"ppr:{ranks}:node:pe={threads}", "--bind-to", "core"]
        else:
            cmd += ["--bind-to", "none"]
        if ranks > a.node_cores or (a.binding == "core" and ranks * threads > a.node_cores):
            cmd += ["--oversubscribe"]
    elif ranks != 1:
        raise SystemExit("scaling.py: --launcher '' runs without mpirun: 1 rank only")
    cmd += [a.binary, "run", scene, *overrides, "--threads", str(threads), "--quiet",
            "--overwrite", "--out", out_dir]
    return cmd


def run_env():
    env = dict(os.environ)
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        env.update(ROOT_ENV)
    env.setdefault("MPLBACKEND", "Agg")
    return env


def shell_line(cmd):
    pre = ""
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        pre = " ".join(f"{k}={v}" for k, v in ROOT_ENV.items()) + " "
    return pre + " ".join(shlex.quote(c) for c in cmd)


def first_error(text):
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    for ln in lines:
        if "error" in ln.lower() or "stopped" in ln.lower() or "refus" in ln.lower():
            return ln[:300]
    return (lines[-1] if lines else "")[:300]


def check_scheme(a, scene, scheme):
    """None if `cfddem check` accepts the scheme on this scene, else the error line."""
    cmd = [a.binary, "check", scene, f"dem.scheme={scheme}", *a.set]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, env=run_env(), timeout=600)
    except OSError as e:
        return str(e)
    if r.returncode != 0:
        return f"`cfddem check` exit {r.returncode}: {first_error(r.stderr + r.stdout)}"
    return None


def scene_numbers(a, scene):
    """(particles, fluid cells or 0) from `cfddem check`."""
    r = subprocess.run([a.binary, "check", scene, *a.set], capture_output=True, text=True,
                       env=run_env())
    particles, cells = None, 0
    for ln in r.stdout.splitlines():
        if ln.startswith("particles.count ="):
            particles = int(ln.split("=")[1])
        if ln.startswith("fluid.cells ="):
            cells = math.prod(int(x) for x in ln.split("=")[1].strip(" []").split(","))
    return particles, cells


def one_run(a, cmd, out_dir):
    """Run cmd --repeat times; (status, note, best run.json or None)."""
    best, note = None, ""
    for _ in range(a.repeat):
        if os.path.exists(os.path.join(out_dir, "run.json")):
            os.remove(os.path.join(out_dir, "run.json"))
        os.makedirs(out_dir, exist_ok=True)
        try:
            r = subprocess.run(cmd, capture_output=True, text=True, env=run_env(),
                               timeout=a.timeout)
        except subprocess.TimeoutExpired:
            return "timeout", f"over --timeout {a.timeout} s", best
        except OSError as e:
            return "failed", str(e), best
        with open(os.path.join(out_dir, "stderr.txt"), "w") as f:
            f.write(r.stderr)
        if r.returncode == 2:
            return "refused", f"exit 2: {first_error(r.stderr + r.stdout)}", None
        if r.returncode != 0:
            return "failed", f"exit {r.returncode}: {first_error(r.stderr + r.stdout)}", None
        try:
            with open(os.path.join(out_dir, "run.json")) as f:
                js = json.load(f)
        except (OSError, ValueError) as e:
            return "failed", f"exit 0 but no readable run.json ({e})", None
        if best is None or js["loop_seconds"] < best["loop_seconds"]:
            best = js
    return "ok", note, best


def wall_per_step(js):
    """(seconds per unit, unit)."""
    loop = float(js["loop_seconds"])
    if js.get("fluid_steps"):
        return loop / int(js["fluid_steps"]), "fluid_step"
    conf = js.get("configuration", {})
    interval = float(conf.get("output.interval", "nan"))
    end = float(js.get("end_time", conf.get("run.end_time", "nan")))
    n = end / interval if interval > 0 else float("nan")
    return loop / n, f"output_interval ({interval:g} s)"


def fill_derived(rows, mode):
    """speedup, efficiency (vs the same scheme on 1 core) and speedup_vs_explicit."""
    rows_ok = [r for r in rows if r.get("status") == "ok"]
    t1 = {r["scheme"]: r["wall_per_step_s"] for r in rows_ok if r["cores"] == 1}
    expl = {(r["layout"], r["cores"]): r["wall_per_step_s"] for r in rows_ok
            if r["scheme"] == "explicit"}
    for r in rows_ok:
        t, c = r["wall_per_step_s"], r["cores"]
        if r["scheme"] in t1:
            ref = t1[r["scheme"]]
            if mode == "strong":
                r["speedup"] = ref / t
                r["efficiency"] = ref / (c * t)
            else:
                r["speedup"] = c * ref / t
                r["efficiency"] = ref / t
        key = (r["layout"], c)
        if key in expl:
            r["speedup_vs_explicit"] = expl[key] / t


def write_csv(path, rows):
    tmp = path + ".tmp"  # written whole, then renamed: a reader never sees half a table
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=FIELDS)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in
                        ((k, r.get(k, "")) for k in FIELDS)})
    os.replace(tmp, path)


def read_csv(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        for k in ("cores", "ranks", "threads"):
            r[k] = int(r[k]) if r.get(k) else 0
        for k in ("wall_per_step_s", "speedup", "efficiency"):
            r[k] = float(r[k]) if r.get(k) not in (None, "") else None
    return rows


def plot(rows, mode, path, title):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if r["status"] == "ok" and r.get("efficiency") not in (None, "")]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    schemes = sorted({r["scheme"] for r in ok})
    layouts = sorted({r["layout"] for r in ok if r["layout"] != "serial"}) or ["serial"]
    styles = {"ranks-only": "-", "threads-only": "--", "serial": "-"}
    for i, lay in enumerate(x for x in layouts if x.startswith("hybrid")):
        styles[lay] = [":", "-.", (0, (5, 1, 1, 1, 1, 1)), (0, (1, 3))][i % 4]
    markers = {"explicit": "o", "orb": "s", "islands": "^"}
    allc = sorted({r["cores"] for r in ok})
    for si, s in enumerate(schemes):
        color = f"C{si}"
        for lay in layouts:
            pts = sorted((r["cores"], r) for r in ok if r["scheme"] == s and
                         (r["layout"] == lay or r["cores"] == 1))
            if not pts:
                continue
            c = [p[0] for p in pts]
            lab = f"{s}, {lay}"
            kw = dict(color=color, ls=styles.get(lay, "-"), marker=markers.get(s, "o"), label=lab)
            axes[0].plot(c, [p[1]["wall_per_step_s"] for p in pts], **kw)
            axes[1].plot(c, [p[1]["speedup"] for p in pts], **kw)
            axes[2].plot(c, [p[1]["efficiency"] for p in pts], **kw)
        t1 = [r["wall_per_step_s"] for r in ok if r["scheme"] == s and r["cores"] == 1]
        if t1 and allc:
            ideal = [t1[0] / c for c in allc] if mode == "strong" else [t1[0]] * len(allc)
            axes[0].plot(allc, ideal, color=color, lw=0.8, alpha=0.5)
    unit = ok[0]["step_unit"] if ok else "step"
    axes[0].set_xscale("log", base=2)
    axes[0].set_yscale("log")
    axes[0].set_ylabel(f"wall per {unit} [s] (thin: ideal)")
    if allc:
        axes[1].plot(allc, allc, "k", lw=0.8, label="ideal")
        axes[2].axhline(1.0, color="k", lw=0.8)
    axes[1].set_ylabel("speed-up T(1)/T(c)" if mode == "strong" else "scaled speed-up c T(1)/T(c)")
    axes[2].set_ylabel("efficiency " + ("T(1)/(c T(c))" if mode == "strong" else "T(1)/T(c)"))
    axes[2].set_ylim(0, max(1.1, max([r["efficiency"] for r in ok], default=1.0) * 1.05))
    for ax in axes:
        ax.set_xscale("log", base=2)
        ax.set_xlabel("cores (ranks x threads)")
        if allc:
            ax.set_xticks(allc, [str(c) for c in allc])
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7)
    bad = [r for r in rows if r["status"] != "ok"]
    if bad:
        title += f"  ({len(bad)} configuration(s) not run: see CSV status/note)"
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path + ".tmp.png", dpi=110)
    os.replace(path + ".tmp.png", path)
    plt.close(fig)


def machine_info(a):
    info = {"host": socket.gethostname(), "platform": platform.platform(),
            "cores": os.cpu_count(), "node_cores_assumed": a.node_cores,
            "date": datetime.datetime.now().isoformat(timespec="seconds"),
            "binary": os.path.abspath(a.binary) if os.path.exists(a.binary) else a.binary,
            "command": " ".join(shlex.quote(x) for x in sys.argv)}
    try:
        with open("/proc/cpuinfo") as f:
            for ln in f:
                if ln.startswith("model name"):
                    info["cpu"] = ln.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    src = os.path.dirname(os.path.dirname(os.path.dirname(info["binary"])))
    try:
        info["cfddem_commit"] = subprocess.run(
            ["git", "-C", src, "rev-parse", "HEAD"], capture_output=True, text=True,
            check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        pass
    try:
        with open(info["binary"], "rb") as f:
            info["binary_sha256"] = hashlib.sha256(f.read()).hexdigest()
    except OSError:
        pass
    if a.note:
        info["note"] = a.note
    try:
        info["load_avg_start"] = os.getloadavg()
    except OSError:
        pass
    return info


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n", 1)[1])
    ap.add_argument("mode", choices=["strong", "weak"])
    ap.add_argument("--scene", help="strong: the fixed scene file")
    ap.add_argument("--base", choices=sorted(scaled_scene.BASES),
                    help="scaled scene base (strong with --particles; weak)")
    ap.add_argument("--particles", type=float, help="strong: scene size with --base")
    ap.add_argument("--particles-per-core", type=float, help="weak: particles per core")
    ap.add_argument("--grow", choices=["xz", "xyz"], default="xz", help="scaled_scene.py --grow")
    ap.add_argument("--no-fluid", action="store_true", help="scaled scenes without the gas")
    ap.add_argument("--cell-multiple", type=int, default=0, metavar="M",
                    help="scaled scenes: the grown axes' cell counts multiples of M "
                         "(scaled_scene.py --cell-multiple), so the gas's multigrid coarsens them")
    ap.add_argument("--cores", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    ap.add_argument("--layouts", nargs="+", default=["ranks-only", "threads-only", "hybrid"],
                    choices=["ranks-only", "threads-only", "hybrid"])
    ap.add_argument("--hybrid-threads", type=int, nargs="+", default=[4],
                    help="threads per rank of the hybrid layouts (default 4; e.g. 2 4 8)")
    ap.add_argument("--schemes", nargs="+", default=["explicit", "orb", "islands"])
    ap.add_argument("--end-time", type=float, help="run.end_time for every run")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--scheme-set", action="append", default=[], metavar="SCHEME:KEY=VALUE")
    ap.add_argument("--repeat", type=int, default=1, help="min of N runs per configuration")
    ap.add_argument("--timeout", type=float, default=None, help="seconds per run")
    ap.add_argument("--binary", default=default_binary())
    ap.add_argument("--launcher", default="mpirun", help="'' = no mpirun (1 rank only)")
    ap.add_argument("--binding", choices=["none", "core"], default="none")
    ap.add_argument("--node-cores", type=int, default=os.cpu_count())
    ap.add_argument("--out", default=None, help="output folder (default runs/scaling_<mode>)")
    ap.add_argument("--note", help="free text kept in OUT/<mode>_meta.json (where the binary "
                    "came from, the node's state, ...)")
    ap.add_argument("--dry-run", action="store_true", help="print the commands, run nothing")
    ap.add_argument("--plot-only", metavar="CSV", help="re-plot an existing CSV")
    a = ap.parse_args()
    out = a.out or os.path.join("runs", f"scaling_{a.mode}")

    if a.plot_only:
        rows = read_csv(a.plot_only)
        png = os.path.splitext(a.plot_only)[0] + ".png"
        plot(rows, a.mode, png, f"{a.mode} scaling ({os.path.basename(a.plot_only)})")
        print(f"scaling.py: wrote {png}")
        return

    overrides = list(a.set)
    if a.end_time is not None:
        overrides.append(f"run.end_time={a.end_time!r}")
    a.set = overrides
    per_scheme = {}
    for item in a.scheme_set:
        if ":" not in item or "=" not in item:
            ap.error(f"--scheme-set {item}: expected SCHEME:KEY=VALUE")
        s, kv = item.split(":", 1)
        per_scheme.setdefault(s, []).append(kv)

    os.makedirs(out, exist_ok=True)
    scene_dir = os.path.join(out, "scenes")

    def scaled(n):
        """Write (once) and return the scaled scene file for n particles."""
        os.makedirs(scene_dir, exist_ok=True)
        name = f"{a.base}_{scaled_scene.fmt_count(n)}{'_dem' if a.no_fluid else ''}_{a.grow}"
        if a.cell_multiple > 1:
            name += f"_m{a.cell_multiple}"
        path = os.path.join(scene_dir, name + ".toml")
        scene, over, info = scaled_scene.scale_scene(a.base, n, a.grow, no_fluid=a.no_fluid,
                                                     cell_multiple=a.cell_multiple)
        text = scaled_scene.write_toml(scene, [
            f"{over['name']}: made by tools/scaling.py via scaled_scene.scale_scene",
            f"{n} particles, phi {info['solid_fraction']:.5f}, cells {info['cells']}, "
            f"grow {a.grow}, orb_levels {info['orb_levels']}"])
        scaled_scene.write_text(path, text)
        return path

    # the scene of each core count
    if a.mode == "strong":
        if a.scene:
            scene_of = {c: a.scene for c in a.cores}
        elif a.base and a.particles:
            p = scaled(int(round(a.particles)))
            scene_of = {c: p for c in a.cores}
        else:
            ap.error("strong: --scene FILE, or --base B --particles N")
    else:
        if not (a.base and a.particles_per_core):
            ap.error("weak: --base B --particles-per-core N")
        scene_of = {c: scaled(int(round(a.particles_per_core * c))) for c in a.cores}
    if 1 not in a.cores:
        print("scaling.py: note: --cores has no 1: speed-up and efficiency need the 1-core run "
              "and stay empty", file=sys.stderr)

    # which schemes this binary accepts (checked on the smallest scene)
    schemes, rows = [], []
    first_scene = scene_of[min(a.cores)]
    for s in a.schemes:
        err = None if a.dry_run else check_scheme(a, first_scene, s)
        if err:
            print(f"scaling.py: scheme {s} left out: {err}", file=sys.stderr)
            rows.append({"mode": a.mode, "scheme": s, "status": "skipped",
                         "note": f"scheme not accepted by this binary: {err}"})
        else:
            schemes.append(s)

    meta = machine_info(a)
    meta["schemes_run"] = schemes
    csv_path = os.path.join(out, f"{a.mode}.csv")
    numbers = {}
    for c in sorted(a.cores):
        scene = scene_of[c]
        if scene not in numbers:
            numbers[scene] = (None, 0) if a.dry_run else scene_numbers(a, scene)
        particles, cells = numbers[scene]
        for lay, ranks, threads in layouts_for(c, a.layouts, a.hybrid_threads):
            for s in schemes:
                run_dir = os.path.join(out, "runs", f"{a.mode}_{s}_c{c}_{ranks}x{threads}")
                ov = [f"dem.scheme={s}", *a.set, *per_scheme.get(s, [])]
                cmd = launch_cmd(a, ranks, threads, scene, ov, run_dir)
                if a.dry_run:
                    print(shell_line(cmd))
                    continue
                row = {"mode": a.mode, "scheme": s, "layout": lay, "cores": c, "ranks": ranks,
                       "threads": threads, "particles": particles, "fluid_cells": cells,
                       "command": shell_line(cmd)}
                try:
                    row["load_1min"] = round(os.getloadavg()[0], 2)
                except OSError:
                    pass
                t0 = time.time()
                status, note, js = one_run(a, cmd, run_dir)
                row["status"], row["note"] = status, note
                if js is not None and status == "ok":
                    row["wall_per_step_s"], row["step_unit"] = wall_per_step(js)
                    row["loop_seconds"] = float(js["loop_seconds"])
                    row["particle_steps_per_second"] = float(js.get("particle_steps_per_second",
                                                                     float("nan")))
                    row["particles"] = js.get("particles", particles)
                    meta.setdefault("cfddem_version", js.get("version"))
                    ph = js.get("phase_seconds", {})
                    if isinstance(ph, dict) and "fluid" in ph:
                        row["fluid_seconds"] = float(ph["fluid"])
                    if "mpi_wait_seconds" in js:
                        w = js["mpi_wait_seconds"]
                        if isinstance(w, (list, tuple)):
                            w = max(w)
                        elif isinstance(w, dict):
                            w = w.get("max", w.get("mean", ""))
                        row["mpi_wait_seconds"] = w
                    if int(js.get("ranks", ranks)) != ranks or int(js.get("threads", threads)) != threads:
                        row["note"] = (f"run.json says {js.get('ranks')} x {js.get('threads')}, "
                                       f"launched {ranks} x {threads}")
                    elif ranks > 1 and "mpi_wait_seconds" not in js:
                        row["note"] = ("run.json has no mpi_wait_seconds: this binary may run the "
                                       "whole scene on every rank (not distributed)")
                rows.append(row)
                fill_derived(rows, a.mode)
                write_csv(csv_path, rows)
                print(f"scaling.py: {a.mode} {s:8s} {lay:12s} c={c:<3d} {ranks}x{threads}: "
                      f"{status}"
                      + (f" {row['wall_per_step_s']:.4g} s per {row['step_unit']}"
                         if "wall_per_step_s" in row else "") +
                      f" (run {time.time() - t0:.1f} s) {row['note']}", file=sys.stderr)
    if a.dry_run:
        return
    fill_derived(rows, a.mode)
    write_csv(csv_path, rows)
    try:
        meta["load_avg_end"] = os.getloadavg()
    except OSError:
        pass
    scaled_scene.write_text(os.path.join(out, f"{a.mode}_meta.json"), json.dumps(meta, indent=2))
    what = a.scene or (f"{a.base} {'%g' % a.particles} particles" if a.mode == "strong" else
                       f"{a.base} {'%g' % a.particles_per_core} particles/core")
    title = (f"{a.mode} scaling: {what}{', no gas' if a.no_fluid else ''} "
             f"({meta['host']}, {meta.get('cpu', '?')}, {meta['cores']} cores)")
    png = os.path.join(out, f"{a.mode}.png")
    plot(rows, a.mode, png, title)
    print(f"scaling.py: wrote {csv_path}, {png}, {a.mode}_meta.json", file=sys.stderr)


if __name__ == "__main__":
    main()

#!/usr/bin/python3
"""Scaled versions of the paper's riser and fluidized bed, for strong and weak scaling.

Reads the base scene (scenes/riser.toml or scenes/fluidized_bed.toml) and writes a scene with
--particles N particles that keeps the base scene's

  * particle diameter and density,
  * solid fraction phi = N V_p / V_domain (riser 2.04%, fluidized bed 20.4% over the column),
  * fluid cell size (riser 0.1875 x 0.2 x 0.1875 mm, fluidized bed 0.05 x 0.2 x 0.05 mm),
  * time steps (fluid.dt, dem.* unchanged), boundary conditions and drive.

How the domain grows (--grow, default "xz"):

  xz   the two lateral axes grow, the height (y, the flow axis) stays at the base 1 cm and its
       50 cells. The riser keeps its 2 Pa drop per 1 cm period (the same 200 Pa/m drive), the
       bed keeps its 4.8 mm packed height, inflow and outflow: the physics per column is the
       base scene's, only wider (like LAMMPS' Chute bench, which grows in x and y, never z).
  xyz  all three axes grow by the same factor (cell counts scaled, rounded to integers); the
       riser's pressure_drop (Pa per period) is scaled with the height so the gradient stays
       200 Pa/m; the bed's packed region grows in height with the column.

Cells stay integer: the cell counts are rounded, so the domain volume (and phi) can differ
slightly from the exact target; the generator picks the integer counts whose product is closest
to the target and prints the phi it obtained. A periodic axis whose base count is even keeps an
even count (hypre's PFMG stops coarsening at the first odd period and its SMG cannot run on one;
the riser is periodic on every axis). phi is then within 1.4% of the base at N = 2e4, 1.2% from
5e4 on and 0.7% from 1e6 on, for both bases. The particle count is exactly N.

ORB: partition.orb_levels = ceil(log2(N / --per-leaf)) (default --per-leaf 200, clamped to
0..20), so leaves hold between per-leaf/2 and per-leaf particles: 100-200 by default, which is
what both base scenes use (riser 14,000 / 2^7 = 109, bed 10,000 / 2^6 = 156).

--no-fluid drops the [fluid] table (the same particles, DEM only; scenes without a gas do no
fluid work at all). The DEM-only riser has no gravity and no drive, so its particles sit still
unless given a granular temperature (--set particles.temperature=1e-4); the DEM-only bed falls
and settles under gravity.

Examples:
  tools/scaled_scene.py --base riser --particles 1e6 --out runs/scaled/riser_1e6.toml
  tools/scaled_scene.py --base fluidized_bed --particles 1e5 --grow xyz --out bed_1e5.toml
  tools/scaled_scene.py --base riser --particles 2e4 --no-fluid --out riser_2e4_dem.toml
  tools/scaled_scene.py --base riser --particles 1e6 --print-overrides   # key=value list for
                                                                         # cfddem run scenes/riser.toml
"""
import argparse
import json
import math
import os
import sys

try:
    import tomllib  # Python >= 3.11
except ImportError:  # pragma: no cover
    try:
        import tomli as tomllib
    except ImportError:
        sys.exit("scaled_scene.py: needs Python >= 3.11 (tomllib) or the tomli module")

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(os.path.dirname(HERE), "scenes")
BASES = {"riser": "riser.toml", "fluidized_bed": "fluidized_bed.toml"}


# ---------------------------------------------------------------- TOML writing (no tomli_w)
def toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)  # shortest round-trip repr, valid TOML (1e-05, 0.015, ...)
    if isinstance(v, str):
        return json.dumps(v)  # TOML basic strings share JSON's escapes for our values
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")


def write_text(path, text):
    """Write the whole file under a temporary name, then rename it over path."""
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def flatten(d, prefix=""):
    """Nested dict -> [(dotted key, value)] (sub-tables become dotted keys: fluid.bc.y_lo)."""
    out = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out += flatten(v, key + ".")
        else:
            out.append((key, v))
    return out


def write_toml(scene, header_lines):
    lines = [f"# {h}" if h else "#" for h in header_lines]
    top = {k: v for k, v in scene.items() if not isinstance(v, dict)}
    for k, v in top.items():
        lines.append(f"{k} = {toml_value(v)}")
    for table, body in scene.items():
        if not isinstance(body, dict):
            continue
        lines.append("")
        lines.append(f"[{table}]")
        for k, v in flatten(body):
            lines.append(f"{k} = {toml_value(v)}")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- scaling
def closest_pair(target, a0, b0, step_a=1, step_b=1):
    """Integers (a, b) >= 1, a a multiple of step_a and b of step_b, with a/b within two steps
    of a0/b0 (as even as the steps allow), a*b closest to target among those."""
    a_c = math.sqrt(target * a0 / b0)
    best = None
    k0 = max(1, math.floor(a_c / step_a))
    for k in range(max(1, k0 - 3), k0 + 5):
        a = k * step_a
        b = max(step_b, round(target / a / step_b) * step_b)
        uneven = abs(a * b0 / a0 - b) > 2 * max(step_a, step_b)
        key = (uneven, abs(a * b - target))
        if best is None or key < best[0]:
            best = (key, a, b)
    return best[1], best[2]


def even_step(s, axis):
    """2 on a periodic axis whose base count is even, else 1. hypre's PFMG stops coarsening at
    the first odd periodic count, and its SMG (the projection's fallback) cannot run on one at
    all, so a scaled grid keeps the base grid's even periods."""
    periodic = s["domain"].get("periodic", [True, True, True])
    return 2 if periodic[axis] and int(s["fluid"]["cells"][axis]) % 2 == 0 else 1


def scale_scene(base_name, n, grow="xz", per_leaf=200.0, no_fluid=False, levels=None,
                cell_multiple=0):
    path = os.path.join(SCENES, BASES[base_name])
    with open(path, "rb") as f:
        s = tomllib.load(f)
    if "fluid" not in s or "cells" not in s["fluid"]:
        sys.exit(f"scaled_scene.py: {path} has no fluid.cells: cannot keep the cell size")
    lo = [float(x) for x in s["domain"]["lo"]]
    hi = [float(x) for x in s["domain"]["hi"]]
    cells0 = [int(c) for c in s["fluid"]["cells"]]
    h = [(hi[i] - lo[i]) / cells0[i] for i in range(3)]
    n0 = int(s["particles"]["count"])
    d = float(s["particles"]["diameter"])
    vp = math.pi * d ** 3 / 6.0
    vol0 = math.prod(hi[i] - lo[i] for i in range(3))
    phi0 = n0 * vp / vol0
    f = n / n0  # volume factor: V = N V_p / phi0 = f V0
    step = [even_step(s, i) for i in range(3)]
    if cell_multiple > 1:
        # --cell-multiple M: the grown axes' counts are multiples of M, so the multigrid halves
        # them log2(M) times before an odd count stops it (phi then moves further from the base).
        for i in ((0, 2) if grow == "xz" else (0, 1, 2)):
            step[i] = max(step[i], cell_multiple)
    if grow == "xz":
        nx, nz = closest_pair(cells0[0] * cells0[2] * f, cells0[0], cells0[2], step[0], step[2])
        cells = [nx, cells0[1], nz]
    elif grow == "xyz":
        g = f ** (1.0 / 3.0)
        ny = max(step[1], round(cells0[1] * g / step[1]) * step[1])
        nx, nz = closest_pair(math.prod(cells0) * f / ny, cells0[0], cells0[2], step[0], step[2])
        cells = [nx, ny, nz]
    else:
        raise ValueError(grow)
    new_hi = [float(f"{lo[i] + cells[i] * h[i]:.14g}") for i in range(3)]
    vol = math.prod(new_hi[i] - lo[i] for i in range(3))
    phi = n * vp / vol
    if levels is None:
        levels = max(0, min(20, math.ceil(math.log2(max(n / per_leaf, 1.0)))))

    over = {}  # dotted key -> value: what changes against the base scene
    over["name"] = f"{base_name}_{fmt_count(n)}" + ("_dem" if no_fluid else "")
    over["domain.hi"] = new_hi
    over["particles.count"] = int(n)
    over["fluid.cells"] = cells
    over["partition.orb_levels"] = int(levels)
    ystretch = cells[1] / cells0[1]
    pd = s["fluid"].get("pressure_drop")
    if pd is not None and grow == "xyz":
        # Pa per period: keep the gradient (Pa/m) of the base scene
        over["fluid.pressure_drop"] = [float(pd[i]) * cells[i] / cells0[i] for i in range(3)]
    p = s["particles"]
    if "region_lo" in p or "region_hi" in p:
        rlo = [float(x) for x in p.get("region_lo", lo)]
        rhi = [float(x) for x in p.get("region_hi", hi)]
        new_rhi = list(rhi)
        for i in range(3):
            if i == 1 and grow == "xz":
                continue  # the packed height stays
            # a region that spans the base axis spans the new one; otherwise scale its extent
            if math.isclose(rlo[i], lo[i]) and math.isclose(rhi[i], hi[i]):
                new_rhi[i] = new_hi[i]
            else:
                stretch = ystretch if i == 1 else cells[i] / cells0[i]
                new_rhi[i] = rlo[i] + (rhi[i] - rlo[i]) * stretch
        over["particles.region_hi"] = new_rhi

    scene = json.loads(json.dumps(s))  # deep copy
    for key, v in over.items():
        parts = key.split(".")
        t = scene
        for part in parts[:-1]:
            t = t.setdefault(part, {})
        t[parts[-1]] = v
    if no_fluid:
        del scene["fluid"]
    info = {
        "base": path, "particles": int(n), "grow": grow, "cells": cells,
        "cell_size_m": h, "domain_hi_m": new_hi, "solid_fraction": phi,
        "solid_fraction_base": phi0, "orb_levels": int(levels),
        "particles_per_leaf": n / 2 ** levels, "fluid_cells": math.prod(cells),
        "no_fluid": no_fluid,
    }
    return scene, over, info


def fmt_count(n):
    """1e6 -> '1e6', 20000 -> '2e4', 123456 -> '123456'."""
    e = int(math.floor(math.log10(n))) if n > 0 else 0
    m = n / 10 ** e
    if abs(m - round(m)) < 1e-9 and e >= 3:
        return f"{int(round(m))}e{e}"
    return str(int(n))


def override_args(over):
    """The key=value list for `cfddem run BASE ...` (TOML values, shell-quoted)."""
    out = []
    for k, v in over.items():
        out.append(f"{k}={toml_value(v)}")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n", 1)[1])
    ap.add_argument("--base", choices=sorted(BASES), default="riser")
    ap.add_argument("--particles", type=float, required=True, help="particle count (1e6 or 1000000)")
    ap.add_argument("--grow", choices=["xz", "xyz"], default="xz",
                    help="axes that grow (default xz: lateral, fixed 1 cm height)")
    ap.add_argument("--per-leaf", type=float, default=200.0,
                    help="ORB leaves hold between this/2 and this many particles (default 200)")
    ap.add_argument("--levels", type=int, help="ORB levels (overrides --per-leaf)")
    ap.add_argument("--no-fluid", action="store_true", help="drop the gas: DEM only, same particles")
    ap.add_argument("--cell-multiple", type=int, default=0, metavar="M",
                    help="grown axes' cell counts are multiples of M (e.g. 8 or 16), so the "
                         "multigrid coarsens them log2(M) times; phi moves further from the "
                         "base (the generated grids' odd counts otherwise leave the multigrid a "
                         "large coarsest level: docs/performance_history.md)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="extra override written into the scene (TOML value; bare word = string)")
    ap.add_argument("--out", help="scene file to write (default: print the scene to stdout)")
    ap.add_argument("--print-overrides", action="store_true",
                    help="print the key=value overrides against the base scene instead")
    ap.add_argument("--json", action="store_true", help="print the derived numbers as JSON on stdout")
    a = ap.parse_args()
    n = int(round(a.particles))
    if n < 1:
        ap.error("--particles must be >= 1")
    if a.cell_multiple < 0:
        ap.error("--cell-multiple must be >= 0")
    scene, over, info = scale_scene(a.base, n, a.grow, a.per_leaf, a.no_fluid, a.levels,
                                    a.cell_multiple)
    for kv in a.set:
        if "=" not in kv:
            ap.error(f"--set {kv}: expected KEY=VALUE")
        key, val = kv.split("=", 1)
        try:
            v = tomllib.loads(f"v = {val}")["v"]
        except tomllib.TOMLDecodeError:
            v = val
        over[key] = v
        parts = key.split(".")
        t = scene
        for part in parts[:-1]:
            t = t.setdefault(part, {})
        t[parts[-1]] = v

    if a.print_overrides:
        if a.no_fluid:
            sys.exit("scaled_scene.py: --no-fluid cannot be written as overrides (a key cannot "
                     "remove the [fluid] table); write a scene with --out")
        print(" ".join(f"'{x}'" for x in override_args(over)))
        return
    header = [
        f"{over['name']}: scenes/{BASES[a.base]} scaled by tools/scaled_scene.py",
        f"  {' '.join(sys.argv[1:])}",
        f"{n} particles, solid fraction {info['solid_fraction']:.5f} (base "
        f"{info['solid_fraction_base']:.5f}), cells {info['cells']} "
        f"(size {', '.join(f'{x:.4g}' for x in info['cell_size_m'])} m, as the base), "
        f"grow {a.grow}",
        f"ORB levels {info['orb_levels']}: {info['particles_per_leaf']:.0f} particles per leaf"
        + ("; no gas (DEM only)" if a.no_fluid else ""),
        "",
    ]
    text = write_toml(scene, header)
    if a.out:
        os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
        write_text(a.out, text)
        print(f"scaled_scene.py: wrote {a.out}: {n} particles, phi {info['solid_fraction']:.5f} "
              f"(base {info['solid_fraction_base']:.5f}), cells {info['cells']} "
              f"({info['fluid_cells']} cells{', unused: no gas' if a.no_fluid else ''}), "
              f"orb_levels {info['orb_levels']} ({info['particles_per_leaf']:.0f}/leaf)",
              file=sys.stderr)
    else:
        sys.stdout.write(text)
    if a.json:
        print(json.dumps(info))


if __name__ == "__main__":
    main()

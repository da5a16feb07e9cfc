#!/usr/bin/python3
"""Cooling of a granular gas in a gas at rest, with the drag law's Reynolds dependence.

docs/theory.md §3.2 gives T/T0 for drag with a constant coefficient (MFIX-Exa's DEM07 law). With a
drag law whose F depends on the particle Reynolds number (BVK, BVK2: theory.md §4) the drag's
energy loss depends on the velocity distribution. For a Maxwellian of per-component variance T,

    dT/dt = -(2 / (3 m)) <beta(|v|) |v|^2> - b T^(3/2),

beta(s) = 3 pi mu d eps F(phi, Re(s)), Re = eps rho_g d s / mu, and b Haff's collisional rate
(8 / sqrt(pi)) (1 - e^2) phi g0 / d. This integrates that equation (RK4 on a tabulated loss) and
prints T/T0 at t* = t sqrt(T0) / d = 10 .. 50 for the DEM07 law, for each drag law with the box's
solid fraction and with --phi-drag (the solid fraction the particles' drag sees), and for the
cfddem runs given (their diagnostics.csv).

usage: /usr/bin/python3 tools/still_gas_cooling.py [RUN_DIR ...] [--phi-drag 0.025]
Defaults are scenes/hcs_gas.toml's: 1222 particles of 100 um, 1000 kg/m^3, in a 4 mm box,
e = 0.8, T0 = 0.1, rho_g = 1, mu_g = 2e-5.
"""
import argparse
import csv
import math
import sys

import numpy as np

D, RHO_P, MU, RHO_G, E, T0 = 100e-6, 1000.0, 2e-5, 1.0, 0.8, 0.1
PHI = 1222 * math.pi / 6 * D**3 / (4e-3) ** 3
MASS = RHO_P * math.pi / 6 * D**3


def f_bvk(phi, re):
    eps = 1 - phi
    f = 10 * phi / eps**2 + eps**2 * (1 + 1.5 * math.sqrt(phi))
    if re > 0:
        f += (0.413 * re / (24 * eps**2) * (1 / eps + 3 * eps * phi + 8.4 * re**-0.343)
              / (1 + 10 ** (3 * phi) * re ** (-(1 + 4 * phi) / 2)))
    return f


def f_bvk2(phi, re):
    eps = 1 - phi
    f = 10 * phi / eps**2 + eps**2 * (1 + 1.5 * math.sqrt(phi))
    if re > 0:
        f += re * (0.11 * phi * (1 + phi) - 0.00456 / eps**4
                   + (0.169 * eps + 0.0644 / eps**4) * re**-0.343)
    return f


def drag_loss(law, phi, T):
    """<beta(|v|) |v|^2> over Maxwell speeds of per-component variance T."""
    eps = 1 - phi
    s = np.linspace(1e-9, 8 * math.sqrt(T), 800)
    pdf = math.sqrt(2 / math.pi) * s**2 / T**1.5 * np.exp(-s * s / (2 * T))
    beta = np.array([3 * math.pi * MU * D * eps * law(phi, eps * RHO_G * D * x / MU) for x in s])
    y = beta * s * s * pdf
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(s)))


def cooling(law, phi_drag, times):
    g0 = (1 - PHI / 2) / (1 - PHI) ** 3
    b = (8 / math.sqrt(math.pi)) * (1 - E * E) * PHI * g0 / D
    grid = np.geomspace(1e-5 * T0, 1.2 * T0, 300)
    table = np.log([drag_loss(law, phi_drag, x) for x in grid])

    def rate(T):
        loss = math.exp(np.interp(math.log(T), np.log(grid), table))
        return -(2 / (3 * MASS)) * loss - b * T**1.5

    T, t, out, h = T0, 0.0, [], 2e-5
    for target in times:
        while t < target - 1e-15:
            step = min(h, target - t)
            k1 = rate(T)
            k2 = rate(T + step / 2 * k1)
            k3 = rate(T + step / 2 * k2)
            k4 = rate(T + step * k3)
            T += step / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            t += step
        out.append(T / T0)
    return out


def dem07(t):
    # MFIX-Exa's DEM07 law and its constants for T0 = 0.1 (docs/theory.md §3.2).
    a, b = 91.382708, 222.511014
    return (math.exp(a * t / 2) + (b * math.sqrt(T0) / a) * (math.exp(a * t / 2) - 1)) ** -2


def run_ratios(run_dir, times):
    """T/T0 of a cfddem run (its diagnostics.csv) at the given times, linearly interpolated."""
    with open(f"{run_dir}/diagnostics.csv") as f:
        rows = list(csv.DictReader(f))
    t = np.array([float(r["time"]) for r in rows])
    T = np.array([float(r["granular_temperature"]) for r in rows])
    return [float(np.interp(x, t, T) / T[0]) for x in times]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="*")
    ap.add_argument("--phi-drag", type=float, default=0.025)
    args = ap.parse_args()
    tstar = [10, 20, 30, 40, 50]
    times = [x * D / math.sqrt(T0) for x in tstar]
    print(f"{'t*':34s}" + "".join(f"{x:>8d}" for x in tstar))
    print(f"{'DEM07 law (constant drag)':34s}" + "".join(f"{dem07(t):8.4f}" for t in times))
    for name, law in (("bvk", f_bvk), ("bvk2", f_bvk2)):
        for phi in (PHI, args.phi_drag):
            label = f"still gas, {name}, phi_drag {phi:.4f}"
            print(f"{label:34s}" + "".join(f"{x:8.4f}" for x in cooling(law, phi, times)))
    for run in args.runs:
        try:
            ratios = run_ratios(run, times)
        except OSError as e:
            print(f"still_gas_cooling: {e}", file=sys.stderr)
            return 2
        print(f"{run[-34:]:34s}" + "".join(f"{x:8.4f}" for x in ratios))
    return 0


if __name__ == "__main__":
    sys.exit(main())

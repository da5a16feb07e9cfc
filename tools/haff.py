#!/usr/bin/python3
"""Haff's law check of a homogeneous cooling run.

Fits T/T0 = (1 + t/t_H)^-2 to cfddem's diagnostics.csv (columns time, granular_temperature) by
nonlinear least squares (scipy curve_fit), prints the fitted t_H next to the kinetic-theory
prediction (docs/theory.md; Enskog, Carnahan-Starling contact value)

    1/t_H = (4/sqrt(pi)) (1 - e^2) phi g0 sqrt(T0) / d,   g0 = (1 - phi/2) / (1 - phi)^3,

optionally compares T/T0 with a LAMMPS curve (a whitespace table like tests/data/T_hcs1222_seed1.dat:
t first, then T and T/T0, or a "T/T0" column named in the last '#' header line), and plots
T/T0 against t for cfddem, LAMMPS and Haff (matplotlib, Agg) to a PNG.

usage: /usr/bin/python3 tools/haff.py runs/hcs/diagnostics.csv [--lammps tests/data/T_hcs1222_seed1.dat]
           [--e 0.8] [--d 1e-4] [--phi 0.009997] [--T0 T] [--tmax S] [--png haff.png]
Defaults are the paper's HCS: e = 0.8, d = 100 um, phi = 1222 spheres in a 4 mm box = 0.009997
(t_H = 120.06 ms at T0 = 0.01). T0 defaults to the first row of the diagnostics file.
Exit status 0; 2 for unreadable input.
"""
import argparse
import csv
import math
import sys

HCS_PHI = 1222 * math.pi * 1e-12 / 6 / (4e-3) ** 3   # 0.0099975


def g0_carnahan_starling(phi):
    return (1 - phi / 2) / (1 - phi) ** 3


def haff_time(e, phi, temperature0, diameter):
    """Predicted t_H [s]."""
    rate = 4 / math.sqrt(math.pi) * (1 - e * e) * phi * g0_carnahan_starling(phi) \
        * math.sqrt(temperature0) / diameter
    return 1 / rate


def haff_curve(t, t_h):
    return (1 + t / t_h) ** -2


def read_diagnostics(path):
    import numpy as np
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows or "time" not in rows[0] or "granular_temperature" not in rows[0]:
        raise ValueError(f"{path}: need a header with columns time, granular_temperature")
    t = np.array([float(r["time"]) for r in rows])
    temp = np.array([float(r["granular_temperature"]) for r in rows])
    return t, temp


def read_curve(path):
    """(t, T/T0) from a whitespace table; the T/T0 column is found from the header if named."""
    import numpy as np
    names = []
    with open(path) as f:
        for line in f:
            if line.startswith("#"):
                w = line[1:].split()
                if w and w[0].lower().startswith("t"):
                    names = w
    data = np.loadtxt(path, comments="#", ndmin=2)
    col = next((k for k, n in enumerate(names) if "T/T0" in n), None)
    if col is not None and col < data.shape[1]:
        return data[:, 0], data[:, col]
    return data[:, 0], data[:, 1] / data[0, 1]


def fit_haff(t, ratio, guess):
    import numpy as np
    from scipy.optimize import curve_fit
    popt, pcov = curve_fit(haff_curve, t, ratio, p0=[guess])
    return float(popt[0]), float(np.sqrt(pcov[0, 0]))


def main(argv=None):
    ap = argparse.ArgumentParser(description="Fit Haff's law to a cfddem diagnostics.csv")
    ap.add_argument("diagnostics", help="cfddem diagnostics.csv (time, granular_temperature)")
    ap.add_argument("--lammps", help="LAMMPS T(t) table to compare with (t, T, T/T0, ...)")
    ap.add_argument("--e", type=float, default=0.8, help="restitution (default 0.8)")
    ap.add_argument("--d", type=float, default=1e-4, help="diameter in m (default 1e-4)")
    ap.add_argument("--phi", type=float, default=HCS_PHI,
                    help=f"solid fraction (default {HCS_PHI:.6f}: 1222 spheres in 4 mm)")
    ap.add_argument("--T0", type=float, help="T0 in m^2/s^2 (default: the first row)")
    ap.add_argument("--tmax", type=float, help="fit and compare only t <= tmax [s]")
    ap.add_argument("--png", help="write a plot of T/T0 vs t here")
    a = ap.parse_args(argv)

    import numpy as np
    try:
        t, temp = read_diagnostics(a.diagnostics)
        ref = read_curve(a.lammps) if a.lammps else None
    except (OSError, ValueError) as err:
        print(f"haff.py: {err}", file=sys.stderr)
        return 2
    t0 = a.T0 if a.T0 else temp[0]
    keep = t <= a.tmax if a.tmax else np.ones_like(t, dtype=bool)
    t, ratio = t[keep], temp[keep] / t0
    if len(t) < 2:
        print("haff.py: fewer than two rows to fit", file=sys.stderr)
        return 2

    t_pred = haff_time(a.e, a.phi, t0, a.d)
    t_fit, t_err = fit_haff(t, ratio, t_pred)
    print(f"rows {len(t)}, t = 0 .. {t[-1] * 1e3:.4g} ms, T0 = {t0:.6g} m^2/s^2, "
          f"e = {a.e}, d = {a.d:g} m, phi = {a.phi:.6g}, g0 = {g0_carnahan_starling(a.phi):.6g}")
    print(f"t_H fit        = {t_fit * 1e3:.4f} ms (+- {t_err * 1e3:.2g} ms, 1 sigma)")
    print(f"t_H prediction = {t_pred * 1e3:.4f} ms   fit / prediction = {t_fit / t_pred:.4f}")
    print(f"T/T0 at t = {t[-1] * 1e3:.4g} ms: run {ratio[-1]:.6f}, fit "
          f"{haff_curve(t[-1], t_fit):.6f}, prediction {haff_curve(t[-1], t_pred):.6f}")

    if ref is not None:
        rt, rr = ref
        if a.tmax:
            rt, rr = rt[rt <= a.tmax], rr[rt <= a.tmax]
        both = (t >= rt[0]) & (t <= rt[-1])
        diff = ratio[both] - np.interp(t[both], rt, rr)
        if len(diff):
            print(f"vs {a.lammps}: {both.sum()} common times up to {t[both][-1] * 1e3:.4g} ms; "
                  f"T/T0 difference max {np.abs(diff).max():.3e}, RMS "
                  f"{math.sqrt(float(np.mean(diff ** 2))):.3e}")
            if len(rt) > 2:
                r_fit, _ = fit_haff(rt, rr, t_pred)
                print(f"LAMMPS t_H fit = {r_fit * 1e3:.4f} ms")
        else:
            print(f"vs {a.lammps}: no common time range")

    if a.png:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(6.4, 4.4))
        ax.plot(t * 1e3, ratio, "-", lw=1.6, label="cfddem")
        if ref is not None:
            shown = ref[0] <= t[-1] * (1 + 1e-9)   # the run's time range
            ax.plot(ref[0][shown] * 1e3, ref[1][shown], "--", lw=1.2, label="LAMMPS")
        tt = np.linspace(0, t[-1], 200)
        ax.plot(tt * 1e3, haff_curve(tt, t_fit), ":", lw=1.2,
                label=f"Haff fit, $t_H$ = {t_fit * 1e3:.2f} ms")
        ax.plot(tt * 1e3, haff_curve(tt, t_pred), "-.", lw=1.2,
                label=f"Haff prediction, $t_H$ = {t_pred * 1e3:.2f} ms")
        ax.set_xlabel("t [ms]")
        ax.set_ylabel("T / T0")
        ax.set_title(f"Homogeneous cooling, e = {a.e}, phi = {a.phi:.4g}")
        ax.grid(alpha=0.3)
        ax.legend()
        fig.tight_layout()
        fig.savefig(a.png, dpi=120)
        print(f"wrote {a.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

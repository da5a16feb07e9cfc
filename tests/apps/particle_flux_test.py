#!/usr/bin/env python3
"""Particles leaving through an outflow face and entering through an inlet (scenes/elutriation.toml,
apps/particle_outflow.hpp, apps/particle_inlet.hpp).

Part "outflow":
For every scheme on one rank:
- the mass balance of every diagnostics row closes: particle_mass + mass_out equals the mass at
  t = 0 within 1e-12 relative (a sum of a few hundred masses of equal size: round-off is 1e-14);
- the count only falls, is the held mass over one particle's mass, and most of the bed has left
  by 10 ms (the inflow is four times the terminal velocity);
- with particles.outflow = "wall" no particle leaves (the old behaviour, now a stated choice);
- a restart from a checkpoint taken while particles leave repeats the run bit for bit.
One rank's orb (its global mode through most of the blow-out) blows out as explicit does. On 2
ranks (where mpirun is found) every scheme closes the same balance and blows out as on one rank
(orb: one rank's leaf steps, dem.orb_global = false), and a restart across removals is bitwise.
"Blows out as" compares the two count curves as two samples of n0 exit times (same_blow_out):
the colliding bed is chaotic, so a perturbation at the gas solver's tolerance gives another
realization, and a bound on single rows below that spread fails on correct code. The islands
scheme runs a box twice as wide there: its halo grows with the particles' speed beyond half of
the scene's 0.8 mm period.

Part "inlet": the same bed with inlet.recycle (what leaves enters again at the bottom) and with
inlet.mass_rate:
- recycling never makes mass: mass_in <= mass_out at every row, the balance closes to 1e-12, and
  the count is back within 3% of the start at 15 ms (a particle waits when 50 tries find no place
  in the slab, crowded while the bed blows out at 5-6 ms);
- a mass rate R places one particle of mass m as soon as R t covers it: mass_in lies within
  [R t - m, R (t + dt_f)] at every row (the row at t follows the edit at t);
- a restart across insertions is bitwise for every scheme (and orb on 2 ranks), and 2 ranks keep
  the same balance;
- a column empty at t = 0 fills from the inlet (the particle step from the inlet's sizes).

Usage: particle_flux_test.py CFDDEM SOURCE_DIR outflow|inlet [MPIEXEC]
"""
import csv
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

CFDDEM, SOURCE, PART = sys.argv[1], sys.argv[2], sys.argv[3]
MPIEXEC = sys.argv[4] if len(sys.argv) > 4 else shutil.which("mpirun")
SCENE = os.path.join(SOURCE, "scenes", "elutriation.toml")


def run(out, *extra, ranks=1):
    cmd = [CFDDEM, "run", SCENE, *extra, "--quiet", "--overwrite", "--out", out]
    env = None
    if ranks > 1:
        cmd = [MPIEXEC, "-np", str(ranks), "--oversubscribe", *cmd]
        env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=240, env=env)
    if p.returncode != 0:
        raise AssertionError(f"cfddem failed ({p.returncode}): {p.stderr}")
    return p


def rows(out):
    with open(os.path.join(out, "diagnostics.csv")) as f:
        return list(csv.DictReader(f))


WIDE = ["domain.hi=[1.6e-3,3e-3,1.6e-3]", "particles.region_hi=[1.6e-3,1.5e-3,1.6e-3]",
        "particles.count=1600", "fluid.cells=[16,30,16]"]


RECYCLE = ["inlet.recycle=true", "inlet.region_lo=[0,0,0]", "inlet.region_hi=[0.8e-3,0.5e-3,0.8e-3]",
           "inlet.velocity=[0,0.2,0]"]


def check_recycle(scheme, tmp, ranks=1):
    out = os.path.join(tmp, f"recycle_{scheme}_{ranks}")
    run(out, f"dem.scheme={scheme}", *RECYCLE, "run.end_time=0.015", ranks=ranks)
    r = rows(out)
    m0 = float(r[0]["particle_mass"])
    n0 = int(float(r[0]["particles"]))
    for x in r:
        held, out_, in_ = float(x["particle_mass"]), float(x["mass_out"]), float(x["mass_in"])
        assert abs(held - in_ + out_ - m0) <= 1e-12 * m0, (scheme, ranks, x["time"])
        assert in_ <= out_, (scheme, ranks, x["time"], in_, out_)
    # While the bed blows out (5-6 ms) up to 20 particles leave per fluid step and wait when the
    # slab has no room; once the burst is over the queue drains.
    assert int(float(r[-1]["particles"])) >= 0.97 * n0, (scheme, ranks, r[-1]["particles"])
    assert float(r[-1]["mass_out"]) > 0.5 * m0 and float(r[-1]["mass_in"]) > 0.9 * float(r[-1]["mass_out"])
    print(f"{scheme} on {ranks} rank(s): recycled {float(r[-1]['mass_in']) / m0:.2f} of the bed's "
          f"mass, count {min(int(float(x['particles'])) for x in r)}..{n0}")
    return [int(float(x["particles"])) for x in r]


def check_mass_rate(scheme, tmp):
    out = os.path.join(tmp, f"rate_{scheme}")
    rate, dt_f = 5.0e-6, 1e-4  # about one particle (5.2e-10 kg) per fluid step
    run(out, f"dem.scheme={scheme}", f"inlet.mass_rate={rate}", "inlet.region_lo=[0,0,0]",
        "inlet.region_hi=[0.8e-3,0.5e-3,0.8e-3]", "run.end_time=0.006")
    r = rows(out)
    m0 = float(r[0]["particle_mass"])
    mp = m0 / int(float(r[0]["particles"]))
    for x in r:
        t, in_ = float(x["time"]), float(x["mass_in"])
        assert rate * t - mp * (1 + 1e-9) <= in_ <= rate * (t + dt_f) * (1 + 1e-9), (scheme, t, in_)
        assert abs(float(x["particle_mass"]) - in_ + float(x["mass_out"]) - m0) <= 1e-12 * m0
    print(f"{scheme}: mass rate {rate} kg/s, {float(r[-1]['mass_in']) / mp:.0f} particles in by "
          f"{r[-1]['time']} s")


def check_empty_start(scheme, tmp):
    # No particle at t = 0: the particle step and cut-offs come from the inlet's sizes.
    out = os.path.join(tmp, f"empty_{scheme}")
    run(out, f"dem.scheme={scheme}", "particles.count=0", "inlet.mass_rate=1e-5",
        "inlet.region_lo=[0,0,0]", "inlet.region_hi=[0.8e-3,0.5e-3,0.8e-3]", "run.end_time=0.003")
    r = rows(out)
    assert int(float(r[0]["particles"])) == 0 and int(float(r[-1]["particles"])) > 40, r[-1]
    for x in r:
        held, in_ = float(x["particle_mass"]), float(x["mass_in"])
        assert abs(held - in_ + float(x["mass_out"])) <= 1e-12 * max(in_, 1e-30), (scheme, x)
    print(f"{scheme}: from an empty column, {r[-1]['particles']} particles by {r[-1]['time']} s")


def check_own_kind(scheme, tmp):
    # inlet.diameter and inlet.density of their own (60 um, 500 kg/m^3: 0.11 of the bed's
    # particle mass): every entering particle has that mass, the rate holds as above, and the
    # particle step is that of the lighter ones (the step model's range holds both kinds; a step
    # of the bed's particles would let the light ones overlap past dem.max_overlap).
    out = os.path.join(tmp, f"kind_{scheme}")
    rate, dt_f = 2.0e-5, 1e-4
    m_in = 500 * 4 / 3 * math.pi * 30e-6 ** 3
    run(out, f"dem.scheme={scheme}", f"inlet.mass_rate={rate}", "inlet.region_lo=[0,0,0]",
        "inlet.region_hi=[0.8e-3,0.5e-3,0.8e-3]", "inlet.diameter=60e-6", "inlet.density=500",
        "run.end_time=0.003")
    r = rows(out)
    m0 = float(r[0]["particle_mass"])
    for x in r:
        t, in_ = float(x["time"]), float(x["mass_in"])
        assert abs(in_ / m_in - round(in_ / m_in)) < 1e-9, (scheme, t, in_ / m_in)
        assert rate * t - m_in * (1 + 1e-9) <= in_ <= rate * (t + dt_f) * (1 + 1e-9), (scheme, t, in_)
        assert abs(float(x["particle_mass"]) - in_ + float(x["mass_out"]) - m0) <= 1e-12 * m0
    with open(os.path.join(out, "run.json")) as f:
        info = json.load(f)
    cfg = info["configuration"]
    # dt_factor sqrt(m / k) of the lighter kind (explicit shortens it to a whole number of steps
    # per fluid step; the bed's own particles alone would give 3x more).
    step = float(cfg["dem.dt_factor"]) * math.sqrt(m_in / float(cfg["dem.spring_constant"]))
    shortest = dt_f / math.ceil(dt_f / step)
    assert shortest * (1 - 1e-9) <= info["dt"] <= step * (1 + 1e-9), (scheme, info["dt"], step)
    print(f"{scheme}: {float(r[-1]['mass_in']) / m_in:.0f} particles of the inlet's own kind in by "
          f"{r[-1]['time']} s")


def check_own_distribution(scheme, tmp):
    # inlet.diameter = { uniform, 60..80 um } and 500 kg/m^3: each entering particle draws its own
    # size; the rate holds within one particle of the largest mass, the balance closes, and the
    # step is that of the smallest entering particle.
    out = os.path.join(tmp, f"dist_{scheme}")
    rate, dt_f = 2.0e-5, 1e-4
    m_lo = 500 * 4 / 3 * math.pi * 30e-6 ** 3
    m_hi = 500 * 4 / 3 * math.pi * 40e-6 ** 3
    run(out, f"dem.scheme={scheme}", f"inlet.mass_rate={rate}", "inlet.region_lo=[0,0,0]",
        "inlet.region_hi=[0.8e-3,0.5e-3,0.8e-3]",
        'inlet.diameter={distribution="uniform",min=60e-6,max=80e-6}', "inlet.density=500",
        "run.end_time=0.002")
    r = rows(out)
    m0, n0 = float(r[0]["particle_mass"]), int(float(r[0]["particles"]))
    for x in r:
        t, in_ = float(x["time"]), float(x["mass_in"])
        assert rate * t - m_hi * (1 + 1e-9) <= in_ <= rate * (t + dt_f) * (1 + 1e-9), (scheme, t, in_)
        assert abs(float(x["particle_mass"]) - in_ + float(x["mass_out"]) - m0) <= 1e-12 * m0
    entered = int(float(r[-1]["particles"])) - n0  # nothing leaves this early
    in_ = float(r[-1]["mass_in"])
    assert in_ / m_hi <= entered <= in_ / m_lo, (scheme, entered, in_ / m_hi, in_ / m_lo)
    with open(os.path.join(out, "run.json")) as f:
        info = json.load(f)
    cfg = info["configuration"]
    step = float(cfg["dem.dt_factor"]) * math.sqrt(m_lo / float(cfg["dem.spring_constant"]))
    assert dt_f / math.ceil(dt_f / step) * (1 - 1e-9) <= info["dt"] <= step * (1 + 1e-9), info["dt"]
    print(f"{scheme}: {entered} particles of the inlet's own distribution in by {r[-1]['time']} s "
          f"(mean mass {in_ / entered:.3g} kg, between {m_lo:.3g} and {m_hi:.3g})")


def check_balance(scheme, tmp, ranks=1, extra=()):
    out = os.path.join(tmp, f"{scheme}_{ranks}")
    run(out, f"dem.scheme={scheme}", *extra, ranks=ranks)
    r = rows(out)
    m0 = float(r[0]["particle_mass"])
    n0 = int(float(r[0]["particles"]))
    mp = m0 / n0
    last = n0
    for x in r:
        held, gone = float(x["particle_mass"]), float(x["mass_out"])
        n = int(float(x["particles"]))
        assert abs(held + gone - m0) <= 1e-12 * m0, (scheme, ranks, x["time"], held, gone, m0)
        assert float(x["mass_in"]) == 0.0, x["mass_in"]
        assert n <= last, (scheme, ranks, x["time"], n, last)
        assert abs(held - n * mp) <= 1e-12 * m0, (scheme, ranks, x["time"], held, n)
        last = n
    assert last < n0 // 2, (scheme, ranks, "most of the bed should have left by then", last)
    print(f"{scheme} on {ranks} rank(s): {n0} -> {last} particles, balance closes at every row")
    return [float(x["time"]) for x in r], [int(float(x["particles"])) for x in r]


def check_restart(scheme, tmp, ranks=1, extra=()):
    full = os.path.join(tmp, f"full_{scheme}_{ranks}")
    second = os.path.join(tmp, f"second_{scheme}_{ranks}")
    common = [f"dem.scheme={scheme}", "run.end_time=0.007", *extra]
    run(full, *common, "output.checkpoint_interval=0.005", ranks=ranks)
    r = rows(full)
    at5 = [x for x in r if abs(float(x["time"]) - 0.005) < 1e-9][0]
    # Particles leave (and with an inlet enter) after the checkpoint.
    assert float(at5["mass_out"]) > 0 and float(r[-1]["mass_out"]) > float(at5["mass_out"])
    if extra:
        assert float(r[-1]["mass_in"]) > float(at5["mass_in"])
    run(second, *common, "--restart", os.path.join(full, "checkpoint_000000050.h5"), ranks=ranks)
    a, b = rows(full), rows(second)
    assert len(a) == len(b)
    for x, y in zip(a, b):
        for k in x:
            if k != "wall_seconds":
                assert x[k] == y[k], (scheme, ranks, x["time"], k, x[k], y[k])
    print(f"{scheme} on {ranks} rank(s): restart across removals is bitwise")


def exit_moments(times, counts):
    """The restricted mean and variance of a particle's exit time over [0, T] (T the last row):
    with S(t) = n(t) / n0 the fraction still in, E[min(tau, T)] = int_0^T S dt and
    E[min(tau, T)^2] = int_0^T 2 t S dt (trapezoid rule over the rows)."""
    m1 = m2 = 0.0
    n0 = counts[0]
    for i in range(1, len(times)):
        h = times[i] - times[i - 1]
        s0, s1 = counts[i - 1] / n0, counts[i] / n0
        m1 += 0.5 * h * (s0 + s1)
        m2 += h * (times[i - 1] * s0 + times[i] * s1)
    return m1, max(0.0, m2 - m1 * m1)  # the rows' quadrature can round it below zero


def same_blow_out(one, many, what):
    """Two blow-outs of one bed agree as two samples of exit times (counts at the same rows).

    The bed is chaotic: the one-rank orb's count curve at fluid.tolerance 1e-10, 1e-11, 1e-12 and
    at 5e-11 .. 2e-12 (and two ranks' at those) differ by 3 to 16 particles of 400 at some row, so
    a bound of 2% on every row (the test's former one) failed on unchanged code at a tighter
    solver tolerance. Counted as samples of the n0 particles' exit times the differences are
    those of statistics, with bounds that follow from the sample size:
    - the largest difference of the fractions still in, at any row, within the two-sample
      Kolmogorov-Smirnov bound at significance 1e-3, c sqrt(1/n_a + 1/n_b), c = sqrt(ln(2/1e-3)/2)
      = 1.95 (55 particles of 400); the rows sample the curves, so this bounds the statistic from
      below;
    - the restricted mean exit times within 3 standard errors of a difference of two independent
      samples (sqrt(var_a/n_a + var_b/n_b), each variance from its own curve).
    Two realizations share the initial bed, so they differ less than independent samples do: 15
    such pairs (one rank at 1e-10 against the others, and one rank against two at each of
    5e-11 .. 2e-12) differ by 0.01-0.86 standard errors. One rank's orb leaf steps, which lag the
    explicit scheme (296 particles left at 5 ms against 217), differ from it by 10.6 standard
    errors and by 105 particles at a row: both bounds catch that.
    """
    (ta, na), (tb, nb) = one, many
    assert ta == tb, (what, "rows at different times", ta, tb)
    ks = max(abs(a / na[0] - b / nb[0]) for a, b in zip(na, nb))
    c = math.sqrt(math.log(2 / 1e-3) / 2)
    ks_bound = c * math.sqrt(1 / na[0] + 1 / nb[0])
    (ma, va), (mb, vb) = exit_moments(ta, na), exit_moments(tb, nb)
    se = math.sqrt(va / na[0] + vb / nb[0])
    z = (ma - mb) / se if se > 0 else (0.0 if ma == mb else math.inf)
    print(f"{what}: largest difference of the fraction still in {ks:.4f} (bound {ks_bound:.4f}); "
          f"mean exit time {ma * 1e3:.4f} against {mb * 1e3:.4f} ms, {z:+.2f} standard errors")
    assert ks <= ks_bound, (what, ks, ks_bound, na, nb)
    assert abs(ma - mb) <= 3 * se, (what, ma, mb, se, na, nb)


def close_counts(one, many, what):
    assert len(one) == len(many), what
    for a, b in zip(one, many):
        assert abs(a - b) <= 0.02 * one[0], (what, one, many)


def outflow(tmp):
    counts = {}
    for scheme in ("explicit", "orb", "islands"):
        counts[scheme] = check_balance(scheme, tmp)
        check_restart(scheme, tmp)
    wall = os.path.join(tmp, "wall")
    run(wall, 'particles.outflow="wall"', "run.end_time=0.006")
    assert all(int(float(x["particles"])) == 400 and float(x["mass_out"]) == 0.0
               for x in rows(wall))
    # One rank's orb takes its global mode through most of the blow-out (every particle on the
    # fine steps, no frozen partners) and follows the explicit scheme's counts (the leaf steps
    # lag: 296 particles left at 5 ms against 217); R ranks take the leaf steps, as one rank does
    # with dem.orb_global = false.
    same_blow_out(counts["explicit"], counts["orb"], "orb's global mode and explicit")
    if MPIEXEC:
        leaf = ["dem.orb_global=false"]
        same_blow_out(counts["explicit"], check_balance("explicit", tmp, ranks=2), "explicit")
        same_blow_out(check_balance("orb", tmp, extra=leaf), check_balance("orb", tmp, ranks=2),
                      "orb")
        check_restart("explicit", tmp, ranks=2)
        wide = [*WIDE, "run.end_time=0.006"]
        same_blow_out(check_balance("islands", tmp, extra=wide),
                      check_balance("islands", tmp, ranks=2, extra=wide), "islands")
    else:
        print("mpirun not found: the 2-rank cases were not run")


def inlet(tmp):
    counts = {}
    for scheme in ("explicit", "orb", "islands"):
        counts[scheme] = check_recycle(scheme, tmp)
        check_restart(scheme, tmp, extra=RECYCLE)
    for scheme in ("explicit", "islands"):
        check_mass_rate(scheme, tmp)
        check_empty_start(scheme, tmp)
        check_own_kind(scheme, tmp)
        check_own_distribution(scheme, tmp)
    if MPIEXEC:
        close_counts(counts["explicit"], check_recycle("explicit", tmp, ranks=2), "explicit")
        check_restart("orb", tmp, ranks=2, extra=RECYCLE)
    else:
        print("mpirun not found: the 2-rank cases were not run")


def main():
    with tempfile.TemporaryDirectory() as tmp:
        {"outflow": outflow, "inlet": inlet}[PART](tmp)
    print("OK")


if __name__ == "__main__":
    main()

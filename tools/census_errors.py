"""Errors of a run in the contact census: the diagnostics columns of dem/contact_census.hpp
(contacts, overlap_mean, overlap_max, collision_frequency, the wall ones and coordination_0 ..
coordination_12), compared with a reference run over time windows.

The census of one row is an instant: in a dilute gas a handful of contacts are open at a time, so
row-by-row differences are mostly sampling noise. A window is therefore reduced first, the same
way in every run, and the reduced values are compared:

  collision_frequency, wall_collision_frequency   mean over the window's rows [1/s]
  overlap_mean                                    contact-weighted mean over the rows:
                                                  sum(overlap_mean * contacts) / sum(contacts)
  wall_overlap_mean                               the same with wall_contacts
  overlap_max                                     the largest over the rows
  coordination                                    the coordination-number distribution: the
                                                  bins' counts summed over the rows, normalised

  error = |X - X_ref| / |X_ref| for the scalars (0 when both are 0, inf when only X_ref is),
  error = sum_k |p_k - p_ref,k| (the L1 distance, 0 .. 2) for the coordination distribution.

The wall quantities are left out when the reference has no wall contact at all (periodic boxes).

Sampling noise. A row catches a contact only if the contact is open at the row's instant (a
contact lasts t_c, rows are output.interval apart), so the window's census is a sample of the
contact-instants it caught. Two runs whose collisions happen at slightly different times (any
two schemes, long before chaos separates their bulk observables) catch different contacts, and
their window values differ by that sampling alone. sampling() estimates it from the rows
themselves (rows further apart than t_c are independent samples): the standard error of the
window mean of the collision frequency (the rows' standard deviation over sqrt(rows)), and of the
contact-weighted overlap mean (the ratio estimator's, sqrt(sum n_i^2 (x_i - X)^2) / sum n_i),
for both runs combined and relative to the reference's value; NaN for overlap_max and the
coordination distribution. An error within twice that is not a measured difference; more rows
(a smaller output.interval) shrink it.
Uses numpy only.
"""
import numpy as np

SCALARS = ("collision_frequency", "overlap_mean", "overlap_max", "wall_collision_frequency",
           "wall_overlap_mean")


def has_census(d):
    """True when the diagnostics columns d (name -> array) hold the census (a run with
    output.contact_census = false writes no census columns)."""
    return "contacts" in d and "coordination_0" in d and bool(np.all(np.isfinite(d["contacts"])))


def coordination_columns(d):
    cols = [c for c in d if c.startswith("coordination_")]
    return sorted(cols, key=lambda c: int(c.split("_")[1]))


def quantities(ref):
    """The census quantities to compare against the reference ref (name -> array)."""
    q = ["collision_frequency", "overlap_mean", "overlap_max"]
    if np.any(ref["wall_contacts"] > 0):
        q += ["wall_collision_frequency", "wall_overlap_mean"]
    return q + ["coordination"]


def _rows(t, w):
    return (t > w[0]) & (t <= w[1] * (1 + 1e-12))


def window_values(d, w):
    """The census of d reduced over the rows in window w = (a, b] (the row at t = 0 is left
    out): scalar name -> value, and "coordination" -> the normalised distribution. None when the
    window holds no row."""
    keep = _rows(d["time"], w)
    if not np.any(keep):
        return None
    out = {"collision_frequency": float(np.mean(d["collision_frequency"][keep])),
           "wall_collision_frequency": float(np.mean(d["wall_collision_frequency"][keep])),
           "overlap_max": float(np.max(d["overlap_max"][keep]))}
    for name, count in (("overlap_mean", "contacts"), ("wall_overlap_mean", "wall_contacts")):
        n = d[count][keep]
        out[name] = float(np.sum(d[name][keep] * n) / np.sum(n)) if np.sum(n) > 0 else 0.0
    counts = np.array([np.sum(d[c][keep]) for c in coordination_columns(d)])
    out["coordination"] = counts / max(np.sum(counts), 1.0)
    return out


def relative(x, ref):
    if x == ref:
        return 0.0
    if ref == 0.0:
        return float("inf")
    return abs(x - ref) / abs(ref)


def l1(p, q):
    """L1 distance of two distributions over the same bins (0: equal, 2: disjoint)."""
    return float(np.sum(np.abs(np.asarray(p) - np.asarray(q))))


def errors(d, ref, w, names):
    """name -> error of d against ref in window w (nan when either has no row there)."""
    a, b = window_values(d, w), window_values(ref, w)
    if a is None or b is None:
        return {n: float("nan") for n in names}
    return {n: l1(a[n], b[n]) if n == "coordination" else relative(a[n], b[n]) for n in names}


def _standard_error(d, w, q):
    keep = _rows(d["time"], w)
    if q in ("collision_frequency", "wall_collision_frequency"):
        x = d[q][keep]
        return float(np.std(x, ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")
    count = {"overlap_mean": "contacts", "wall_overlap_mean": "wall_contacts"}.get(q)
    if count is None:
        return float("nan")
    n, x = d[count][keep], d[q][keep]
    total = np.sum(n)
    if total <= 0 or np.count_nonzero(n) < 2:
        return float("nan")
    mean = np.sum(n * x) / total
    return float(np.sqrt(np.sum(n * n * (x - mean) ** 2)) / total)


def sampling(d, ref, w, q):
    """Relative standard error of the difference of quantity q between d and ref in window w from
    the sampling of contacts by the rows (both runs combined, over |X_ref|); NaN where it is not
    defined (overlap_max, the coordination distribution, too few rows or contacts)."""
    v = window_values(ref, w)
    if v is None or q not in v or not np.isscalar(v[q]) or v[q] == 0.0:
        return float("nan")
    se = [_standard_error(x, w, q) for x in (d, ref)]
    return float(np.sqrt(se[0] ** 2 + se[1] ** 2) / abs(v[q]))


def verdict(error, floor, noise):
    """The census error against the chaos floor and the sampling noise (2 standard deviations)."""
    if not np.isfinite(error):
        return "no rows in window"
    if error <= floor:
        return "indistinguishable from chaos"
    if np.isfinite(noise) and error <= 2.0 * noise:
        return f"within the sampling noise (2 x {100 * noise:.3g}%)"
    return f"scheme error {100 * error:.3g}% above the floor {100 * floor:.3g}%" + (
        f" and the sampling noise 2 x {100 * noise:.3g}%" if np.isfinite(noise) else "")

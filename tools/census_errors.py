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
Uses numpy only.
"""
import numpy as np

SCALARS = ("collision_frequency", "overlap_mean", "overlap_max", "wall_collision_frequency",
           "wall_overlap_mean")


def has_census(d):
    """True when the diagnostics columns d (name -> array) hold the census (its columns are NaN
    in a run with output.contact_census = false)."""
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

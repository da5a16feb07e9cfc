#!/usr/bin/python3
"""A cost model of cfddem at many cores, priced from counts measured anywhere.

Two cores cannot time sixteen, but an R-rank run on them counts exactly what each rank of an
R-rank job does (run.json's rank_counts: particle steps, pair evaluations, gas cell updates,
point-to-point messages and bytes, collectives, reductions) -- counts do not depend on timing or
on oversubscription. This script prices those counts:

  compute_r   = particle_steps_r * t_ps + force_evaluations_r * t_fe + cell_updates_r * t_cell
  pressure    = max_r cells_r * (pressure iterations above the calibration's) * t_iter
                (t_* measured on one core: --calibration, a 1-rank run.json of the same scene;
                t_iter, --iteration-ns, default 20 ns per cell per iteration: one V-cycle of
                the riser grid, 0.99 ms on 51,200 cells; runs that solved with hypre on R
                ranks took far more iterations than the one-rank multigrid: riser 1e5, 304
                against 15; the multigrid is now the R-rank default too)
  halo_r      = p2p_messages_r * alpha + p2p_bytes_r / beta
  reductions  = reductions * alpha * ceil(log2 P)       (a tree: log2 P latencies each)
  collective  = 2 * collective_bytes / beta + (collectives - reductions) * alpha * ceil(log2 P)
                (an all-reduce of m bytes moves ~2m per rank: reduce-scatter + all-gather,
                Thakur, Rabenseifner & Gropp 2005; the parallel ORB's histograms are the
                large payload, 257 buckets x 8 B x 8 rounds per tree node and ORB)
  T(P)        = max_r compute_r + pressure + max_r halo_r + reductions + collective
                + coarse grid
                (bulk synchronous)
  efficiency  = T_serial / (P * T(P)),   T_serial = the calibration run's counted compute
                (a calibration on a different scene of the same scheme: the R-rank counts
                summed over the ranks, an upper bound by the pairs with a ghost; a calibration
                of another scheme is refused, exit 2)

The terms it names as limiting (the largest loss against perfect scaling):
  load imbalance  = max_r compute_r - mean_r compute_r
  halo bytes      = max_r halo_r
  reductions      = reductions * alpha * ceil(log2 P)
  collective bytes = the collective term above
  pressure iterations = the pressure term above
  coarse grid     = the pressure solve's global steps: per projection iteration, the multigrid
                    levels that no longer split over P ranks cost alpha per level and ~log2 P
                    latencies for their gather (only when the run has a gas)

Several --run-dir (a sweep at R = 2..64): each P extrapolates from the largest R <= P (the
smallest R when none is), so P = R is priced from its own counts, without extrapolation.

Extrapolation from the measured R ranks to P cores (strong scaling, the same scene):
  work per rank       x R/P, with the measured imbalance max/mean held
  halo bytes per rank x (R/P)^(2/3) (a box's surface), messages per rank held (<= 26 faces,
                        edges and corners of a box, as measured)
  reductions          held (the same steps), each costing log2 P latencies
  collective bytes    held (the ORB tree is the scene's), but the parallel ORB's median searches
                      (rank_counts.orb_search_bytes) as the nodes a rank searches by reductions
                      at P ranks against R (orb_search_nodes: one per halving of the ranks and
                      a group's top levels)
Weak scaling (--weak): work, messages and halo bytes per rank held as measured; the reductions'
log2 P and the coarse grid grow; the collective bytes grow as P / R (the scaled scene's ORB tree
and gas grid grow with the particles: the all-gathered cuts, the gas's gathered level), except
the ORB's searches, priced as above with the tree log2(P / R) levels deeper. Runs without
orb_search_bytes (before the ORB searched in rank groups) grow all their collective bytes.

Network defaults (--network):
  shm: one node's shared memory, alpha = 0.4 us, beta = 10 GB/s (Open MPI's vader/sm
       transport's published ping-pong latency and single-pair bandwidth on current x86 nodes;
       OSU micro-benchmarks osu_latency/osu_bw, mvapich.cse.ohio-state.edu/benchmarks)
  ib:  an InfiniBand HDR-class network, alpha = 1.5 us, beta = 20 GB/s (HDR 200 Gb/s = 25 GB/s
       raw, ~1 us switch-to-switch latency; NVIDIA ConnectX-6 product brief, with MPI overhead)
A node holds --cores-per-node cores (default 64): jobs within one node use shm, larger ones ib.

Cores that differ (--check): the run's rank r is priced with the r-th of several --calibration
runs, each a 1-rank run pinned to the core that rank was bound to (`taskset -c r` against
`mpirun --bind-to core`). The shared 2-core VM of docs/performance.md had one core 21% slower
than the other for a while (the same 1e5 riser step 0.787 s on core 0, 0.955 s on core 1, twice
each), and a bulk-synchronous run goes at its slowest rank's pace.

Usage:
  tools/scaling_model.py --run-dir runs/riser_r8 --calibration runs/riser_r1 --cores 16 256 4096
  tools/scaling_model.py --run-dir runs/riser_r2 --calibration runs/riser_r1 --check
  tools/scaling_model.py --run-dir runs/riser_r2 --calibration runs/r1_core0 runs/r1_core1 --check
  tools/scaling_model.py --run-dir runs/riser_r{2,4,8,16,32,64} --counts
prints CSV lines `cores,efficiency,limiting_term` after a header (--detail adds the rank count
extrapolated from and each term's seconds; --check: the model's time for each run's rank count
against its measured loop_seconds, and the relative error; --counts: the count table, per fluid
step the mean and max over the ranks). tools/scaling_model_sweep.py does a whole sweep.
"""
import argparse
import copy
import json
import math
import os
import sys

NETWORKS = {"shm": (0.4e-6, 10e9), "ib": (1.5e-6, 20e9)}


def load(run_dir):
    path = os.path.join(run_dir, "run.json") if os.path.isdir(run_dir) else run_dir
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        sys.exit(f"scaling_model.py: cannot read {path}: {e}")


def config_value(j, key):
    """A value of run.json's resolved configuration (typed, or the older quoted strings)."""
    v = j.get("configuration", {}).get(key)
    if isinstance(v, str):
        try:
            return json.loads(v)
        except json.JSONDecodeError:
            return v
    return v


def gas_cells(j):
    cells = config_value(j, "fluid.cells")
    return math.prod(cells) if isinstance(cells, list) else 0


def fluid_steps(run):
    """Fluid steps of the run: the model's unit of time (per fluid step, so that runs of
    different lengths compare); 1 for a run without a gas (then per run)."""
    return max(int(run.get("fluid_steps") or run.get("gas_substeps") or 1), 1)


def scene_key(j):
    """What makes two runs the same scene for the model: scheme, particle count, gas cells (and
    without a gas, whose unit is the whole run, the end time)."""
    cells = gas_cells(j)
    return (config_value(j, "dem.scheme") or j.get("scheme"), config_value(j, "particles.count"),
            cells, None if cells else j.get("end_time", config_value(j, "run.end_time")))


def calibrate(j):
    """Seconds per particle step, per pair evaluation and per gas cell update on one core, from
    a 1-rank run's phases: neighbor + regrid + integrate over particle steps, force over pair
    evaluations, fluid over cells x gas sub-steps. Returns (t_ps, t_fe, t_cell, serial, key,
    iterations): serial is the run's counted compute per fluid step, key its scene_key,
    iterations its pressure iterations per fluid step."""
    if j.get("ranks", 1) != 1 or j.get("threads", 1) != 1:
        sys.exit("scaling_model.py: --calibration must be a run on 1 rank with 1 thread")
    ph = j["phase_seconds"]
    ps, fe = max(j.get("particle_steps", 0), 1), max(j.get("force_evaluations", 0), 1)
    cu = gas_cells(j) * j.get("gas_substeps", 0)
    t_ps = (ph.get("neighbor", 0.0) + ph.get("regrid", 0.0) + ph.get("integrate", 0.0)) / ps
    t_fe = ph.get("force", 0.0) / fe
    t_cell = ph.get("fluid", 0.0) / cu if cu > 0 else 0.0
    serial = (ps * t_ps + fe * t_fe + cu * t_cell) / fluid_steps(j)
    iterations = j.get("projection_iterations", 0) / fluid_steps(j)
    return t_ps, t_fe, t_cell, serial, scene_key(j), iterations


def serial_seconds(run, cal):
    """The one-core time of `run`'s scene: the calibration run's counted compute when it is the
    same scene; otherwise the R-rank counts summed over the ranks (particle steps and cell
    updates add up exactly; pairs with a ghost count on both ranks, so this is an upper bound
    by the ghost pairs)."""
    t_ps, t_fe, t_cell, serial, key = cal[:5]
    if key == scene_key(run):
        return serial
    rc = run["rank_counts"]
    return (sum(rc["particle_steps"]) * t_ps + sum(rc["force_evaluations"]) * t_fe +
            sum(rc["cell_updates"]) * t_cell) / fluid_steps(run)


def network(cores, name, per_node):
    if name != "auto":
        return NETWORKS[name]
    return NETWORKS["shm"] if cores <= per_node else NETWORKS["ib"]


T_ITER = 20e-9  # s per cell per pressure iteration: one V-cycle of the riser grid, 0.99 ms CPU
#                 on 51,200 cells (docs/performance_history.md, "The gas step on one rank")


def orb_search_nodes(ranks, levels):
    """Tree nodes whose weighted median a rank of the parallel ORB searches by reductions
    (partition/parallel_orb.cpp): one per halving (an even group of more than 8 ranks halves)
    and the 2^T - 1 nodes of its group's top T = ceil(log2 G) + 3 levels (at most the levels
    left); without a halving and with L <= T, every node."""
    def shared(g, levels_left):  # shared_orb_levels
        return min(levels_left, (g - 1).bit_length() + 3)
    g, halvings = ranks, 0
    while g > 8 and g % 2 == 0 and halvings < levels:
        g, halvings = g // 2, halvings + 1
    top = 0 if g == 1 else shared(g, levels - halvings)
    return halvings + 2 ** top - 1


def predict(run, cal, cores, weak, net, per_node, t_iter=T_ITER, rank_cals=None):
    """Model time per fluid step (per run without a gas) and its terms at `cores` ranks, from
    `run`'s counts at R ranks. `rank_cals` (the check of a run on cores that differ): a
    calibration per core, rank r's compute priced with rank_cals[r % len(rank_cals)]."""
    if run.get("rank_counts") is None:
        sys.exit("scaling_model.py: the run has no rank_counts (an R-rank run of cfddem is needed)")
    n = fluid_steps(run)
    rc = {k: [x / n for x in v] for k, v in run["rank_counts"].items() if isinstance(v, list)}
    R = len(rc["particle_steps"])
    t_ps, t_fe, t_cell = cal[:3]
    serial = serial_seconds(run, cal)
    # The pressure solve on R ranks may take other iteration counts than the one-rank solve
    # (hypre there, before the multigrid ran over ranks: riser 1e5, 304 against 15 per fluid
    # step): the iterations above the calibration's cost t_iter per cell each.
    extra_it = max(0.0, run.get("projection_iterations", 0) / n - cal[5])
    substeps = max(run.get("gas_substeps", 0) / n, 1.0)
    def unit_costs(r):
        return rank_cals[r % len(rank_cals)][:3] if rank_cals else (t_ps, t_fe, t_cell)

    comp = []
    for r in range(R):
        c_ps, c_fe, c_cell = unit_costs(r)
        comp.append(rc["particle_steps"][r] * c_ps + rc["force_evaluations"][r] * c_fe +
                    rc["cell_updates"][r] * c_cell)
    solve = max(rc["cell_updates"]) / substeps * extra_it * t_iter
    alpha, beta = network(cores, net, per_node)
    halo = [rc["p2p_messages"][r] * alpha + rc["p2p_bytes"][r] / beta for r in range(R)]
    reductions = max(rc["reductions"])
    mean_c, max_c = sum(comp) / R, max(comp)
    imbalance = max_c / mean_c if mean_c > 0 else 1.0
    if weak:
        work_scale, halo_bytes_scale = 1.0, 1.0
    else:
        work_scale, halo_bytes_scale = R / cores, (R / cores) ** (2.0 / 3.0)
    mean_w = mean_c * work_scale
    compute = mean_w * imbalance
    r_max = max(range(R), key=lambda r: halo[r])
    halo_t = rc["p2p_messages"][r_max] * alpha + rc["p2p_bytes"][r_max] * halo_bytes_scale / beta
    log_p = max(1, math.ceil(math.log2(max(cores, 2))))
    red_t = reductions * alpha * log_p
    # Collective payloads: the all-reduces are priced bandwidth-optimally (a reduce-scatter then
    # an all-gather moves about 2 m bytes per rank for an m-byte vector, independent of P;
    # Thakur, Rabenseifner & Gropp 2005, IJHPCA 19(1)), and the collectives that are not
    # reductions (gathers, broadcasts, all-to-all of counts) pay log2 P latencies each. The
    # parallel ORB's median searches (one row of 257 buckets per node and round) scale with the
    # nodes a rank searches (orb_search_nodes); in weak scaling the scaled scene keeps 100-200
    # particles per leaf, so its tree is log2(P / R) levels deeper. The rest grows as P / R in
    # weak scaling (the all-gathered cuts, the gas's gathered level) and is held in strong.
    search = rc.get("orb_search_bytes", [0.0] * R)
    levels = config_value(run, "partition.orb_levels")
    if isinstance(levels, int) and levels > 0 and max(search) > 0:
        deeper = round(math.log2(cores / R)) if weak else 0
        search_scale = orb_search_nodes(cores, levels + deeper) / orb_search_nodes(R, levels)
    else:
        search, search_scale = [0.0] * R, 1.0
    rest_scale = cores / R if weak else 1.0
    coll_bytes = max((rc["collective_bytes"][r] - search[r]) * rest_scale +
                     search[r] * search_scale for r in range(R))
    coll_t = (2.0 * coll_bytes / beta +
              (max(rc["collectives"]) - reductions) * alpha * log_p)
    coarse_t = 0.0
    if gas_cells(run) > 0 and run.get("projection_iterations"):
        # Levels whose grid has fewer cells than ranks are gathered: about log2(cores / cells
        # per coarsest split) more latencies per V-cycle, one V-cycle per projection iteration.
        cells = gas_cells(run)
        per_rank = cells / cores if not weak else cells / R
        replicated_levels = max(0.0, math.log2(max(cores / max(per_rank, 1.0), 1.0)) / 3.0)
        levels = max(1.0, math.log2(max(per_rank, 2.0)) / 3.0) + replicated_levels
        coarse_t = run["projection_iterations"] / n * alpha * (2 * levels +
                                                               math.log2(max(cores, 2)))
    solve_t = solve * work_scale
    total = compute + solve_t + halo_t + red_t + coll_t + coarse_t
    # Perfect scaling: the 1-core run's work spread evenly (strong), or the same work per rank
    # as measured, balanced and without communication (weak).
    ideal = mean_c if weak else serial / cores
    eff = ideal / total if total > 0 else 0.0
    terms = {"load imbalance": compute - mean_w, "pressure iterations": solve_t,
             "halo bytes": halo_t, "reductions": red_t, "collective bytes": coll_t,
             "coarse grid": coarse_t}
    return total, eff, max(terms, key=terms.get), terms


def ranks_of(run):
    rc = run.get("rank_counts")
    if rc is None:
        sys.exit("scaling_model.py: the run has no rank_counts (an R-rank run of cfddem is needed)")
    return len(rc["particle_steps"])


def nearest_run(runs, cores):
    """The measured run to extrapolate from: the largest rank count not above `cores` (the
    least extrapolation in the direction the counts are known to move), else the smallest."""
    below = [r for r in runs if ranks_of(r) <= cores]
    if below:
        return max(below, key=ranks_of)
    return min(runs, key=ranks_of)


COUNT_FIELDS = ("particle_steps", "force_evaluations", "cell_updates", "p2p_messages",
                "p2p_bytes", "collectives", "collective_bytes", "reductions")


def count_rows(run):
    """Per fluid step: for each count, the mean and the max over the ranks (max/mean is the
    count's imbalance). Set-up messages (the first ORB, the first ghost exchange) are in the
    counts, spread over the steps."""
    rc, n = run["rank_counts"], fluid_steps(run)
    row = {"ranks": ranks_of(run), "fluid_steps": n}
    for f in COUNT_FIELDS:
        v = rc[f]
        row[f"{f}_mean"] = sum(v) / len(v) / n
        row[f"{f}_max"] = max(v) / n
    return row


def count_maxima(run):
    """Per count, its maximum over the ranks per fluid step (what the model's terms price)."""
    n = fluid_steps(run)
    return {f: max(run["rank_counts"][f]) / n for f in COUNT_FIELDS}


def trend_exponents(small, big, n_small, n_big):
    """Per count, the exponent e of max_r count ~ N^e between two scenes of one base and scheme
    at the same rank count (`small` and `big`: count_maxima of runs with n_small and n_big
    particles). A count that is zero in either keeps e = 1 (work is linear in N; a zero count
    stays zero when grown). A count that fell as the scene grew (e < 0) is held instead (e = 0):
    at a fixed rank count a larger scene moves no fewer bytes with the same algorithm, and such a
    fall comes from a change of algorithm between the two sizes (fluid.solver = "auto" takes
    hypre where the multigrid's hierarchy ends large: the riser at 1e6 but not at 1e5), which the
    next decade does not repeat."""
    out = {}
    for f in COUNT_FIELDS:
        a, b = small[f], big[f]
        out[f] = max(0.0, math.log(b / a) / math.log(n_big / n_small)) if a > 0 and b > 0 else 1.0
    return out


def grow(run, factor, exponents):
    """`run`'s scene grown `factor` times in particles as tools/scaled_scene.py grows it (the two
    lateral axes, cells with them), priced as counts, not run: every rank's count times
    factor ** exponents[count], the measured trend of that count with N continued. The pressure
    iterations per fluid step are held (the multigrid's count does not grow with the grid)."""
    g = copy.deepcopy(run)
    g["rank_counts"] = {k: ([x * factor ** exponents[k] for x in v] if k in exponents else v)
                        for k, v in run["rank_counts"].items()}
    g["particles"] = run["particles"] * factor
    cfg = g.setdefault("configuration", {})
    cells = config_value(run, "fluid.cells")
    if isinstance(cells, list):
        side = math.sqrt(factor)
        cfg["fluid.cells"] = [round(cells[0] * side), cells[1], round(cells[2] * side)]
    cfg["particles.count"] = run["particles"] * factor
    return g


def check_scheme(run, cal, where):
    if cal[4][0] != scene_key(run)[0]:
        print(f"scaling_model.py: {where} is a {scene_key(run)[0]} run but --calibration is a "
              f"{cal[4][0]} run: calibrate each scheme with its own 1-rank run", file=sys.stderr)
        sys.exit(2)


def plot(path, curves, title=None):
    """curves: [(label, [(cores, efficiency, limiting_term)])] -> a PNG of efficiency against
    cores, each point annotated with the first letter(s) of its limiting term."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    short = {"load imbalance": "imb", "halo bytes": "halo", "reductions": "red",
             "collective bytes": "coll", "coarse grid": "cg", "pressure iterations": "p-it"}
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for label, pts in curves:
        xs, ys = [p[0] for p in pts], [p[1] for p in pts]
        ax.plot(xs, ys, marker="o", label=label)
        for x, y, lim in pts:
            ax.annotate(short.get(lim, lim), (x, y), textcoords="offset points", xytext=(3, 3),
                        fontsize=7)
    ax.set_xscale("log", base=2)
    ax.set_xlabel("cores (1 thread per rank)")
    ax.set_ylabel("predicted parallel efficiency")
    ax.set_ylim(0, 1.05)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    tmp = path + ".tmp.png"
    fig.savefig(tmp, dpi=120)
    os.replace(tmp, path)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run-dir", required=True, nargs="+",
                    help="R-rank runs of one scene (run.json with rank_counts); several: each "
                         "core count extrapolates from the largest R not above it")
    ap.add_argument("--calibration", nargs="+",
                    help="a 1-rank, 1-thread run of the same scheme (per-core speed); not "
                         "needed with --counts. Several (--check only): one per core the "
                         "checked ranks ran on, rank r priced by the r-th (cores that differ)")
    ap.add_argument("--cores", type=int, nargs="+", default=[16, 256, 4096])
    ap.add_argument("--weak", action="store_true", help="weak scaling (work per rank held)")
    ap.add_argument("--network", choices=["auto", "shm", "ib"], default="auto")
    ap.add_argument("--cores-per-node", type=int, default=64)
    ap.add_argument("--iteration-ns", type=float, default=T_ITER * 1e9,
                    help="ns per cell per pressure iteration (default %(default)g)")
    ap.add_argument("--check", action="store_true",
                    help="compare the model with each run's measured loop_seconds")
    ap.add_argument("--detail", action="store_true",
                    help="add the run used and each term's seconds to the CSV")
    ap.add_argument("--counts", action="store_true",
                    help="print the count table (per fluid step, mean and max over the ranks)")
    ap.add_argument("--label", default="", help="a label for --plot's curve")
    ap.add_argument("--plot", help="write a PNG of the predicted efficiencies")
    a = ap.parse_args()
    for c in a.cores:
        if c < 1:
            sys.exit(f"scaling_model.py: --cores {c}: must be >= 1")
    runs = sorted((load(d) for d in a.run_dir), key=ranks_of)
    if a.counts:
        rows = [count_rows(r) for r in runs]
        print(",".join(rows[0].keys()))
        for row in rows:
            print(",".join(f"{v:.6g}" if isinstance(v, float) else str(v) for v in row.values()))
        return
    if not a.calibration:
        sys.exit("scaling_model.py: --calibration is required (except with --counts)")
    cals = [calibrate(load(c)) for c in a.calibration]
    cal = cals[0]
    if len(cals) > 1 and not a.check:
        sys.exit("scaling_model.py: several --calibration runs are for --check (one per core "
                 "of the checked run); a prediction takes one")
    for d, r in zip(a.run_dir, runs):
        for c in cals:
            check_scheme(r, c, d)
    if a.check:
        print("ranks,model_seconds_per_fluid_step,measured_seconds_per_fluid_step,"
              "relative_error,limiting_term")
        for run in runs:
            R = ranks_of(run)
            total, _, lim, _ = predict(run, cal, R, True, a.network, a.cores_per_node,
                                       a.iteration_ns * 1e-9, cals if len(cals) > 1 else None)
            meas = run["loop_seconds"] / fluid_steps(run)
            print(f"{R},{total:.6g},{meas:.6g},{(total - meas) / meas:.4g},{lim}")
        return
    header = "cores,efficiency,limiting_term"
    if a.detail:
        header += (",from_ranks,model_seconds,imbalance_s,pressure_iterations_s,halo_s,"
                   "reductions_s,collective_s,coarse_grid_s")
    print(header)
    pts = []
    for c in a.cores:
        run = nearest_run(runs, c)
        total, eff, lim, terms = predict(run, cal, c, a.weak, a.network, a.cores_per_node,
                                         a.iteration_ns * 1e-9)
        pts.append((c, eff, lim))
        line = f"{c},{eff:.4f},{lim}"
        if a.detail:
            line += (f",{ranks_of(run)},{total:.6g},{terms['load imbalance']:.4g},"
                     f"{terms['pressure iterations']:.4g},"
                     f"{terms['halo bytes']:.4g},{terms['reductions']:.4g},"
                     f"{terms['collective bytes']:.4g},{terms['coarse grid']:.4g}")
        print(line)
    if a.plot:
        plot(a.plot, [(a.label or ("weak" if a.weak else "strong"), pts)],
             "scaling_model.py: " + ("weak" if a.weak else "strong") + " scaling, predicted")


if __name__ == "__main__":
    main()

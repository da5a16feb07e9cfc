#!/usr/bin/python3
"""Tests of tools/scaled_scene.py and tools/scaling.py (standard library unittest, no pytest).

  /usr/bin/python3 tools/test_scaling_tools.py            # pure Python checks
  CFDDEM=build/bin/cfddem /usr/bin/python3 tools/test_scaling_tools.py
                                                          # + `cfddem check` of scaled scenes and a
                                                          #   --dry-run of scaling.py
"""
import math
import os
import subprocess
import sys
import tempfile
import tomllib
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import scaled_scene  # noqa: E402
import scaling  # noqa: E402
import scaling_model  # noqa: E402

CFDDEM = os.environ.get("CFDDEM", "")


class ScaledScene(unittest.TestCase):
    COUNTS = [2e4, 62500, 1e5, 1e6, 1e7]

    def base(self, name):
        with open(os.path.join(scaled_scene.SCENES, scaled_scene.BASES[name]), "rb") as f:
            return tomllib.load(f)

    def test_keeps_count_cell_size_and_solid_fraction(self):
        for name in scaled_scene.BASES:
            b = self.base(name)
            h0 = [(b["domain"]["hi"][i] - b["domain"]["lo"][i]) / b["fluid"]["cells"][i]
                  for i in range(3)]
            for grow in ("xz", "xyz"):
                for n in self.COUNTS:
                    with self.subTest(base=name, grow=grow, n=n):
                        s, over, info = scaled_scene.scale_scene(name, int(n), grow)
                        self.assertEqual(s["particles"]["count"], int(n))
                        self.assertEqual(s["particles"]["diameter"], b["particles"]["diameter"])
                        cells = s["fluid"]["cells"]
                        self.assertTrue(all(isinstance(c, int) and c >= 1 for c in cells))
                        for i in range(3):
                            h = (s["domain"]["hi"][i] - s["domain"]["lo"][i]) / cells[i]
                            self.assertAlmostEqual(h / h0[i], 1.0, places=10)
                        rel = info["solid_fraction"] / info["solid_fraction_base"] - 1
                        # the bounds of the module docstring (even periods cost the riser a
                        # coarser choice of products)
                        self.assertLess(abs(rel), 0.014 if n < 5e4 else 0.012 if n < 1e6
                                        else 0.007)
                        if grow == "xz":
                            self.assertEqual(cells[1], b["fluid"]["cells"][1])
                            self.assertEqual(s["domain"]["hi"][1], b["domain"]["hi"][1])
                        # lateral cells as even as integers allow, within two steps when
                        # periodic counts stay even
                        step = max(scaled_scene.even_step(b, 0), scaled_scene.even_step(b, 2))
                        self.assertLessEqual(abs(cells[0] - cells[2]), 2 * step)
                        for i in range(3):
                            if scaled_scene.even_step(b, i) == 2:
                                self.assertEqual(cells[i] % 2, 0, (i, cells))

    def test_cell_multiple_makes_the_grown_counts_multiples(self):
        for name in scaled_scene.BASES:
            b = self.base(name)
            for n in (1e5, 1e6):
                for m in (8, 16):
                    with self.subTest(base=name, n=n, m=m):
                        s, _, info = scaled_scene.scale_scene(name, int(n), "xz", cell_multiple=m)
                        cells = s["fluid"]["cells"]
                        self.assertEqual(cells[0] % m, 0, cells)
                        self.assertEqual(cells[2] % m, 0, cells)
                        self.assertEqual(cells[1], b["fluid"]["cells"][1])
                        self.assertEqual(s["particles"]["count"], int(n))
                        # the closest product of multiples of m is within half a step of one
                        # factor, m / (2 n_lateral) of the volume; twice that as the bound
                        rel = info["solid_fraction"] / info["solid_fraction_base"] - 1
                        self.assertLess(abs(rel), m / min(cells[0], cells[2]), (rel, cells))

    def test_orb_levels_give_100_to_200_per_leaf(self):
        for n in self.COUNTS + [14000, 10000]:
            s, over, info = scaled_scene.scale_scene("riser", int(n))
            self.assertTrue(100 <= info["particles_per_leaf"] <= 200, (n, info))
        # the base scenes' own levels are reproduced
        self.assertEqual(scaled_scene.scale_scene("riser", 14000)[2]["orb_levels"], 7)
        self.assertEqual(scaled_scene.scale_scene("fluidized_bed", 10000)[2]["orb_levels"], 6)

    def test_riser_xyz_keeps_the_pressure_gradient(self):
        b = self.base("riser")
        s, _, _ = scaled_scene.scale_scene("riser", 10 ** 6, "xyz")
        g0 = b["fluid"]["pressure_drop"][1] / b["domain"]["hi"][1]
        g = s["fluid"]["pressure_drop"][1] / s["domain"]["hi"][1]
        self.assertAlmostEqual(g / g0, 1.0, places=10)
        s, _, _ = scaled_scene.scale_scene("riser", 10 ** 6, "xz")
        self.assertEqual(s["fluid"]["pressure_drop"], b["fluid"]["pressure_drop"])

    def test_bed_region_and_lattice_capacity(self):
        b = self.base("fluidized_bed")
        for grow in ("xz", "xyz"):
            s, _, _ = scaled_scene.scale_scene("fluidized_bed", 10 ** 6, grow)
            p = s["particles"]
            self.assertEqual(p["region_hi"][0], s["domain"]["hi"][0])
            self.assertEqual(p["region_hi"][2], s["domain"]["hi"][2])
            if grow == "xz":
                self.assertEqual(p["region_hi"][1], b["particles"]["region_hi"][1])
            d = p["diameter"]
            sites = math.prod(math.floor((p["region_hi"][i] - p["region_lo"][i]) / d + 1e-9)
                              for i in range(3))
            self.assertGreaterEqual(sites, p["count"])

    def test_no_fluid_drops_the_gas_only(self):
        s, _, _ = scaled_scene.scale_scene("riser", 20000, no_fluid=True)
        self.assertNotIn("fluid", s)
        self.assertEqual(s["particles"]["count"], 20000)

    def test_toml_round_trip(self):
        for name in scaled_scene.BASES:
            s, _, _ = scaled_scene.scale_scene(name, 123456)
            text = scaled_scene.write_toml(s, ["header"])
            self.assertEqual(tomllib.loads(text), s)

    def test_fmt_count(self):
        self.assertEqual(scaled_scene.fmt_count(10 ** 6), "1e6")
        self.assertEqual(scaled_scene.fmt_count(20000), "2e4")
        self.assertEqual(scaled_scene.fmt_count(62500), "62500")


class Scaling(unittest.TestCase):
    def test_layouts(self):
        L = scaling.layouts_for
        self.assertEqual(L(1, ["ranks-only", "threads-only", "hybrid"], 4), [("serial", 1, 1)])
        self.assertEqual(L(16, ["ranks-only", "threads-only", "hybrid"], 4),
                         [("ranks-only", 16, 1), ("threads-only", 1, 16), ("hybrid", 4, 4)])
        self.assertEqual(L(2, ["hybrid"], 4), [])  # no distinct hybrid on 2 cores
        self.assertEqual(L(4, ["hybrid"], 2), [("hybrid", 2, 2)])
        self.assertEqual(L(16, ["hybrid"], [2, 4, 8, 16]),
                         [("hybrid-2t", 8, 2), ("hybrid-4t", 4, 4), ("hybrid-8t", 2, 8)])

    def test_launch_line(self):
        class A:
            launcher, binding, node_cores, binary = "mpirun", "none", 2, "cfddem"
        cmd = scaling.launch_cmd(A, 4, 1, "s.toml", ["dem.scheme=orb"], "out")
        self.assertEqual(cmd[:6], ["mpirun", "-np", "4", "--bind-to", "none", "--oversubscribe"])
        self.assertEqual(cmd[6:], ["cfddem", "run", "s.toml", "dem.scheme=orb", "--threads", "1",
                                   "--quiet", "--overwrite", "--out", "out"])
        cmd = scaling.launch_cmd(A, 2, 1, "s.toml", [], "out")
        self.assertNotIn("--oversubscribe", cmd)
        A.binding = "core"
        cmd = scaling.launch_cmd(A, 2, 4, "s.toml", [], "out")
        self.assertIn("ppr:2:node:pe=4", cmd)
        self.assertIn("--oversubscribe", cmd)  # 8 cores asked of a 2-core node

    def test_wall_per_step(self):
        t, u = scaling.wall_per_step({"loop_seconds": 2.0, "fluid_steps": 4})
        self.assertEqual((t, u), (0.5, "fluid_step"))
        t, u = scaling.wall_per_step({"loop_seconds": 2.0, "end_time": 2e-3,
                                      "configuration": {"output.interval": "0.001"}})
        self.assertAlmostEqual(t, 1.0)
        self.assertTrue(u.startswith("output_interval"))

    def rows(self):
        return [
            {"scheme": "explicit", "status": "skipped"},  # no cores: must not break anything
            {"scheme": "explicit", "layout": "serial", "cores": 1, "status": "ok",
             "wall_per_step_s": 8.0},
            {"scheme": "orb", "layout": "serial", "cores": 1, "status": "ok",
             "wall_per_step_s": 4.0},
            {"scheme": "explicit", "layout": "ranks-only", "cores": 4, "status": "ok",
             "wall_per_step_s": 2.5},
            {"scheme": "orb", "layout": "ranks-only", "cores": 4, "status": "ok",
             "wall_per_step_s": 2.0},
            {"scheme": "orb", "layout": "threads-only", "cores": 4, "status": "refused"},
        ]

    def test_strong_and_weak_efficiency(self):
        r = self.rows()
        scaling.fill_derived(r, "strong")
        self.assertAlmostEqual(r[3]["speedup"], 8.0 / 2.5)
        self.assertAlmostEqual(r[3]["efficiency"], 8.0 / (4 * 2.5))
        self.assertAlmostEqual(r[4]["efficiency"], 4.0 / (4 * 2.0))
        self.assertAlmostEqual(r[4]["speedup_vs_explicit"], 2.5 / 2.0)
        self.assertAlmostEqual(r[2]["speedup_vs_explicit"], 2.0)
        self.assertNotIn("efficiency", r[5])
        r = self.rows()
        scaling.fill_derived(r, "weak")
        self.assertAlmostEqual(r[3]["efficiency"], 8.0 / 2.5)
        self.assertAlmostEqual(r[3]["speedup"], 4 * 8.0 / 2.5)

    def test_csv_and_plot(self):
        r = self.rows()
        scaling.fill_derived(r, "strong")
        with tempfile.TemporaryDirectory() as d:
            path = os.path.join(d, "strong.csv")
            scaling.write_csv(path, r)
            back = scaling.read_csv(path)
            self.assertEqual(len(back), len(r))
            scaling.plot(back, "strong", os.path.join(d, "strong.png"), "test")
            self.assertGreater(os.path.getsize(os.path.join(d, "strong.png")), 1000)


class ScalingModel(unittest.TestCase):
    """tools/scaling_model.py on synthetic run.json files, where the answer is known."""

    @staticmethod
    def runs(ranks, steps=(1000,), pairs=(500,), msgs=0, bytes_=0, reductions=0):
        steps = list(steps) * (ranks // len(steps))
        pairs = list(pairs) * (ranks // len(pairs))
        cal = {"ranks": 1, "threads": 1, "particle_steps": sum(steps),
               "force_evaluations": sum(pairs),
               "phase_seconds": {"neighbor": 0.0, "integrate": 1e-7 * sum(steps),
                                 "force": 2e-7 * sum(pairs), "fluid": 0.0}}
        run = {"loop_seconds": 1.0, "rank_counts": {
            "particle_steps": steps, "force_evaluations": pairs, "cell_updates": [0] * ranks,
            "p2p_messages": [msgs] * ranks, "p2p_bytes": [bytes_] * ranks,
            "collectives": [reductions] * ranks, "collective_bytes": [0] * ranks,
            "reductions": [reductions] * ranks}}
        return run, scaling_model.calibrate(cal)

    def test_balanced_work_without_messages_scales_perfectly(self):
        run, cal = self.runs(4)
        for cores in (4, 64, 4096):
            _, eff, _, _ = scaling_model.predict(run, cal, cores, False, "shm", 64)
            self.assertAlmostEqual(eff, 1.0, places=12)
        _, eff, _, _ = scaling_model.predict(run, cal, 4096, True, "ib", 64)
        self.assertAlmostEqual(eff, 1.0, places=12)

    def test_imbalance_is_the_max_over_the_mean(self):
        run, cal = self.runs(2, steps=(3000, 1000), pairs=(0, 0))
        _, eff, lim, terms = scaling_model.predict(run, cal, 2, False, "shm", 64)
        self.assertAlmostEqual(eff, 2.0 / 3.0, places=12)  # mean 2000, max 3000
        self.assertEqual(lim, "load imbalance")

    def test_reductions_cost_log2_p_latencies_and_limit_at_scale(self):
        run, cal = self.runs(4, reductions=10000)
        alpha = scaling_model.NETWORKS["ib"][0]
        t16, _, _, terms16 = scaling_model.predict(run, cal, 16, False, "ib", 64)
        self.assertAlmostEqual(terms16["reductions"], 10000 * alpha * 4, places=15)
        _, e16, _, _ = scaling_model.predict(run, cal, 16, False, "ib", 64)
        _, e4096, lim, _ = scaling_model.predict(run, cal, 4096, False, "ib", 64)
        self.assertLess(e4096, e16)
        self.assertEqual(lim, "reductions")

    def test_halo_bytes_shrink_with_the_surface_in_strong_scaling(self):
        run, cal = self.runs(8, msgs=0, bytes_=8_000_000)
        beta = scaling_model.NETWORKS["shm"][1]
        _, _, _, t8 = scaling_model.predict(run, cal, 8, False, "shm", 64)
        _, _, _, t64 = scaling_model.predict(run, cal, 64, False, "shm", 64)
        self.assertAlmostEqual(t8["halo bytes"], 8e6 / beta, places=15)
        self.assertAlmostEqual(t64["halo bytes"], 8e6 / beta / 4.0, places=15)  # (8/64)^(2/3)

    def test_each_core_count_extrapolates_from_the_largest_run_not_above_it(self):
        runs = [self.runs(r)[0] for r in (2, 8, 64)]
        pick = scaling_model.nearest_run
        self.assertEqual(scaling_model.ranks_of(pick(runs, 1)), 2)  # none below: the smallest
        self.assertEqual(scaling_model.ranks_of(pick(runs, 16)), 8)
        self.assertEqual(scaling_model.ranks_of(pick(runs, 64)), 64)
        self.assertEqual(scaling_model.ranks_of(pick(runs, 4096)), 64)

    def test_count_rows_are_per_fluid_step_mean_and_max(self):
        run, _ = self.runs(2, steps=(3000, 1000), msgs=6, bytes_=100)
        run["fluid_steps"] = 2
        row = scaling_model.count_rows(run)
        self.assertEqual(row["ranks"], 2)
        self.assertEqual(row["particle_steps_mean"], 1000.0)  # (3000 + 1000) / 2 ranks / 2
        self.assertEqual(row["particle_steps_max"], 1500.0)
        self.assertEqual(row["p2p_messages_max"], 3.0)

    def test_grow_continues_each_counts_trend(self):
        # Work linear in N, halo bytes as sqrt(N) (a column grown in x and z, height fixed),
        # messages flat, a zero count staying zero: a 1e5 and a 1e6 run give those exponents,
        # and the 1e6 run grown 10x carries each count one more decade along its trend.
        small, _ = self.runs(2, steps=(1000, 1000), pairs=(0, 0), msgs=26, bytes_=1e6)
        big, cal = self.runs(2, steps=(10000, 10000), pairs=(0, 0), msgs=26, bytes_=1e6 * 10**0.5)
        small["particles"], big["particles"] = 1e5, 1e6
        big["configuration"] = {"fluid.cells": [270, 50, 270], "dem.scheme": None}
        e = scaling_model.trend_exponents(scaling_model.count_maxima(small),
                                          scaling_model.count_maxima(big), 1e5, 1e6)
        self.assertAlmostEqual(e["particle_steps"], 1.0, places=12)
        self.assertAlmostEqual(e["p2p_bytes"], 0.5, places=12)
        self.assertAlmostEqual(e["p2p_messages"], 0.0, places=12)
        self.assertEqual(e["force_evaluations"], 1.0)  # zero in both: stays zero when grown
        fell = dict(scaling_model.count_maxima(big), collective_bytes=1.0)
        rose = dict(scaling_model.count_maxima(small), collective_bytes=100.0)
        self.assertEqual(scaling_model.trend_exponents(rose, fell, 1e5, 1e6)["collective_bytes"],
                         0.0)  # a fall (another solver at the larger size) is held, not continued
        g = scaling_model.grow(big, 10.0, e)
        self.assertEqual(g["particles"], 1e7)
        self.assertAlmostEqual(g["rank_counts"]["particle_steps"][0], 1e5, places=6)
        self.assertAlmostEqual(g["rank_counts"]["p2p_bytes"][1], 1e7, places=3)
        self.assertAlmostEqual(g["rank_counts"]["p2p_messages"][0], 26.0, places=12)
        self.assertEqual(g["rank_counts"]["force_evaluations"], [0.0, 0.0])
        self.assertEqual(scaling_model.gas_cells(g), 854 * 50 * 854)  # 270 sqrt(10), rounded
        self.assertEqual(big["particles"], 1e6)  # the measured run is left as it was

    def test_a_calibration_of_another_scheme_is_refused(self):
        run, cal = self.runs(2)
        run["configuration"] = {"dem.scheme": "orb"}
        with self.assertRaises(SystemExit) as e:
            scaling_model.check_scheme(run, cal, "run")
        self.assertEqual(e.exception.code, 2)

    def test_serial_time_of_another_scene_is_the_summed_counts(self):
        # Calibrated on a scene half the size: the serial time must be the R-rank run's own
        # work (the sum over its ranks), not the smaller calibration run's.
        run, cal = self.runs(4)
        small = {"ranks": 1, "threads": 1, "particle_steps": 2000, "force_evaluations": 1000,
                 "configuration": {"particles.count": 50},
                 "phase_seconds": {"integrate": 2e-4, "force": 2e-4}}
        cal_small = scaling_model.calibrate(small)
        serial = scaling_model.serial_seconds(run, cal_small)
        self.assertAlmostEqual(serial, 4 * (1000 * 1e-7 + 500 * 2e-7), places=15)
        # Same scene: the calibration run's own counted compute.
        self.assertAlmostEqual(scaling_model.serial_seconds(run, cal), cal[3], places=15)

    def test_runs_of_different_lengths_compare_per_fluid_step(self):
        # The calibration ran 4 fluid steps, the R-rank run 1: the same scene per fluid step,
        # so balanced work without messages still scales perfectly (not 4x too well).
        run, _ = self.runs(4)
        cal = {"ranks": 1, "threads": 1, "particle_steps": 4 * 4000, "force_evaluations": 4 * 2000,
               "fluid_steps": 4, "phase_seconds": {"integrate": 4 * 4000 * 1e-7,
                                                   "force": 4 * 2000 * 2e-7}}
        run["fluid_steps"] = 1
        _, eff, _, _ = scaling_model.predict(run, scaling_model.calibrate(cal), 16, False, "shm",
                                             64)
        self.assertAlmostEqual(eff, 1.0, places=12)

    def test_collective_bytes_cost_two_passes_held_strong_grown_weak(self):
        run, cal = self.runs(4)
        run["rank_counts"]["collective_bytes"] = [1_000_000] * 4
        run["rank_counts"]["collectives"] = [10] * 4  # 10 gathers, no reductions
        alpha, beta = scaling_model.NETWORKS["ib"]
        for cores in (16, 4096):
            _, _, _, t = scaling_model.predict(run, cal, cores, False, "ib", 64)
            log_p = math.ceil(math.log2(cores))
            self.assertAlmostEqual(t["collective bytes"], 2e6 / beta + 10 * alpha * log_p,
                                   places=15)
        _, _, lim, t = scaling_model.predict(run, cal, 4096, True, "ib", 64)
        self.assertAlmostEqual(t["collective bytes"], 2e6 * 1024 / beta + 10 * alpha * 12,
                               places=12)  # the ORB tree grows with the particles: x P/R
        self.assertEqual(lim, "collective bytes")

    def test_orb_search_nodes_follow_the_parallel_orb(self):
        nodes = scaling_model.orb_search_nodes
        self.assertEqual(nodes(4, 5), 31)       # few levels: every node, by all ranks
        self.assertEqual(nodes(4, 9), 31)       # 2 + 3 levels, then each subtree alone
        self.assertEqual(nodes(16, 9), 1 + 63)  # one halving, then a group of 8: 6 levels
        self.assertEqual(nodes(4096, 21), 9 + 63)
        self.assertEqual(nodes(12, 12), 1 + 63)  # 12 -> 6 ranks: ceil(log2 6) + 3 levels
        self.assertEqual(nodes(3, 12), 31)       # odd: no halving
        self.assertEqual(nodes(1024, 13), 7 + 63)  # halvings even where the levels are few
        self.assertEqual(nodes(64, 2), 2)        # the halvings reach the leaves

    def test_orb_search_bytes_scale_with_the_nodes_the_rest_as_before(self):
        run, cal = self.runs(16)
        run["configuration"] = {"partition.orb_levels": 13}
        run["rank_counts"]["collective_bytes"] = [3_000_000] * 16
        run["rank_counts"]["orb_search_bytes"] = [2_000_000] * 16
        alpha, beta = scaling_model.NETWORKS["ib"]
        nodes = scaling_model.orb_search_nodes
        for cores, weak in ((16, False), (4096, False), (4096, True)):
            _, _, _, t = scaling_model.predict(run, cal, cores, weak, "ib", 64)
            rest = 1e6 * (cores / 16 if weak else 1.0)
            search = 2e6 * nodes(cores, 13 + (8 if weak else 0)) / nodes(16, 13)
            self.assertAlmostEqual(t["collective bytes"], 2.0 * (rest + search) / beta,
                                   places=12)

    def test_pressure_iterations_above_the_calibrations_are_priced(self):
        run, _ = self.runs(2)
        run["rank_counts"]["cell_updates"] = [2000, 1000]  # box cells x 2 gas sub-steps
        run.update(fluid_steps=1, gas_substeps=2, projection_iterations=100)
        cal = scaling_model.calibrate({"ranks": 1, "threads": 1, "particle_steps": 2000,
                                       "force_evaluations": 1000, "fluid_steps": 1,
                                       "gas_substeps": 2, "projection_iterations": 10,
                                       "phase_seconds": {"integrate": 2e-4, "force": 2e-4}})
        _, _, _, t = scaling_model.predict(run, cal, 2, True, "shm", 64, t_iter=1e-8)
        self.assertAlmostEqual(t["pressure iterations"], 1000 * 90 * 1e-8, places=15)
        run["projection_iterations"] = 10  # the calibration's: nothing extra
        _, _, _, t = scaling_model.predict(run, cal, 2, True, "shm", 64, t_iter=1e-8)
        self.assertEqual(t["pressure iterations"], 0.0)

    def test_a_calibration_per_core_prices_each_rank_on_its_own_core(self):
        # Balanced work on two cores, the second 1.25x slower: the ranks wait for it.
        run, fast = self.runs(2)
        slow_cal = {"ranks": 1, "threads": 1, "particle_steps": 2000, "force_evaluations": 1000,
                    "phase_seconds": {"neighbor": 0.0, "integrate": 1.25e-7 * 2000,
                                      "force": 1.25 * 2e-7 * 1000, "fluid": 0.0}}
        slow = scaling_model.calibrate(slow_cal)
        t_one, _, _, _ = scaling_model.predict(run, fast, 2, True, "shm", 64)
        t_two, _, lim, terms = scaling_model.predict(run, fast, 2, True, "shm", 64,
                                                     rank_cals=[fast, slow])
        self.assertAlmostEqual(t_two / t_one, 1.25, places=12)
        self.assertEqual(lim, "load imbalance")  # the slow core's share above the mean
        self.assertAlmostEqual(terms["load imbalance"], t_two - 0.5 * (t_one + t_two), places=15)

    def test_calibration_must_be_one_rank_one_thread(self):
        with self.assertRaises(SystemExit):
            scaling_model.calibrate({"ranks": 2, "threads": 1, "phase_seconds": {}})


@unittest.skipUnless(CFDDEM and os.access(CFDDEM, os.X_OK), "set CFDDEM=path/to/cfddem")
class WithBinary(unittest.TestCase):
    def test_check_accepts_scaled_scenes(self):
        with tempfile.TemporaryDirectory() as d:
            for name in scaled_scene.BASES:
                for no_fluid in (False, True):
                    s, _, _ = scaled_scene.scale_scene(name, 10 ** 5, no_fluid=no_fluid)
                    path = os.path.join(d, f"{name}_{no_fluid}.toml")
                    with open(path, "w") as f:
                        f.write(scaled_scene.write_toml(s, []))
                    r = subprocess.run([CFDDEM, "check", path], capture_output=True, text=True)
                    self.assertEqual(r.returncode, 0, r.stderr)
                    self.assertIn("particles.count = 100000", r.stdout)

    def test_dry_run(self):
        with tempfile.TemporaryDirectory() as d:
            r = subprocess.run([sys.executable, os.path.join(HERE, "scaling.py"), "weak",
                                "--base", "riser", "--particles-per-core", "1e4", "--cores",
                                "1", "2", "4", "--node-cores", "2", "--binary", CFDDEM,
                                "--out", d, "--dry-run"], capture_output=True, text=True)
            self.assertEqual(r.returncode, 0, r.stderr)
            lines = r.stdout.strip().splitlines()
            # 1 core: 1 layout; 2 and 4 cores: ranks-only + threads-only; x 3 schemes
            self.assertEqual(len(lines), 3 * (1 + 2 + 2))
            self.assertTrue(all("mpirun -np" in ln for ln in lines))
            self.assertEqual(sum("--oversubscribe" in ln for ln in lines), 3)


if __name__ == "__main__":
    unittest.main()

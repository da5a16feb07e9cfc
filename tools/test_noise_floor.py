#!/usr/bin/python3
"""Tests of tools/noise_floor.py, tools/census_errors.py and trade.py --noise-floor (standard
library unittest).

  /usr/bin/python3 tools/test_noise_floor.py                       # pure Python checks
  CFDDEM=build/bin/cfddem /usr/bin/python3 tools/test_noise_floor.py  # + runs of the binary
"""
import csv
import os
import subprocess
import sys
import tempfile
import tomllib
import unittest

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import census_errors  # noqa: E402
import noise_floor  # noqa: E402

ROOT = os.path.dirname(HERE)
CFDDEM = os.environ.get("CFDDEM", "")


def state(n, rng):
    return {"x": rng.uniform(0, 1e-3, n), "y": rng.uniform(0, 1e-3, n),
            "z": rng.uniform(0, 1e-3, n), "vx": rng.normal(size=n), "vy": rng.normal(size=n),
            "vz": rng.normal(size=n), "diameter": np.full(n, 1e-4), "density": np.full(n, 1e3)}


class Perturbation(unittest.TestCase):
    def test_moves_positions_by_at_most_rel_times_extent_and_keeps_the_rest(self):
        s = state(500, np.random.default_rng(1))
        lo, hi = [0.0, 0.0, 0.0], [1e-3, 2e-3, 1e-3]
        p = noise_floor.perturbed(s, lo, hi, [False, False, False], 1e-9, seed=7)
        for a, c in enumerate("xyz"):
            d = np.abs(p[c] - s[c])
            self.assertLessEqual(d.max(), 1e-9 * (hi[a] - lo[a]) * (1 + 1e-6))
            self.assertGreater(d.max(), 0.1 * 1e-9 * (hi[a] - lo[a]))  # it does move them
        for c in ("vx", "vy", "vz", "diameter", "density"):
            self.assertTrue(np.array_equal(p[c], s[c]))

    def test_seeds_differ_and_repeat(self):
        s = state(50, np.random.default_rng(2))
        box = ([0.0] * 3, [1e-3] * 3, [True] * 3)
        a = noise_floor.perturbed(s, *box, 1e-12, seed=1)
        b = noise_floor.perturbed(s, *box, 1e-12, seed=1)
        c = noise_floor.perturbed(s, *box, 1e-12, seed=2)
        self.assertTrue(np.array_equal(a["x"], b["x"]))
        self.assertFalse(np.array_equal(a["x"], c["x"]))

    def test_stays_in_the_box(self):
        s = state(4, np.random.default_rng(3))
        s["x"][:] = [0.0, 1e-3, 0.0, 1e-3]  # on the faces
        for per in (True, False):
            p = noise_floor.perturbed(s, [0.0] * 3, [1e-3] * 3, [per] * 3, 1e-6, seed=5)
            self.assertTrue(np.all((p["x"] >= 0.0) & (p["x"] <= 1e-3)), p["x"])


class Errors(unittest.TestCase):
    def test_window_error_is_the_trade_definition(self):
        t = np.linspace(0, 1, 11)
        ref = 1.0 + t
        o = ref * 1.01  # 1% everywhere
        for w in noise_floor.windows(1.0, 4):
            self.assertAlmostEqual(noise_floor.window_error(t, o, t, ref, w), 0.01, places=12)
        self.assertEqual(noise_floor.window_error(t, ref, t, ref, (0.0, 1.0)), 0.0)

    def test_window_leaves_out_t0_and_rows_past_the_reference(self):
        t = np.array([0.0, 0.5, 1.0, 1.5])
        o = np.array([100.0, 1.0, 1.0, 100.0])
        ref_t, ref_o = np.array([0.0, 1.0]), np.array([1.0, 1.0])
        self.assertEqual(noise_floor.window_error(t, o, ref_t, ref_o, (0.0, 2.0)), 0.0)

    def test_verdict(self):
        self.assertEqual(noise_floor.verdict(0.01, 0.02), "indistinguishable from chaos")
        self.assertIn("above the floor", noise_floor.verdict(0.03, 0.02))


def census(t, contacts, overlap, coordination, wall=None):
    """Diagnostics columns of a census: one value per row; coordination rows of 13 counts."""
    t = np.asarray(t, dtype=float)
    n = len(t)
    d = {"time": t, "contacts": np.asarray(contacts, dtype=float),
         "overlap_mean": np.asarray(overlap, dtype=float),
         "overlap_max": np.asarray(overlap, dtype=float) * 2,
         "collision_frequency": np.asarray(contacts, dtype=float) * 10.0,
         "wall_contacts": np.zeros(n) if wall is None else np.asarray(wall, dtype=float),
         "wall_overlap_mean": np.zeros(n), "wall_collision_frequency": np.zeros(n)}
    c = np.asarray(coordination, dtype=float)
    for k in range(13):
        d[f"coordination_{k}"] = c[:, k]
    return d


class CensusErrors(unittest.TestCase):
    def test_window_reduction(self):
        """Frequency: the rows' mean; overlap: weighted by the contacts; max: the largest;
        coordination: summed counts, normalised. The row at t = 0 is left out."""
        coord = np.zeros((3, 13))
        coord[:, 0] = [10, 8, 6]
        coord[1, 1], coord[2, 1], coord[2, 12] = 2, 3, 1
        d = census([0.0, 1.0, 2.0], [99, 1, 3], [9.0, 0.1, 0.2], coord)
        v = census_errors.window_values(d, (0.0, 2.0))
        self.assertAlmostEqual(v["collision_frequency"], 20.0)
        self.assertAlmostEqual(v["overlap_mean"], (0.1 * 1 + 0.2 * 3) / 4)
        self.assertAlmostEqual(v["overlap_max"], 0.4)
        expect = np.zeros(13)
        expect[0], expect[1], expect[12] = 14 / 20, 5 / 20, 1 / 20
        self.assertTrue(np.allclose(v["coordination"], expect))
        self.assertIsNone(census_errors.window_values(d, (2.0, 3.0)))

    def test_errors_and_l1(self):
        coord = np.zeros((2, 13))
        coord[:, 0] = 10
        ref = census([0.0, 1.0], [0, 2], [0.0, 0.1], coord)
        coord2 = coord.copy()
        coord2[1, 0], coord2[1, 2] = 5, 5  # half the particles moved from bin 0 to bin 2
        d = census([0.0, 1.0], [0, 3], [0.0, 0.11], coord2)
        names = census_errors.quantities(ref)
        self.assertNotIn("wall_overlap_mean", names)  # no walls in the reference
        e = census_errors.errors(d, ref, (0.0, 1.0), names)
        self.assertAlmostEqual(e["collision_frequency"], 0.5)
        self.assertAlmostEqual(e["overlap_mean"], 0.1)
        self.assertAlmostEqual(e["coordination"], 1.0)  # |0.5 - 1| + |0.5 - 0|
        self.assertEqual(census_errors.errors(ref, ref, (0.0, 1.0), names),
                         {n: 0.0 for n in names})
        self.assertEqual(census_errors.l1([1, 0], [0, 1]), 2.0)
        # Sampling: the standard errors of the two runs' window means, combined, over the
        # reference's value; undefined for one row and for the largest overlap.
        self.assertTrue(np.isnan(census_errors.sampling(d, ref, (0.0, 1.0), "collision_frequency")))
        self.assertTrue(np.isnan(census_errors.sampling(d, ref, (0.0, 1.0), "overlap_max")))
        c4 = np.zeros((5, 13))
        a = census([0, 1, 2, 3, 4], [0, 1, 3, 1, 3], [0, 0.1, 0.2, 0.1, 0.2], c4)
        b = census([0, 1, 2, 3, 4], [0, 2, 2, 2, 2], [0, 0.1, 0.1, 0.1, 0.1], c4)
        f = np.array([10.0, 30, 10, 30])  # a's collision frequency rows (contacts x 10)
        se_a = np.std(f, ddof=1) / 2  # b's rows are all 20: no spread
        self.assertAlmostEqual(census_errors.sampling(a, b, (0.0, 4.0), "collision_frequency"),
                               se_a / 20.0)
        # Ratio estimator of a's overlap mean (b's overlaps do not vary): X = 1.4 / 8.
        x = 1.4 / 8
        se = np.sqrt(2 * (0.1 - x) ** 2 + 2 * (3 * (0.2 - x)) ** 2) / 8
        self.assertAlmostEqual(census_errors.sampling(a, b, (0.0, 4.0), "overlap_mean"), se / 0.1)
        self.assertIn("sampling noise", census_errors.verdict(0.5, 0.1, 0.3))
        self.assertIn("above the floor", census_errors.verdict(0.7, 0.1, 0.3))
        self.assertEqual(census_errors.verdict(0.05, 0.1, 0.3), "indistinguishable from chaos")
        walls = census([0.0, 1.0], [0, 2], [0.0, 0.1], coord, wall=[0, 1])
        self.assertIn("wall_collision_frequency", census_errors.quantities(walls))


class SceneCopy(unittest.TestCase):
    def test_generator_keys_replaced_and_the_rest_exact(self):
        with tempfile.TemporaryDirectory() as tmp:
            src = os.path.join(ROOT, "scenes", "hcs_small.toml")
            out = os.path.join(tmp, "s.toml")
            noise_floor.write_scene_with_file(src, os.path.join(tmp, "p.csv"), out)
            with open(src, "rb") as f:
                a = tomllib.load(f)
            with open(out, "rb") as f:
                b = tomllib.load(f)
            self.assertEqual(b["particles"], {"file": os.path.join(tmp, "p.csv")})
            del a["particles"], b["particles"]
            self.assertEqual(a, b)  # every other key with its exact value

    def test_csv_round_trip_is_exact(self):
        s = state(20, np.random.default_rng(4))
        with tempfile.TemporaryDirectory() as tmp:
            p = os.path.join(tmp, "p.csv")
            noise_floor.write_particle_csv(s, p)
            r = noise_floor.read_particle_csv(p)
        for c in s:
            self.assertTrue(np.array_equal(r[c], s[c]), c)


@unittest.skipUnless(CFDDEM, "set CFDDEM to the cfddem binary")
class WithBinary(unittest.TestCase):
    def test_initial_state_file_reproduces_the_generated_run_bitwise(self):
        """The floor's unperturbed copy of a generated scene is the reference itself: the CSV
        carries the generator's state exactly, so an explicit run from it matches bit for bit."""
        scene = os.path.join(ROOT, "scenes", "hcs_small.toml")
        with tempfile.TemporaryDirectory() as tmp:
            s = noise_floor.initial_state(CFDDEM, scene, [], tmp)
            p = os.path.join(tmp, "p.csv")
            noise_floor.write_particle_csv(s, p)
            copy = os.path.join(tmp, "copy.toml")
            noise_floor.write_scene_with_file(scene, p, copy)
            rows = {}
            for name, sc in (("gen", scene), ("file", copy)):
                out = os.path.join(tmp, name)
                subprocess.run([CFDDEM, "run", sc, "run.end_time=0.002", "--threads", "1",
                                "--quiet", "--out", out], check=True, capture_output=True)
                with open(os.path.join(out, "diagnostics.csv")) as f:
                    rows[name] = [r[:5] for r in csv.reader(f)]
            self.assertEqual(rows["gen"], rows["file"])
            self.assertGreater(len(rows["gen"]), 10)

    def test_trade_floor_table(self):
        """trade.py --noise-floor: the floor grows with time (chaos amplifies the perturbation)
        and stays tiny at first; every scheme row carries a verdict against it."""
        scene = os.path.join(ROOT, "scenes", "hcs_small.toml")
        with tempfile.TemporaryDirectory() as tmp:
            out = os.path.join(tmp, "trade")
            subprocess.run([sys.executable, os.path.join(HERE, "trade.py"), scene, "--schemes",
                            "islands", "--nsubit", "10", "--noise-floor", "3", "--windows", "2",
                            "--end-time", "0.004", "--binary", CFDDEM, "--out", out],
                           check=True, capture_output=True)
            with open(os.path.join(out, "trade_floor.csv")) as f:
                rows = list(csv.DictReader(f))
            with open(os.path.join(out, "trade_census.csv")) as f:
                census_table = list(csv.DictReader(f))
            with open(os.path.join(out, "trade.csv")) as f:
                trade_rows = list(csv.DictReader(f))
        floor = [float(r["floor"]) for r in rows if r["scheme"] == "floor"]
        self.assertEqual(len(floor), 2)
        self.assertGreater(floor[0], 0.0)
        self.assertLess(floor[0], 1e-8)  # a 1e-12 start has not grown to anything visible
        self.assertGreaterEqual(floor[1], floor[0])
        verdicts = [r["verdict"] for r in rows if r["scheme"] == "islands"]
        self.assertEqual(len(verdicts), 2)
        for v in verdicts:
            self.assertTrue(v == "indistinguishable from chaos" or "above the floor" in v, v)
        # The census: every quantity in both windows and over the run, for the floor and the
        # scheme, with a verdict against the floor.
        census_rows = [r for r in census_table if r["scheme"] == "islands"]
        self.assertEqual({r["quantity"] for r in census_rows},
                         {"collision_frequency", "overlap_mean", "overlap_max", "coordination"})
        self.assertEqual(len(census_rows), 4 * 3)
        self.assertEqual(len([r for r in census_table if r["scheme"] == "floor"]), 4 * 3)
        for r in census_rows:
            self.assertTrue(r["verdict"] == "indistinguishable from chaos"
                            or "above the floor" in r["verdict"]
                            or "sampling noise" in r["verdict"], r)
        # 100 particles at 1% solids collide: the reference saw contacts.
        self.assertGreater(max(float(r["ref_value"]) for r in census_rows
                               if r["quantity"] == "collision_frequency"), 0.0)
        self.assertIn("coordination_l1", trade_rows[0])


if __name__ == "__main__":
    unittest.main()

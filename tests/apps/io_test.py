#!/usr/bin/env python3
"""Snapshots and checkpoints opened the way a user would: h5py reads the files back, the XDMF
index parses as XML and every dataset it references exists with the shape it declares (particles,
and with a gas the cell data on the fluid grid); a run restarted from a checkpoint continues bit
for bit, with or without a gas; a truncated or corrupt checkpoint, or one of a scene with(out) a
gas given to a scene without (with) one, is refused with exit code 2 and the run directory is
left alone.

Usage: io_test.py CFDDEM_BINARY SOURCE_DIR [unittest args, e.g. -k Restart]
"""
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
import unittest
import xml.etree.ElementTree as ET

import h5py
import numpy as np

BIN = sys.argv[1]
SRC = sys.argv[2]
HCS = os.path.join(SRC, "scenes", "hcs.toml")
BOX = os.path.join(SRC, "scenes", "box_gravity.toml")
# Coupled scenes made small: the HCS in gas on a coarse grid with a different cell count per axis
# (so an axis-order mistake shows), and settling (walls, gravity, a closed box) with 30 particles.
GAS_CELLS = (8, 5, 4)
HCS_GAS = [os.path.join(SRC, "scenes", "hcs_gas.toml"), "fluid.cells=[8,5,4]"]
SETTLING = [os.path.join(SRC, "scenes", "settling.toml"), "particles.count=30"]


def cfddem(*args):
    r = subprocess.run([BIN, "run", *args, "--quiet"], capture_output=True, text=True)
    return r.returncode, r.stdout + r.stderr


def diagnostics(run_dir):
    """Rows of diagnostics.csv as text, without wall_seconds (the only column allowed to differ)."""
    with open(os.path.join(run_dir, "diagnostics.csv")) as f:
        rows = list(csv.reader(f))
    w = rows[0].index("wall_seconds")
    return [[x for i, x in enumerate(r) if i != w] for r in rows]


class Tmp(unittest.TestCase):
    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="cfddem_io_")

    def tearDown(self):
        shutil.rmtree(self.tmp, ignore_errors=True)

    def run_ok(self, *args):
        code, out = cfddem(*args)
        self.assertEqual(code, 0, out)
        return out


class Snapshots(Tmp):
    def test_xdmf_references_existing_datasets_with_declared_shapes(self):
        out = os.path.join(self.tmp, "snap")
        self.run_ok(HCS, "run.end_time=0.002", "output.interval=0.0005",
                    "output.snapshot_interval=0.0005", "--out", out)
        root = ET.parse(os.path.join(out, "snapshots.xmf")).getroot()
        self.assertEqual(root.tag, "Xdmf")
        coll = root.find("Domain/Grid")
        self.assertEqual(coll.get("GridType"), "Collection")
        self.assertEqual(coll.get("CollectionType"), "Temporal")
        grids = coll.findall("Grid")
        self.assertEqual(len(grids), 5)  # t = 0, 0.5, 1, 1.5, 2 ms
        times = [float(g.find("Time").get("Value")) for g in grids]
        self.assertEqual(times, sorted(times))
        self.assertAlmostEqual(times[-1], 0.002, delta=1e-6)
        checked = 0
        for g in grids:
            topo = g.find("Topology")
            self.assertEqual(topo.get("TopologyType"), "Polyvertex")
            n = int(topo.get("NumberOfElements"))
            self.assertEqual(n, 1222)
            self.assertEqual(g.find("Geometry").get("GeometryType"), "XYZ")
            for a in g.findall("Attribute"):
                self.assertEqual(a.get("Center"), "Node")
            for item in g.iter("DataItem"):
                self.assertEqual(item.get("Format"), "HDF")
                fname, dset = item.text.strip().split(":")
                dims = tuple(int(d) for d in item.get("Dimensions").split())
                with h5py.File(os.path.join(out, fname), "r") as f:
                    self.assertIn(dset, f, f"{fname}:{dset}")
                    self.assertEqual(f[dset].shape, dims, f"{fname}:{dset}")
                    self.assertEqual(f[dset].dtype.itemsize, int(item.get("Precision")))
                checked += 1
        self.assertEqual(checked, 5 * 7)  # position + 6 attributes
        # Values: a snapshot is the state the diagnostics row of the same time measured.
        with h5py.File(os.path.join(out, "snapshot_000006910.h5"), "r") as f:
            p = f["particles"]
            v = p["velocity"][()]
            np.testing.assert_allclose(p["diameter"][()], 1e-4, rtol=1e-12)
            np.testing.assert_array_equal(np.sort(p["id"][()]), np.arange(1222))
            np.testing.assert_allclose(p["speed"][()], np.linalg.norm(v, axis=1), rtol=1e-14)
            self.assertTrue(np.all((p["position"][()] >= 0) & (p["position"][()] <= 4e-3)))
            t_snap = f.attrs["time"]
            mean_speed = p["speed"][()].mean()
        row = [r for r in diagnostics(out)[1:] if int(float(r[1])) == 6910][0]
        self.assertAlmostEqual(float(row[0]), t_snap, delta=1e-15)
        self.assertAlmostEqual(float(row[4]), mean_speed, delta=1e-12 * mean_speed)
        self.assertFalse([x for x in os.listdir(out) if ".tmp." in x], "temporary files left")
        # The tools a user runs on these files produce PNGs.
        tools = os.path.join(SRC, "tools")
        for cmd in (["render_snapshot.py", os.path.join(out, "snapshot_000006910.h5"), "-o",
                     os.path.join(out, "s.png"), "--color", "kinetic_energy"],
                    ["plot_diagnostics.py", os.path.join(out, "diagnostics.csv"), "-o",
                     os.path.join(out, "d.png")]):
            r = subprocess.run([sys.executable, os.path.join(tools, cmd[0]), *cmd[1:]],
                               capture_output=True, text=True)
            self.assertEqual(r.returncode, 0, r.stderr)
        for png in ("s.png", "d.png"):
            with open(os.path.join(out, png), "rb") as f:
                self.assertEqual(f.read(8), b"\x89PNG\r\n\x1a\n")

    def test_orb_snapshots_carry_leaf_and_local_dt(self):
        out = os.path.join(self.tmp, "orb")
        self.run_ok(HCS, "dem.scheme=orb", "run.end_time=0.002", "output.interval=0.001",
                    "output.snapshot_interval=0.001", "--out", out)
        root = ET.parse(os.path.join(out, "snapshots.xmf")).getroot()
        grids = root.findall("Domain/Grid/Grid")
        self.assertEqual(len(grids), 3)
        for g in grids[1:]:
            names = [a.get("Name") for a in g.findall("Attribute")]
            self.assertIn("leaf", names)
            for item in g.iter("DataItem"):
                fname, dset = item.text.strip().split(":")
                with h5py.File(os.path.join(out, fname), "r") as f:
                    self.assertEqual(f[dset].shape,
                                     tuple(int(d) for d in item.get("Dimensions").split()))
        with h5py.File(os.path.join(out, "snapshot_000000100.h5"), "r") as f:
            p = f["particles"]
            leaf = p["leaf"][()]
            self.assertTrue(np.all((leaf >= 0) & (leaf < 16)))
            self.assertEqual(len(np.unique(p["id"][()])), 1222)
            self.assertTrue(np.all(p["local_dt"][()] > 0))
            mean_speed = p["speed"][()].mean()
        row = [r for r in diagnostics(out)[1:] if int(float(r[1])) == 100][0]
        self.assertAlmostEqual(float(row[4]), mean_speed, delta=1e-12 * mean_speed)

    def test_coupled_snapshot_holds_cells_on_the_fluid_grid(self):
        out = os.path.join(self.tmp, "gas")
        self.run_ok(*HCS_GAS, "run.end_time=0.001", "output.interval=0.0005",
                    "output.snapshot_interval=0.0005", "--out", out)
        nx, ny, nz = GAS_CELLS
        root = ET.parse(os.path.join(out, "snapshots.xmf")).getroot()
        colls = root.findall("Domain/Grid")
        self.assertEqual([c.get("Name") for c in colls], ["particles", "fluid"])
        for c in colls:
            self.assertEqual(c.get("CollectionType"), "Temporal")
        particles, fluid = (c.findall("Grid") for c in colls)
        self.assertEqual(len(fluid), 3)  # t = 0, 0.5, 1 ms
        self.assertEqual([g.find("Time").get("Value") for g in fluid],
                         [g.find("Time").get("Value") for g in particles])
        for g in fluid:
            topo = g.find("Topology")
            self.assertEqual(topo.get("TopologyType"), "3DRectMesh")
            # XDMF gives node dimensions slowest axis first: z y x.
            self.assertEqual([int(d) for d in topo.get("Dimensions").split()],
                             [nz + 1, ny + 1, nx + 1])
            geo = g.find("Geometry")
            self.assertEqual(geo.get("GeometryType"), "VXVYVZ")
            names = [a.get("Name") for a in g.findall("Attribute")]
            self.assertEqual(names, ["eps_g", "pressure", "gas_velocity"])
            for a in g.findall("Attribute"):
                self.assertEqual(a.get("Center"), "Cell")
            for item in g.iter("DataItem"):
                fname, dset = item.text.strip().split(":")
                dims = tuple(int(d) for d in item.get("Dimensions").split())
                with h5py.File(os.path.join(out, fname), "r") as f:
                    self.assertIn(dset, f, f"{fname}:{dset}")
                    self.assertEqual(f[dset].shape, dims, f"{fname}:{dset}")
            node_dims = [int(i.get("Dimensions")) for i in geo.findall("DataItem")]
            self.assertEqual(node_dims, [nx + 1, ny + 1, nz + 1])
        with h5py.File(os.path.join(out, "snapshot_000006910.h5"), "r") as f:
            fl = f["fluid"]
            self.assertEqual(fl["eps_g"].shape, (nz, ny, nx))
            self.assertEqual(fl["pressure"].shape, (nz, ny, nx))
            self.assertEqual(fl["gas_velocity"].shape, (nz, ny, nx, 3))
            eps = fl["eps_g"][()]
            self.assertTrue(np.all((eps > 0) & (eps <= 1)), (eps.min(), eps.max()))
            self.assertLess(eps.min(), 1.0)  # the particles are deposited
            for a, n in zip("xyz", GAS_CELLS):
                np.testing.assert_allclose(fl[f"{a}_nodes"][()], np.linspace(0, 4e-3, n + 1),
                                           rtol=0, atol=1e-15)
            self.assertTrue(np.all(np.isfinite(fl["pressure"][()])))
            # The cells are the gas at the snapshot's time: their momentum is the diagnostics
            # row's (rho_g = 1 kg/m^3).
            u = fl["gas_velocity"][()]
            momentum = (eps[..., None] * u).sum(axis=(0, 1, 2)) * (4e-3 ** 3 / (nx * ny * nz))
            t = f.attrs["time"]
        header, *rows = diagnostics(out)
        row = [r for r in rows if abs(float(r[0]) - t) < 1e-12][0]
        for a, m in zip("xyz", momentum):
            expected = float(row[header.index(f"gas_momentum_{a}")])
            self.assertAlmostEqual(m, expected, delta=1e-12 * np.abs(momentum).max())
        self.assertNotEqual(momentum[0], 0.0)
        # The render tool draws the cells under the particles.
        png = os.path.join(out, "cells.png")
        r = subprocess.run([sys.executable, os.path.join(SRC, "tools", "render_snapshot.py"),
                            os.path.join(out, "snapshot_000006910.h5"), "--view", "xz",
                            "--cells", "eps_g", "-o", png], capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        with open(png, "rb") as f:
            self.assertEqual(f.read(8), b"\x89PNG\r\n\x1a\n")

    def test_zero_particles_gives_empty_snapshot(self):
        out = os.path.join(self.tmp, "empty")
        self.run_ok(HCS, "particles.file=", "particles.count=0", "particles.diameter=1e-4",
                    "particles.density=1000", "run.end_time=1e-4",
                    "output.snapshot_interval=5e-5", "dem.dt=1e-6", "--out", out)
        root = ET.parse(os.path.join(out, "snapshots.xmf")).getroot()
        for item in root.iter("DataItem"):
            fname, dset = item.text.strip().split(":")
            with h5py.File(os.path.join(out, fname), "r") as f:
                self.assertEqual(f[dset].shape[0], 0)


PV_SCRIPT = """
import sys
from paraview.simple import XDMFReader, servermanager
r = XDMFReader(FileNames=[sys.argv[1]])
times = list(r.TimestepValues)
r.UpdatePipeline(times[-1])
d = servermanager.Fetch(r)
b = d.GetBlock(0) if d.IsA("vtkMultiBlockDataSet") else d
pd = b.GetPointData()
names = sorted(pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays()))
print("RESULT", len(times), b.GetNumberOfPoints(), b.GetNumberOfCells(), ",".join(names))
"""


class PvTmp(Tmp):
    """Tests that run a ParaView script with pvbatch (skipped where ParaView is not installed)."""

    def setUp(self):
        self.pvbatch = shutil.which("pvbatch")
        if not self.pvbatch:
            self.skipTest("pvbatch not installed (apt-get install paraview)")
        super().setUp()

    def pv_lines(self, script_text, xmf):
        """Run script_text on xmf; its stdout lines as {first word: the fields after it}."""
        script = os.path.join(self.tmp, "load.py")
        with open(script, "w") as f:
            f.write(script_text)
        r = subprocess.run([self.pvbatch, script, xmf], capture_output=True, text=True,
                           timeout=240)
        lines = {x.split()[0]: x.split()[1:] for x in r.stdout.splitlines() if x.split()}
        self.assertIn("RESULT", lines, r.stdout + r.stderr)
        return lines


class ParaView(PvTmp):
    """The reader users pick (Debian's ParaView 5.11 XDMFReader) loads the index as a series."""

    def test_xdmf_reader_loads_time_series(self):
        out = os.path.join(self.tmp, "pv")
        self.run_ok(HCS, "run.end_time=0.002", "output.snapshot_interval=0.001", "--out", out)
        steps, points, cells, names = self.pv_lines(
            PV_SCRIPT, os.path.join(out, "snapshots.xmf"))["RESULT"]
        self.assertEqual(int(steps), 3)
        self.assertEqual(int(points), 1222)
        self.assertEqual(int(cells), 1222)  # Polyvertex: one vertex cell per particle
        for a in ("velocity", "speed", "kinetic_energy", "diameter", "id", "local_dt"):
            self.assertIn(a, names.split(","))


PV_FLUID_SCRIPT = """
import sys
from paraview.simple import XDMFReader, servermanager
r = XDMFReader(FileNames=[sys.argv[1]])
times = list(r.TimestepValues)
r.UpdatePipeline(times[-1])
d = servermanager.Fetch(r)
names = [d.GetMetaData(i).Get(d.NAME()) for i in range(d.GetNumberOfBlocks())]
b = d.GetBlock(names.index("fluid"))
cd = b.GetCellData()
arrays = sorted(cd.GetArrayName(i) for i in range(cd.GetNumberOfArrays()))
eps = cd.GetArray("eps_g")
print("RESULT", len(times), ",".join(names), b.GetClassName(), b.GetNumberOfCells(),
      " ".join(str(x) for x in b.GetDimensions()), ",".join(arrays),
      " ".join(repr(x) for x in b.GetBounds()))
print("EPS", " ".join(repr(eps.GetValue(i)) for i in range(eps.GetNumberOfTuples())))
"""


class ParaViewFluid(PvTmp):
    """ParaView's XDMFReader loads a coupled run's cells as a rectilinear grid next to the
    particles, with the cell values in the order h5py reads them (x fastest)."""

    def test_xdmf_reader_loads_fluid_grid(self):
        out = os.path.join(self.tmp, "pvgas")
        self.run_ok(*HCS_GAS, "run.end_time=0.001", "output.snapshot_interval=0.0005", "--out",
                    out)
        lines = self.pv_lines(PV_FLUID_SCRIPT, os.path.join(out, "snapshots.xmf"))
        f = ["RESULT", *lines["RESULT"]]
        nx, ny, nz = GAS_CELLS
        self.assertEqual(int(f[1]), 3)
        self.assertEqual(f[2], "particles,fluid")
        self.assertEqual(f[3], "vtkRectilinearGrid")
        self.assertEqual(int(f[4]), nx * ny * nz)
        self.assertEqual([int(x) for x in f[5:8]], [nx + 1, ny + 1, nz + 1])
        self.assertEqual(f[8], "eps_g,gas_velocity,pressure")
        np.testing.assert_allclose([float(x) for x in f[9:15]], [0, 4e-3] * 3, atol=1e-15)
        eps_pv = [float(x) for x in lines["EPS"]]
        with h5py.File(os.path.join(out, "snapshot_000006910.h5"), "r") as h:
            np.testing.assert_array_equal(eps_pv, h["fluid/eps_g"][()].ravel())


class Restart(Tmp):
    def check_restart(self, scene, total, half, extra):
        scene = scene if isinstance(scene, list) else [scene]
        full = os.path.join(self.tmp, "full")
        first = os.path.join(self.tmp, "first")
        second = os.path.join(self.tmp, "second")
        common = [f"output.snapshot_interval={half}", *extra]
        self.run_ok(*scene, f"run.end_time={total}", *common, "--out", full)
        # N steps with a checkpoint at the end (written before the step that records row N) ...
        self.run_ok(*scene, f"run.end_time={half}", f"output.checkpoint_interval={half}", *common,
                    "--out", first)
        ckpts = sorted(x for x in os.listdir(first) if x.startswith("checkpoint_"))
        self.assertEqual(len(ckpts), 1, ckpts)
        # ... then restart and run the other N steps.
        self.run_ok(*scene, f"run.end_time={total}", *common, "--out", second, "--restart",
                    os.path.join(first, ckpts[0]))
        a, b = diagnostics(full), diagnostics(second)
        self.assertEqual(len(a), len(b))
        for ra, rb in zip(a, b):
            self.assertEqual(ra, rb)
        last = sorted(x for x in os.listdir(full) if x.startswith("snapshot_"))[-1]
        with h5py.File(os.path.join(full, last)) as fa, h5py.File(os.path.join(second, last)) as fb:
            self.assertEqual(sorted(fa), sorted(fb))
            for g in fa:  # particles, and the cells with a gas
                for k in fa[g]:
                    np.testing.assert_array_equal(fa[g][k][()], fb[g][k][()], f"{g}/{k}")
        # Restarting at the checkpoint's own end time repeats the first run's last row: the one
        # particle step past the end reads what the checkpoint holds (with a gas, the held force).
        at_end = os.path.join(self.tmp, "at_end")
        self.run_ok(*scene, f"run.end_time={half}", *common, "--out", at_end, "--restart",
                    os.path.join(first, ckpts[0]))
        self.assertEqual(diagnostics(at_end), diagnostics(first))
        # The restarted run's XDMF index lists only snapshots present in its own directory.
        root = ET.parse(os.path.join(second, "snapshots.xmf")).getroot()
        for item in root.iter("DataItem"):
            self.assertTrue(os.path.exists(os.path.join(second, item.text.split(":")[0])))
        return a

    def test_explicit_hcs_bitwise(self):
        rows = self.check_restart(HCS, 0.004, 0.002, ["output.interval=0.0005"])
        self.assertEqual(len(rows), 1 + 9)

    def test_explicit_frictional_walls_bitwise(self):
        # Friction (tangential history), walls and gravity, with contacts alive at the restart.
        self.check_restart(BOX, 0.016, 0.008, ["output.interval=0.001"])

    def test_orb_frictional_walls_bitwise(self):
        # The orb scheme's tangential history, by particle ids, in the checkpoint (/orb/history_*).
        self.check_restart(BOX, 0.016, 0.008, ["dem.scheme=orb", "output.interval=0.001"])

    def test_islands_frictional_walls_bitwise(self):
        # The islands scheme's tangential history per list entry (/islands/history_*).
        self.check_restart(BOX, 0.016, 0.008, ["dem.scheme=islands", "output.interval=0.001"])

    def test_orb_hcs_bitwise(self):
        # Checkpoints fall on regrid points (every dem.nsubit sub-iterations).
        self.check_restart(HCS, 0.004, 0.002, ["dem.scheme=orb", "output.interval=0.0005"])

    def test_orb_global_mode_switching_bitwise(self):
        # The global mode (every particle on the fine steps where nearly every leaf would be
        # fine) and the leaf steps taking turns: proximity_radii 2.5 at 64 leaves puts the
        # particles in fine leaves on both sides of 3/4.
        self.check_restart(HCS, 0.004, 0.002, ["dem.scheme=orb", "dem.nsubit=15",
                                               "partition.orb_levels=6",
                                               "dem.proximity_radii=2.5",
                                               "output.interval=0.0005"])
        with open(os.path.join(self.tmp, "full", "run.json")) as f:
            info = json.load(f)
        self.assertGreater(info["global_subiterations"], 0)
        self.assertLess(info["global_subiterations"], info["steps"] - 1)
        with open(os.path.join(self.tmp, "second", "run.json")) as f:
            self.assertEqual(json.load(f)["global_subiterations"], info["global_subiterations"])

    def test_orb_held_global_mode_bitwise(self):
        # proximity_radii 2.8 at 64 leaves: the global mode holds over most regrid points, which
        # then decide on the leaves as they are and cut no new ORB, and leaves them at some; the
        # checkpoint falls in a held interval, so it carries the ORB the next point decides on.
        extra = ["dem.scheme=orb", "dem.nsubit=15", "partition.orb_levels=6",
                 "dem.proximity_radii=2.8", "output.interval=0.0005"]
        self.check_restart(HCS, 0.004, 0.002, extra)
        first = os.path.join(self.tmp, "first")
        ckpt = sorted(x for x in os.listdir(first) if x.startswith("checkpoint_"))[0]
        with h5py.File(os.path.join(first, ckpt), "r") as f:
            self.assertIn("held_cut_axis", f["orb"])
        with open(os.path.join(self.tmp, "full", "run.json")) as f:
            info = json.load(f)
        points = round(0.004 / 1e-4) + 1  # regrid points: every dem.nsubit sub-iterations
        self.assertGreater(info["regrids"], 1)
        self.assertLess(info["regrids"], points)
        self.assertGreater(info["global_subiterations"], 0)
        self.assertLess(info["global_subiterations"], info["steps"] - 1)

    def test_islands_hcs_bitwise(self):
        # The list as built, half steps, counters and histograms; the checkpoint falls between
        # two sub-iterations that are not a multiple of dem.nsubit (islands have no regrid).
        rows = self.check_restart(HCS, 0.0041, 0.00205, ["dem.scheme=islands", "dem.nsubit=10",
                                                         "output.interval=0.0005"])
        self.assertGreater(float(rows[-1][rows[0].index("fine_leaf_fraction")]), 0.0)

    def test_islands_auto_hcs_bitwise(self):
        # dem.nsubit = "auto": the chosen length, its running means and its log are state; the
        # loop steps control intervals (dem.regrid_interval). A rerun on one thread is the same
        # run to the bit, and run.json logs the choices.
        # A 3% gas (hcs_small with 300 particles): its count changes twice in 4 ms, so the
        # restart carries a length that is not the first interval's. (On HCS 1222 "auto" keeps
        # its first count since the islands fold their steps before the entry time.)
        gas = [os.path.join(SRC, "scenes", "hcs_small.toml"), "particles.count=300"]
        rows = self.check_restart(gas, 0.004, 0.002, ["dem.scheme=islands", "dem.nsubit=auto",
                                                      "output.interval=0.0005"])
        self.assertEqual(len(rows), 1 + 9)
        one = os.path.join(self.tmp, "one_thread")
        self.run_ok(*gas, "run.end_time=0.004", "output.snapshot_interval=0.002",
                    "dem.scheme=islands", "dem.nsubit=auto", "output.interval=0.0005",
                    "--threads", "1", "--out", one)
        self.assertEqual(diagnostics(one), rows)
        with open(os.path.join(one, "run.json")) as f:
            run = json.load(f)
        self.assertEqual(run["nsubit"], "auto")
        self.assertEqual(run["bound_violations"], 0)
        choices = run["nsubit_choices"]
        self.assertGreaterEqual(len(choices), 2)
        self.assertEqual(sum(c["intervals"] for c in choices), 40)
        self.assertTrue(all(c["nsubit_min"] <= c["nsubit"] <= c["nsubit_max"] for c in choices))

    def test_coupled_islands_auto_settling_bitwise(self):
        # With a gas the interval is fluid.dt; the held force's change bounds the length.
        self.check_restart(SETTLING, 0.002, 0.001, ["dem.scheme=islands", "dem.nsubit=auto",
                                                    "output.interval=0.0005"])

    # Coupled scenes: N fluid steps + checkpoint + restart + N fluid steps = 2N fluid steps, to
    # the bit (gas velocities, pressure, eps_g history, loop position, pending row/snapshot).
    def test_coupled_explicit_hcs_gas_bitwise(self):
        rows = self.check_restart(HCS_GAS, 0.002, 0.001, ["output.interval=0.0005"])
        self.assertEqual(len(rows), 1 + 5)
        self.assertNotEqual(rows[-1][rows[0].index("gas_momentum_x")], "0")

    def test_coupled_orb_hcs_gas_bitwise(self):
        self.check_restart(HCS_GAS, 0.002, 0.001, ["dem.scheme=orb", "output.interval=0.0005"])

    def test_coupled_explicit_settling_bitwise(self):
        # Walls, gravity, the closed box's SMG-preconditioned projection.
        self.check_restart(SETTLING, 0.002, 0.001, ["output.interval=0.0005"])

    def test_coupled_orb_settling_bitwise(self):
        self.check_restart(SETTLING, 0.002, 0.001, ["dem.scheme=orb", "output.interval=0.0005"])

    def test_coupled_islands_hcs_gas_bitwise(self):
        self.check_restart(HCS_GAS, 0.002, 0.001, ["dem.scheme=islands", "dem.nsubit=10",
                                                   "output.interval=0.0005"])

    def test_coupled_islands_settling_bitwise(self):
        # Walls (tied particles) and gravity with the held gas force in the speed bounds.
        self.check_restart(SETTLING, 0.002, 0.001, ["dem.scheme=islands", "dem.nsubit=10",
                                                    "output.interval=0.0005"])

    def check_adaptive_restart(self, scene, extra):
        # fluid.dt = 0: each fluid step comes from the gas's CFL number (capped by fluid.max_dt)
        # and need not land on the checkpoint time, so the checkpoint comes from inside the full
        # run (the first fluid-step boundary at or after 1 ms) and the restart repeats its end.
        full = os.path.join(self.tmp, "full")
        second = os.path.join(self.tmp, "second")
        common = [*scene, "fluid.dt=0", "fluid.max_dt=2e-4", "run.end_time=0.002",
                  "output.interval=0.0005", *extra]
        self.run_ok(*common, "output.checkpoint_interval=0.001", "--out", full)
        ckpts = sorted(x for x in os.listdir(full) if x.startswith("checkpoint_"))
        self.assertEqual(len(ckpts), 2, ckpts)  # at ~1 ms and at the end
        self.run_ok(*common, "--out", second, "--restart", os.path.join(full, ckpts[0]))
        self.assertEqual(diagnostics(full), diagnostics(second))
        with open(os.path.join(full, "run.json")) as f:
            j = json.load(f)
        self.assertGreater(j["fluid_steps"], 10)
        return j

    def test_coupled_adaptive_fluid_step_bitwise(self):
        self.check_adaptive_restart(HCS_GAS, [])

    # orb and islands divide whatever step the gas takes into their sub-iterations: the time base
    # of the sub-iterations (and "auto"'s reference interval) is in the checkpoint. A low
    # fluid.cfl makes the gas's Courant step, not fluid.max_dt, set dt_f (it varies from step to
    # step: more than 10 steps in 2 ms).
    def test_coupled_adaptive_orb_bitwise(self):
        j = self.check_adaptive_restart(HCS_GAS, ["dem.scheme=orb", "dem.nsubit=12", "fluid.cfl=0.01"])
        # dem.nsubit sub-iterations per fluid step, of varying length (and the step past the end
        # that completes the last row).
        self.assertEqual(j["steps"], j["fluid_steps"] * 12 + 1)

    def test_coupled_adaptive_islands_bitwise(self):
        self.check_adaptive_restart(HCS_GAS, ["dem.scheme=islands", "dem.nsubit=10",
                                              "fluid.cfl=0.01"])

    def test_coupled_adaptive_islands_auto_bitwise(self):
        self.check_adaptive_restart(HCS_GAS, ["dem.scheme=islands", "dem.nsubit=auto",
                                              "fluid.cfl=0.01"])

    def test_scheme_mismatch_refused(self):
        first = os.path.join(self.tmp, "first")
        self.run_ok(HCS, "run.end_time=0.001", "output.checkpoint_interval=0.001", "--out", first)
        ck = [x for x in os.listdir(first) if x.startswith("checkpoint_")][0]
        code, msg = cfddem(HCS, "dem.scheme=orb", "run.end_time=0.002", "--out",
                           os.path.join(self.tmp, "never"), "--restart", os.path.join(first, ck))
        self.assertEqual(code, 2, msg)
        self.assertIn("scheme", msg)
        self.assertFalse(os.path.exists(os.path.join(self.tmp, "never")))


class BadCheckpoint(Tmp):
    def make_checkpoint(self):
        out = os.path.join(self.tmp, "src")
        self.run_ok(HCS, "run.end_time=0.001", "output.checkpoint_interval=0.0005", "--out", out)
        return os.path.join(out, "checkpoint_000003455.h5")

    def make_gas_checkpoint(self):
        out = os.path.join(self.tmp, "gas")
        self.run_ok(*HCS_GAS, "run.end_time=0.001", "output.checkpoint_interval=0.0005", "--out",
                    out)
        return os.path.join(out, "checkpoint_000000005.h5")

    def expect_refused(self, path, needle="checkpoint", extra=(), scene=(HCS,)):
        # An existing run directory with a result in it must be left exactly as it was.
        out = os.path.join(self.tmp, "existing")
        os.makedirs(out, exist_ok=True)
        with open(os.path.join(out, "diagnostics.csv"), "w") as f:
            f.write("precious\n")
        before = sorted(os.listdir(out))
        code, msg = cfddem(*scene, "run.end_time=0.001", *extra, "--out", out, "--restart", path)
        self.assertEqual(code, 2, msg)
        self.assertIn(needle, msg)
        self.assertIn(path, msg)  # the message names the file
        self.assertEqual(sorted(os.listdir(out)), before)
        with open(os.path.join(out, "diagnostics.csv")) as f:
            self.assertEqual(f.read(), "precious\n")
        fresh = os.path.join(self.tmp, "never")
        code, msg = cfddem(*scene, "run.end_time=0.001", *extra, "--out", fresh, "--restart", path)
        self.assertEqual(code, 2, msg)
        self.assertFalse(os.path.exists(fresh))

    def test_missing(self):
        self.expect_refused(os.path.join(self.tmp, "nope.h5"))

    def test_truncated(self):
        good = self.make_checkpoint()
        bad = os.path.join(self.tmp, "truncated.h5")
        with open(good, "rb") as f:
            data = f.read()
        for cut in (len(data) // 2, len(data) - 100, 1000):
            with open(bad, "wb") as f:
                f.write(data[:cut])
            self.expect_refused(bad)

    def flip_bit(self, good, dataset, byte, mask):
        """A copy of `good` with one bit of a dataset's stored bytes flipped."""
        with h5py.File(good, "r") as f:
            offset = f[dataset].id.get_offset() + byte
        bad = os.path.join(self.tmp, "flipped.h5")
        shutil.copy(good, bad)
        with open(bad, "r+b") as f:
            f.seek(offset)
            b = f.read(1)
            f.seek(offset)
            f.write(bytes([b[0] ^ mask]))
        return bad

    def test_flipped_bits_in_particle_data(self):
        bad = self.flip_bit(self.make_checkpoint(), "particles/vx_half", 8 * 100 + 3, 0x10)
        self.expect_refused(bad, needle="checksum")

    def test_other_format_version(self):
        # A checkpoint of a format this version does not read is refused by number: the
        # message names the version found and the one expected.
        bad = os.path.join(self.tmp, "format2.h5")
        shutil.copy(self.make_checkpoint(), bad)
        with h5py.File(bad, "r+") as f:
            f.attrs["format"] = np.int64(2)
        self.expect_refused(bad, needle="format version 2, this version reads format 1")

    def test_not_hdf5(self):
        bad = os.path.join(self.tmp, "text.h5")
        with open(bad, "w") as f:
            f.write("not a checkpoint\n")
        self.expect_refused(bad)

    def test_gas_checkpoint_to_scene_without_gas(self):
        self.expect_refused(self.make_gas_checkpoint(), needle="has no gas")

    def test_checkpoint_without_gas_to_scene_with_gas(self):
        self.expect_refused(self.make_checkpoint(), needle="holds no gas state", scene=HCS_GAS)

    def test_truncated_gas_checkpoint(self):
        good = self.make_gas_checkpoint()
        bad = os.path.join(self.tmp, "truncated_gas.h5")
        with open(good, "rb") as f:
            data = f.read()
        with h5py.File(good, "r") as f:  # cut inside the gas arrays
            cut = f["gas/p"].id.get_offset() + 100
        for n in (cut, len(data) // 2, len(data) - 100):
            with open(bad, "wb") as f:
                f.write(data[:n])
            self.expect_refused(bad, scene=HCS_GAS)

    def test_flipped_bits_in_gas_data(self):
        bad = self.flip_bit(self.make_gas_checkpoint(), "gas/u", 8 * 200 + 2, 0x01)
        self.expect_refused(bad, needle="checksum", scene=HCS_GAS)

    def test_other_configuration(self):
        good = self.make_checkpoint()
        self.expect_refused(good, needle="dem.restitution", extra=["dem.restitution=0.9"])

    def drop_configuration_line(self, path, key):
        # A checkpoint as a version before `key` wrote it: its configuration without that line.
        with h5py.File(path, "r+") as f:
            lines = f.attrs["configuration"].decode().split("\n")
            kept = [line for line in lines if not line.startswith(key)]
            self.assertEqual(len(kept), len(lines) - 1)
            f.attrs["configuration"] = np.bytes_("\n".join(kept))

    def test_gas_checkpoint_from_before_the_advection_key(self):
        # A gas checkpoint written before fluid.advection existed has no line for it and ran
        # the method of lines: it restarts with "mol", and the Godunov default is refused,
        # naming the key (apps/checkpoint.cpp, kImpliedLines).
        out = os.path.join(self.tmp, "old")
        self.run_ok(*HCS_GAS, "fluid.advection=mol", "run.end_time=0.001",
                    "output.checkpoint_interval=0.0005", "--out", out)
        path = os.path.join(out, "checkpoint_000000005.h5")
        self.drop_configuration_line(path, "fluid.advection")
        self.expect_refused(path, needle="fluid.advection", scene=HCS_GAS)
        code, msg = cfddem(*HCS_GAS, "fluid.advection=mol", "run.end_time=0.001", "--out",
                           os.path.join(self.tmp, "continued"), "--restart", path)
        self.assertEqual(code, 0, msg)


    def test_gas_checkpoint_from_before_the_viscous_step_key(self):
        # A gas checkpoint written before fluid.viscous_step existed has no line for it and
        # solved its implicit viscous systems: it restarts with "solve", and the factored
        # default is refused, naming the key; a checkpoint of the factored step is refused
        # with "solve" (apps/checkpoint.cpp, kImpliedLines).
        out = os.path.join(self.tmp, "old_viscous")
        self.run_ok(*HCS_GAS, "fluid.viscous_step=solve", "run.end_time=0.001",
                    "output.checkpoint_interval=0.0005", "--out", out)
        path = os.path.join(out, "checkpoint_000000005.h5")
        with h5py.File(path, "r") as f:
            self.assertIn('fluid.viscous_step = "solve"',
                          f.attrs["configuration"].decode().split("\n"))
        self.drop_configuration_line(path, "fluid.viscous_step")
        self.expect_refused(path, needle="fluid.viscous_step", scene=HCS_GAS)
        code, msg = cfddem(*HCS_GAS, "fluid.viscous_step=solve", "run.end_time=0.001", "--out",
                           os.path.join(self.tmp, "continued_viscous"), "--restart", path)
        self.assertEqual(code, 0, msg)
        new = os.path.join(self.tmp, "new_viscous")
        self.run_ok(*HCS_GAS, "run.end_time=0.001", "output.checkpoint_interval=0.0005",
                    "--out", new)
        self.expect_refused(os.path.join(new, "checkpoint_000000005.h5"),
                            needle='fluid.viscous_step = "solve" here, "factored" in the checkpoint',
                            scene=HCS_GAS, extra=["fluid.viscous_step=solve"])

if __name__ == "__main__":
    unittest.main(argv=[sys.argv[0], *sys.argv[3:]], verbosity=2)

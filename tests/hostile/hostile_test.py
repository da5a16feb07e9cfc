#!/usr/bin/env python3
"""Hostile input and faults, as a new user meets them (issue 17): every case runs the `cfddem`
program and asserts its exit code (0 success, 2 command-line or configuration error, 3 run-time
failure), a message naming the cause, and that a pre-existing run directory is left byte for byte
as it was. Standard library only; tiny scenes, short end times.

Usage: hostile_test.py CFDDEM_BINARY SOURCE_DIR [-k PATTERN] [--list]
A case that needs something this machine lacks (a tmpfs mount for a real full disk) says so and
falls back to an unprivileged equivalent (a file-size limit) rather than passing silently.
"""
import contextlib
import csv
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile

BIN = os.path.abspath(sys.argv[1])
SRC = os.path.abspath(sys.argv[2])
ARGS = sys.argv[3:]
SCENES = os.path.join(SRC, "scenes")
SMALL = os.path.join(SCENES, "hcs_small.toml")  # 100 particles, 1.737 mm periodic box
HCS = os.path.join(SCENES, "hcs.toml")
SETTLING = os.path.join(SCENES, "settling.toml")  # walls, gravity, a gas at rest
BED = os.path.join(SCENES, "fluidized_bed.toml")  # 10,000 particles, inflow, outflow
RISER = os.path.join(SCENES, "riser.toml")  # periodic, a pressure drop
HCS_GAS = os.path.join(SCENES, "hcs_gas.toml")  # periodic, gas at rest, T = 0.1 m^2/s^2
TINY = ["run.end_time=2e-5"]  # 138 steps of hcs_small
TIMEOUT = 60

with open(os.path.join(SRC, "CMakeLists.txt")) as f:
    VERSION = re.search(r"project\(cfddem VERSION ([0-9.]+)", f.read()).group(1)


def run(args, timeout=TIMEOUT, preexec=None, cwd=None, env=None):
    """(exit code, stdout + stderr); a hang is a failure of its own. env: variables added to
    this process's environment."""
    try:
        r = subprocess.run([BIN, *args], capture_output=True, text=True, timeout=timeout,
                           preexec_fn=preexec, cwd=cwd,
                           env=None if env is None else {**os.environ, **env})
    except subprocess.TimeoutExpired:
        return "timeout", ""
    return r.returncode, r.stdout + r.stderr


def run_two_ranks(args, timeout=TIMEOUT):
    """run() of `cfddem args` on 2 MPI ranks (one thread each), as root may; None where this
    machine has no mpirun."""
    mpirun = shutil.which("mpirun")
    if not mpirun:
        return None
    try:
        r = subprocess.run([mpirun, "-np", "2", "--oversubscribe", BIN, *args, "--threads", "1"],
                           capture_output=True, text=True, timeout=timeout,
                           env=dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1",
                                    OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1"))
    except subprocess.TimeoutExpired:
        return "timeout", ""
    return r.returncode, r.stdout + r.stderr


def tree(d):
    """Every file under d with its bytes."""
    out = {}
    for root, _, files in os.walk(d):
        for n in files:
            p = os.path.join(root, n)
            with open(p, "rb") as f:
                out[os.path.relpath(p, d)] = f.read()
    return out


def rows(d):
    with open(os.path.join(d, "diagnostics.csv")) as f:
        return list(csv.reader(f))


class Context:
    def __init__(self, tmp):
        self.tmp = tmp
        # The pre-existing run directory every refused case points at.
        self.precious = os.path.join(tmp, "precious")
        code, out = run(["run", SMALL, *TINY, "output.snapshot_interval=1e-5",
                         "output.checkpoint_interval=1e-5", "--quiet", "--out", self.precious])
        assert code == 0, out
        self.before = tree(self.precious)
        assert any(n.startswith("snapshot_") for n in self.before), sorted(self.before)

    def fresh(self, name):
        d = os.path.join(self.tmp, name)
        shutil.rmtree(d, ignore_errors=True)
        return d

    def file(self, name, text):
        p = os.path.join(self.tmp, name)
        with open(p, "w") as f:
            f.write(text)
        return p


CASES = []


def case(fn):
    CASES.append(fn)
    return fn


def expect(ctx, args, code, needle, out_dir=None, timeout=TIMEOUT, fresh=False, **kw):
    """Run `args` (with --out the precious directory unless given), check the exit code, the
    message and that the precious directory is unchanged. fresh: an input error found while the
    particles are set up (after the run directory is looked at), so --out is a new directory,
    which must not be created. Returns the output."""
    never = os.path.join(ctx.tmp, "never_written")
    if args and args[0] == "run" and "--out" not in args:
        args = [*args, "--out", never if fresh else (out_dir or ctx.precious)]
    got, out = run(args, timeout=timeout, **kw)
    assert got == code, f"exit {got}, expected {code}: {out[-1500:]}"
    if needle:
        assert re.search(needle, out), f"message lacks /{needle}/: {out[-1500:]}"
    assert tree(ctx.precious) == ctx.before, "the pre-existing run directory changed"
    assert not os.path.exists(never), "a refused run created its directory"
    return out


def stops(ctx, scene, overrides, needle, name, end="2e-4"):
    """A run of `scene` with `overrides` to run.end_time = `end` that stops (exit 3) with
    `needle`, into a fresh directory `name`."""
    return expect(ctx, ["run", scene, *overrides, f"run.end_time={end}", "--quiet"], 3, needle,
                  out_dir=ctx.fresh(name))


# ---- the command line (exit 2, plain message) ----
@case
def threads_zero(ctx):
    expect(ctx, ["run", SMALL, "--threads", "0"], 2, r"--threads: must be >= 1, got 0")


@case
def threads_negative(ctx):
    expect(ctx, ["run", SMALL, "--threads=-3"], 2, r"--threads: must be >= 1")


@case
def threads_not_a_number(ctx):
    expect(ctx, ["run", SMALL, "--threads", "two"], 2, r"must be a whole number >= 1, got 'two'")


@case
def simd_level_not_a_level(ctx):
    # The kernels' instruction set cap (core/simd_level.hpp): refused before anything is read.
    expect(ctx, ["run", SMALL], 2, r"CFDDEM_SIMD: 'avx2' is not an instruction set level",
           env={"CFDDEM_SIMD": "avx2"})


@case
def mistyped_command(ctx):
    expect(ctx, ["runn", SMALL], 2, r"unknown command 'runn' \(the commands are: run, check")


@case
def no_command(ctx):
    expect(ctx, [], 2, r"a command is required: run or check")


@case
def unknown_option(ctx):
    expect(ctx, ["run", SMALL, "--no-such-option"], 2, r"--no-such-option")


@case
def version(ctx):
    out = expect(ctx, ["--version"], 0, None)
    assert out == f"cfddem {VERSION}\n", out


@case
def threads_beyond_cores_warn(ctx):
    expect(ctx, ["run", SMALL, *TINY, "--threads", "512", "--quiet"], 0,
           r"warning: --threads 512 exceeds the \d+ core", out_dir=ctx.fresh("threads"))


# ---- scene files and keys (exit 2, naming the key or file) ----
@case
def scene_missing(ctx):
    expect(ctx, ["run", "/no/such/scene.toml"], 2, r"/no/such/scene.toml: scene file not found")


@case
def scene_is_a_directory(ctx):
    expect(ctx, ["run", SCENES], 2, r"is a directory, not a scene file")


@case
def toml_syntax_error(ctx):
    bad = ctx.file("bad.toml", "[domain\nlo = [0, 0, 0]\n")
    expect(ctx, ["run", bad], 2, r"bad.toml line 1")


@case
def unknown_key(ctx):
    expect(ctx, ["run", SMALL, "dem.no_such_key=1"], 2, r"'dem.no_such_key'.*unknown key")


@case
def restitution_out_of_range(ctx):
    expect(ctx, ["run", SMALL, "dem.restitution=1.5"], 2, r"'dem.restitution'.*\[0, 1\]")


@case
def word_for_a_number(ctx):
    expect(ctx, ["run", SMALL, "dem.dt_factor=fast"], 2, r"'dem.dt_factor'.*expected a number")


@case
def domain_inverted(ctx):
    expect(ctx, ["run", SMALL, "domain.hi=[1e-3,-1e-3,1e-3]"], 2, r"'domain.hi'.*must exceed")


@case
def nan_and_inf_refused_naming_the_key(ctx):
    """NaN and inf (TOML reads both) in a vector key passed `check` and stopped the run at step 0
    as "unstable"; a NaN in domain.lo was reported as domain.hi. Each is refused naming its key."""
    for key, value in (("gravity", "[nan,0,0]"), ("particles.velocity", "[inf,0,0]"),
                       ("domain.lo", "[nan,0,0]"), ("particles.region_hi", "[0,-inf,0]")):
        expect(ctx, ["check", SMALL, f"{key}={value}"], 2,
               rf"scene key '{re.escape(key)}'.*element \d must be a finite number")
    expect(ctx, ["run", SETTLING, "fluid.velocity=[nan,0,0]"], 2,
           r"scene key 'fluid.velocity'.*element 0 must be a finite number")
    expect(ctx, ["check", SETTLING, "fluid.outflow_pressure=inf"], 2,
           r"scene key 'fluid.outflow_pressure'.*must be a finite number, got inf")


@case
def kernel_width_and_profile_bins_bounded(ctx):
    """fluid.deposition_width = 1e300 and output.profile_bins = 2e9 stopped with exit 3 and a raw
    C++ message (vector::_M_default_append, "cannot create std::vector larger than
    max_size()"), and profile_bins = 1e8 still ran after 60 s: refused at set-up, naming the key
    and its range."""
    expect(ctx, ["run", SETTLING, "fluid.deposition=dpvm", "fluid.deposition_width=1e300"], 2,
           r"scene key 'fluid.deposition_width'.*must be in \(0, 100\], got 1e\+300", timeout=20)
    for bins in ("2000000000", "1e8"):
        expect(ctx, ["run", SMALL, "output.profile_axis=x", f"output.profile_bins={bins}"], 2,
               r"scene key 'output.profile_bins'.*must be in 1..65536", timeout=20)


@case
def override_without_equals(ctx):
    expect(ctx, ["check", SMALL, "dem.restitution"], 2, r"not of the form key=value")


@case
def particle_file_missing(ctx):
    expect(ctx, ["run", HCS, "particles.file=/no/such.csv"], 2, r"/no/such.csv", fresh=True)


@case
def particle_csv_bad_number(ctx):
    p = ctx.file("bad_number.csv", "x,y,z,vx,vy,vz,diameter,density\n1e-3,1e-3,1e-3,0,0,0,1e-4,"
                                   "lots\n")
    expect(ctx, ["run", HCS, f"particles.file={p}"], 2, r"bad_number.csv line 2.*'lots'", fresh=True)


@case
def particle_csv_missing_column(ctx):
    p = ctx.file("no_density.csv", "x,y,z,vx,vy,vz,diameter\n1e-3,1e-3,1e-3,0,0,0,1e-4\n")
    expect(ctx, ["run", HCS, f"particles.file={p}"], 2, r"missing column 'density'", fresh=True)


@case
def particle_csv_overlap(ctx):
    p = ctx.file("overlap.csv", "x,y,z,vx,vy,vz,diameter,density\n1e-3,1e-3,1e-3,0,0,0,1e-4,1000\n"
                                "1.05e-3,1e-3,1e-3,0,0,0,1e-4,1000\n")
    expect(ctx, ["run", HCS, f"particles.file={p}"], 2, r"particles 0 .* and 1 .* overlap", fresh=True)


@case
def particle_file_cuts_a_wall(ctx):
    """A particle cutting into a wall passed set-up, then stopped at step 0 as "too fast for the
    spring (raise k or lower dt)"; two coincident centres with allow_overlap gave NaN positions.
    Both are refused at set-up, naming the particle and the wall or the pair."""
    head = "x,y,z,vx,vy,vz,diameter,density\n"
    p = ctx.file("cuts_wall.csv", head + "1e-3,1e-3,1e-3,0,0,0,1e-4,1000\n"
                                         "1e-3,4.5e-5,1e-3,0,0,0,1e-4,1000\n")
    wall = ["domain.periodic=[true,false,true]"]
    expect(ctx, ["run", HCS, f"particles.file={p}", *wall], 2,
           r"cuts_wall.csv: particle 1 at .* overlaps wall y_lo by 5e-06 m", fresh=True)
    expect(ctx, ["run", HCS, f"particles.file={p}", *wall, "particles.allow_overlap=true",
                 "run.end_time=1e-5", "--quiet"], 0, None, out_dir=ctx.fresh("cut_allowed"))
    q = ctx.file("same_centre.csv", head + "1e-3,1e-3,1e-3,0,0,0,1e-4,1000\n"
                                           "1e-3,1e-3,1e-3,0,0,0,1e-4,1000\n")
    expect(ctx, ["run", HCS, f"particles.file={q}", "particles.allow_overlap=true"], 2,
           r"particles 0 and 1 have the same centre", fresh=True)


CYLINDER = os.path.join(SCENES, "cylinder_granular.toml")  # R = 1 mm column along y, 2 mm box


@case
def cylinder_keys_refused_naming_the_key(ctx):
    """domain.shape = "cylinder" (issue 40): a radius that is not positive or does not fit in
    the box, a periodic axis across the column, an unknown shape or axis, the cylinder's keys
    with a box and a gas in a column: each refused before anything is written, naming the key."""
    for scene, override, needle in (
            (CYLINDER, "domain.cylinder_radius=-1e-3", r"'domain.cylinder_radius'.*must be > 0, "
                                                       r"got -0.001"),
            (CYLINDER, "domain.cylinder_radius=0", r"'domain.cylinder_radius'.*must be > 0"),
            (CYLINDER, "domain.cylinder_radius=1.5e-3", r"'domain.cylinder_radius'.*0.0015 m does "
                                                        r"not fit in the box.*at most .*0.001 m"),
            (CYLINDER, "domain.periodic=[true,true,false]", r"'domain.periodic'.*must be false on "
                                                            r"axes x and z, across the cylinder"),
            (CYLINDER, "domain.cylinder_axis=x", r"'domain.periodic'.*must be false on axes y "
                                                 r"and z"),
            (CYLINDER, "domain.shape=sphere", r"'domain.shape'.*unknown value \"sphere\" "
                                              r"\(available: \"box\", \"cylinder\"\)"),
            (CYLINDER, "domain.cylinder_axis=w", r"'domain.cylinder_axis'.*unknown value \"w\""),
            (SMALL, "domain.cylinder_radius=5e-4", r"'domain.cylinder_radius'.*applies to "
                                                   r"domain.shape = \"cylinder\" only")):
        expect(ctx, ["run", scene, override], 2, r"scene key " + needle)
    # The gas in a column: the multigrid's empty rows, at least 4 cells across.
    for override, needle in (
            ("fluid.solver=hypre", r"'fluid.solver'.*does not take the solid cells"),
            ("domain.cylinder_radius=2e-4", r"'domain.cylinder_radius'.*spans fewer than 4 cells")):
        expect(ctx, ["run", SETTLING, "domain.shape=cylinder", override], 2,
               r"scene key " + needle)
    # A column too coarse for its area: check warns with the staircase's area.
    expect(ctx, ["check", SETTLING, "domain.shape=cylinder", "fluid.cells=[6,6,6]"], 0,
           r"warning: the gas's column is a staircase of 32 whole cells whose area is 1\.132 pi "
           r"R\^2")


CFB = os.path.join(SCENES, "cfb_riser.toml")  # a recycling inlet, an outflow top face


@case
def inlet_and_outflow_keys_refused_naming_the_key(ctx):
    """Particles through open faces (issue 40): an inlet without a gas, a region outside the
    domain or empty, a negative rate, recycling without removal, a mass rate drawn from a file
    scene's sizes, an unknown outflow rule."""
    for scene, override, needle in (
            (SMALL, "inlet.mass_rate=1e-6", r"'inlet.mass_rate'.*needs a \[fluid\] table"),
            (CFB, "inlet.region_hi=[2e-3,2e-3,3e-3]", r"'inlet.region_hi'.*inside the domain"),
            (CFB, "inlet.region_lo=[0,2e-3,0]", r"'inlet.region_hi'.*non-empty"),
            (CFB, "inlet.mass_rate=-1", r"'inlet.mass_rate'.*must be >= 0"),
            (CFB, "particles.outflow=wall", r"'inlet.recycle'.*particles.outflow must be "
                                            r"\"remove\""),
            (CFB, "particles.outflow=vanish", r"'particles.outflow'"),
            (CFB, "inlet.velocity=[0,inf,0]", r"'inlet.velocity'"),
            (CFB, "inlet.diameter=1e-4", r"'inlet.diameter'.*applies to inlet.mass_rate's new "
                                         r"particles only")):
        expect(ctx, ["run", scene, override], 2, r"scene key " + needle)
    # The inlet's own kind: a size that does not fit, a density out of range.
    for override, needle in (("inlet.diameter=5e-3", r"'inlet.diameter'.*does not fit"),
                             ("inlet.density=-2", r"'inlet.density'.*must be > 0"),
                             ('inlet.diameter={distribution="uniform",min=9e-5,max=8e-5}',
                              r"'inlet.diameter.max'.*must be > inlet.diameter.min"),
                             ('inlet.diameter={distribution="normal",min=6e-5,max=8e-5}',
                              r"'inlet.diameter.mean'.*required")):
        expect(ctx, ["run", CFB, "inlet.mass_rate=1e-6", override], 2, r"scene key " + needle)
    # A region inside the domain where no particle fits entered nothing, silently (0 kg of the
    # 2e-8 kg due in 1 ms): the corner box of a cylinder, a slab thinner than a radius at a wall
    # (with the inlet's largest size, or with recycling the run's own).
    for scene, overrides, needle in (
            (os.path.join(SCENES, "cylinder_bed.toml"),
             ["inlet.mass_rate=2e-5", "inlet.region_lo=[0,7e-3,0]", "inlet.region_hi=[1e-4,9e-3,1e-4]"],
             r"the region's nearest point to the cylinder's axis is 0.000989949 m from it, and a "
             r"particle of "
             r"diameter 0.0001 m needs its centre within 0.00075 m"),
            (BED, ["inlet.mass_rate=2e-5", "inlet.region_lo=[0,7e-3,0]",
                   "inlet.region_hi=[2e-5,9e-3,1.6e-3]"],
             r"along axis 0 no centre of a particle of diameter 0.0001 m lies both in the region "
             r"\[0, 2e-05\] m and a radius from the walls"),
            (CFB, ["inlet.mass_rate=1e-6", 'inlet.diameter={distribution="uniform",min=5e-5,max=1.5e-4}',
                   "inlet.region_lo=[0,0,0]", "inlet.region_hi=[2e-3,6e-5,2e-3]"],
             r"along axis 1 no centre of a particle of diameter 0.00015 m")):
        expect(ctx, ["run", scene, *overrides], 2,
               r"scene keys 'inlet.region_lo', 'inlet.region_hi': no particle can enter: " + needle,
               fresh=True)


@case
def cylinder_particles_placed_inside_and_checked(ctx):
    """Generated particles are placed inside the column (rho <= R - r); one from a file outside
    it, or cutting its wall, is refused at set-up naming the particle."""
    expect(ctx, ["check", CYLINDER], 0, r"domain_shape +cylinder along y, radius 0.001 m, "
                 r"cross-section 3.14159e-06 m\^2")
    column = ["domain.shape=cylinder", "domain.periodic=[false,true,false]"]  # R = 2 mm in HCS
    head = "x,y,z,vx,vy,vz,diameter,density\n2e-3,1e-3,2e-3,0,0,0,1e-4,1000\n"
    for name, second, needle in (
            ("outside.csv", "3.9e-3,1e-3,3.9e-3", r"does not lie inside the cylinder"),
            ("cuts_cylinder.csv", "3.96e-3,1e-3,2e-3", r"overlaps the cylinder's wall by 1e-05 m")):
        p = ctx.file(name, head + second + ",0,0,0,1e-4,1000\n")
        expect(ctx, ["run", HCS, f"particles.file={p}", *column], 2, r"particle 1 at .* " + needle,
               fresh=True)
    # A generator region in the box's corner, beyond the curved wall, placed nothing in 11,000
    # tries and was refused as if random placement had saturated it.
    expect(ctx, ["check", CYLINDER, "particles.region_lo=[0,0,0]",
                 "particles.region_hi=[3e-4,1.6e-3,3e-4]", "particles.count=10"], 2,
           r"scene keys 'particles.region_lo', 'particles.region_hi': the region lies outside the "
           r"cylinder: its nearest centre to the axis is 0.00106066 m from it")
    # The lattice says where its sites went.
    expect(ctx, ["check", CYLINDER, "particles.placement=lattice", "particles.region_lo=[0,0,0]",
                 "particles.region_hi=[3e-4,1.6e-3,3e-4]", "particles.count=10"], 2,
           r"a cubic lattice of spacing d fits 0 particles in the region and inside the cylinder "
           r"\(of its \d+ sites\)")


@case
def fluid_cells_too_many(ctx):
    expect(ctx, ["check", SETTLING, "fluid.cells=[100000,100000,100000]"], 2,
           r"'fluid.cells': at most 65536 cells per axis")


@case
def snapshot_given_as_checkpoint(ctx):
    snap = sorted(n for n in ctx.before if n.startswith("snapshot_"))[0]
    expect(ctx, ["run", SMALL, *TINY, "--restart", os.path.join(ctx.precious, snap)], 2,
           r"is a particle snapshot .* not a checkpoint")


@case
def restart_changed_key_refused(ctx):
    """The refusal shows each number as typed (its shortest form), not the 17 digits the
    checkpoint compares: "0.80000000000000004 in the checkpoint" read as a different value."""
    ck = sorted(n for n in ctx.before if n.startswith("checkpoint_"))[0]
    expect(ctx, ["run", SMALL, *TINY, "dem.restitution=0.5", "--restart",
                 os.path.join(ctx.precious, ck)], 2,
           r"different configuration: dem.restitution = 0.5 here, 0.8 in the checkpoint; "
           r"dem.wall_restitution = 0.5 here, 0.8 in the checkpoint \(only")


@case
def settle_then_turn_the_gas_on(ctx):
    """A restart may change the gas drive: settle 30 particles in a closed box with the gas at
    rest, then continue from the checkpoint with an inflow of 0.1 m/s at y_lo and an outflow at
    y_hi. The incompressible gas then carries U through every plane: its y momentum is
    rho U V (1 - phi) = 3.359e-10 kg m/s (phi = 0.47%), to 1%. Any other key is still refused."""
    base = [SETTLING, "particles.count=30", "run.end_time=2e-3", "output.interval=5e-4"]
    settled = ctx.fresh("settled")
    expect(ctx, ["run", *base, "output.checkpoint_interval=1e-3", "--quiet"], 0, None,
           out_dir=settled)
    ck = os.path.join(settled, "checkpoint_000000010.h5")
    on = ctx.fresh("gas_on")
    expect(ctx, ["run", *base, "fluid.bc.y_lo=inflow", "fluid.bc.y_hi=outflow",
                 "fluid.inflow_velocity=[0,0.1,0]", "fluid.velocity=[0,0.1,0]", "--restart", ck,
                 "--quiet"], 0, None, out_dir=on)
    r = rows(on)
    col = r[0].index("gas_momentum_y")
    assert abs(float(r[1][col])) < 1e-12 and abs(float(r[3][col])) < 1e-12, r  # settling rows
    v = 1.5e-3 ** 3
    phi = 30 * 3.141592653589793 / 6 * 1e-4 ** 3 / v
    want = 1.0 * 0.1 * v * (1 - phi)
    assert abs(float(r[-1][col]) / want - 1) < 0.01, (r[-1][col], want)
    expect(ctx, ["run", *base, "fluid.density=2", "--restart", ck, "--quiet"], 2,
           r"different configuration: fluid.density = 2 here, 1 in the checkpoint \(only .*"
           r"fluid.bc.\* may change",
           out_dir=ctx.fresh("refused_restart"))


@case
def restart_counts_its_own_work(ctx):
    """After a restart the closing line said "74.96 s for 600 fluid steps (0.1249 s each)" when
    400 were run, and run.json's particle_steps_per_second was inflated alike: the counters go
    on from the checkpoint. A restart at t = 1 ms of a 2 ms run with a gas (fluid.dt = 1e-4 s)
    reports its 10 fluid steps and the rate of the particle steps it took, while run.json's
    fluid_steps and particle_steps still count the whole run."""
    import json
    base = [SETTLING, "particles.count=30", "output.interval=5e-4"]
    first = ctx.fresh("restart_count_first")
    expect(ctx, ["run", *base, "run.end_time=1e-3", "output.checkpoint_interval=1e-3",
                 "--quiet"], 0, None, out_dir=first)
    with open(os.path.join(first, "run.json")) as f:
        before = json.load(f)
    second = ctx.fresh("restart_count_second")
    out = expect(ctx, ["run", *base, "run.end_time=2e-3", "--restart",
                       os.path.join(first, "checkpoint_000000010.h5")], 0,
                 r"Loop time of \S+ s for 10 fluid steps \(", out_dir=second)
    with open(os.path.join(second, "run.json")) as f:
        j = json.load(f)
    assert j["fluid_steps"] == 20, j["fluid_steps"]
    assert abs(j["wall_seconds_per_fluid_step"] * 10 / j["loop_seconds"] - 1) < 1e-9, j
    this_run = j["particle_steps_per_second"] * j["loop_seconds"]
    assert abs(this_run / (j["particle_steps"] - before["particle_steps"]) - 1) < 0.05, \
        (this_run, j["particle_steps"], before["particle_steps"])


@case
def restart_profiles_start_at_zero(ctx):
    """A restart into a new --out wrote profiles.csv from the restart time while diagnostics.csv
    starts at t = 0. One rule: both start at t = 0, the rows before the restart taken from the
    run it continues; the restart being bitwise, the file is the uninterrupted run's."""
    prof = ["output.profile_axis=x", "output.profile_bins=4", "output.interval=5e-6"]
    whole = ctx.fresh("profiles_whole")
    expect(ctx, ["run", SMALL, *TINY, *prof, "output.checkpoint_interval=1e-5", "--quiet"], 0,
           None, out_dir=whole)
    ck = sorted(n for n in os.listdir(whole) if n.startswith("checkpoint_"))[0]
    again = ctx.fresh("profiles_again")
    expect(ctx, ["run", SMALL, *TINY, *prof, "--quiet", "--restart", os.path.join(whole, ck)], 0,
           None, out_dir=again)
    with open(os.path.join(whole, "profiles.csv")) as f:
        want = f.read()
    with open(os.path.join(again, "profiles.csv")) as f:
        got = f.read()
    assert got.splitlines()[1].startswith("0,"), got[:300]
    assert got == want, (got[:500], want[:500])


@case
def gas_added_at_a_restart_says_how(ctx):
    """A bed settled with no gas cannot be restarted with one (the checkpoint holds no gas
    state): the refusal now says how to get there (settle with the gas at rest, then change the
    drive)."""
    box = os.path.join(SCENES, "box_gravity.toml")
    settled = ctx.fresh("settled_dry")
    expect(ctx, ["run", box, "run.end_time=2e-4", "output.checkpoint_interval=1e-4", "--quiet"],
           0, None, out_dir=settled)
    ck = sorted(n for n in os.listdir(settled) if n.startswith("checkpoint_"))[0]
    expect(ctx, ["run", box, "run.end_time=4e-4", "fluid.cells=[4,4,4]", "fluid.density=1",
                 "fluid.viscosity=2e-5", "fluid.dt=1e-4", "--restart",
                 os.path.join(settled, ck)], 2,
           r"holds no gas state .*a gas cannot be added at a restart\. To fluidize a settled "
           r"bed, settle it with the gas at rest", out_dir=ctx.fresh("wet_restart"))


@case
def gas_alone_at_its_own_step(ctx):
    """No particles and an adaptive gas (fluid.dt = 0): the gas runs alone at its own step,
    capped by fluid.max_dt = 1e-3 s, and ends at run.end_time (an empty scene's particle step of
    6.3e-3 s used to set the fluid step: two steps, ending at 0.0126 s)."""
    import json
    d = ctx.fresh("gas_alone")
    expect(ctx, ["run", SETTLING, "particles.count=0", "fluid.dt=0", "run.end_time=1e-2",
                 "--quiet"], 0, None, out_dir=d)
    with open(os.path.join(d, "run.json")) as f:
        j = json.load(f)
    assert abs(j["end_time"] - 1e-2) < 1e-12, j["end_time"]
    assert j["fluid_steps"] >= 10 and j["fluid_dt_mean"] <= 1e-3, (j["fluid_steps"],
                                                                   j["fluid_dt_mean"])
    assert float(rows(d)[-1][0]) == float(j["end_time"])


@case
def no_particles_with_every_scheme(ctx):
    """An empty DEM scene runs with every scheme (orb used to stop with exit 3 and a neighbour
    cutoff of 2.5 m made up from no particle)."""
    for scheme in ("explicit", "orb", "islands"):
        d = ctx.fresh(f"empty_{scheme}")
        expect(ctx, ["run", SMALL, "particles.count=0", f"dem.scheme={scheme}",
                     "run.end_time=1e-3", "--quiet"], 0, None, out_dir=d)
    # No particle step to compare dem.nsubit with: no warning (it read "nsubit up to 0").
    out = expect(ctx, ["check", BED, "particles.count=0", "dem.scheme=orb"], 0, None)
    assert "warning: dem.nsubit" not in out, out[-1500:]


@case
def gas_grid_beyond_memory(ctx):
    """fluid.cells = [1000, 1000, 1000] passed `check`, and the run grew to 24 GB until the kernel
    killed it (rc 137, no message). check and run estimate the gas's memory (1.6 KB a cell:
    1.6e3 GB here) and refuse what this machine cannot hold, naming the key and the estimate;
    check shows the estimate of a grid that fits."""
    for cmd in ("check", "run"):
        expect(ctx, [cmd, SETTLING, "fluid.cells=[1000,1000,1000]"], 2,
               r"scene key 'fluid.cells': \[1000, 1000, 1000\] cells need about 1.6e\+03 GB for "
               r"the gas .* more than this machine's", timeout=20)
    out = expect(ctx, ["check", SETTLING], 0, None)
    assert re.search(r"gas_memory_gb \(estimate, all ranks\)\s+0.0016\b", out), out


@case
def skin_and_tolerance_refused_before_the_run(ctx):
    """dem.neighbor_skin = 10 m passed `check` and stopped the run at its first neighbour list
    (exit 3); fluid.tolerance = 1e-300 started the run and stopped it at the first projection
    (exit 3). Both are refused before the run starts, naming the key."""
    for cmd in ("check", "run"):
        expect(ctx, [cmd, SMALL, "dem.neighbor_skin=10"], 2,
               r"scene key 'dem.neighbor_skin': periodic axis 0 is 0.001737 m long, not more "
               r"than twice the neighbor cutoff plus skin, 20.0001 m .*lower dem.neighbor_skin",
               fresh=cmd == "run")
        expect(ctx, [cmd, SETTLING, "fluid.tolerance=1e-300"], 2,
               r"scene key 'fluid.tolerance'.*must be in \[1e-12, 1\), got 1e-300")


@case
def inviscid_gas_with_a_viscous_drag_law(ctx):
    """fluid.viscosity = 0 (allowed) with bvk, bvk2 or koch_hill drag stopped the first step with
    exit 3 "multigrid: the coarsest operator is not positive definite" (the drag's 0 x inf):
    refused at set-up naming the key and the drag law. An inviscid gas with wen_yu (Newton's
    drag as mu -> 0) or no drag runs."""
    for drag in ("bvk", "bvk2", "koch_hill"):
        expect(ctx, ["run", SETTLING, "fluid.viscosity=0", f"fluid.drag={drag}"], 2,
               rf"scene key 'fluid.viscosity': 0 \(an inviscid gas\) cannot take fluid.drag = "
               rf"\"{drag}\"")
    for drag in ("wen_yu", "none"):
        expect(ctx, ["run", SETTLING, "fluid.viscosity=0", f"fluid.drag={drag}",
                     "run.end_time=5e-4", "--quiet"], 0, None, out_dir=ctx.fresh(f"mu0_{drag}"))


@case
def single_gas_cell(ctx):
    """fluid.cells = [1, 1, 1] with the default solver stopped at the first step with exit 3
    "multigrid ... not positive definite" (walls or periodic): refused at set-up, pointing at
    hypre, which runs it."""
    for scene in (SETTLING, HCS_GAS):
        for solver in ("auto", "multigrid"):
            expect(ctx, ["run", scene, "fluid.cells=[1,1,1]", f"fluid.solver={solver}"], 2,
                   rf"scene key 'fluid.cells': \[1, 1, 1\] \(a single gas cell\) cannot be "
                   rf"solved by fluid.solver = \"{solver}\".*fluid.solver = \"hypre\"")
    expect(ctx, ["run", SETTLING, "fluid.cells=[1,1,1]", "fluid.solver=hypre",
                 "run.end_time=5e-4", "--quiet"], 0, None, out_dir=ctx.fresh("one_cell_hypre"))


@case
def extreme_gas_values_refused(ctx):
    """fluid.density = 1e-300, fluid.viscosity = 1e300 and fluid.velocity = [1e300, 0, 0] ran
    the first fluid step for 20-60 s with no progress line. The viscous number nu dt_f / dx^2
    (1e-4 s on cells of 1.5e-4 m) and the Courant number |u| dt_f / dx are refused beyond what
    can run, naming the keys and the number; the scene's own values run."""
    expect(ctx, ["check", SETTLING, "fluid.density=1e-300"], 2,
           r"scene keys 'fluid.viscosity' and 'fluid.density': the kinematic viscosity mu / "
           r"rho_g = 2e\+295 m\^2/s makes the viscous number nu dt_f / dx\^2 = 8.89e\+298",
           timeout=10)
    expect(ctx, ["run", SETTLING, "fluid.viscosity=1e300"], 2,
           r"'fluid.viscosity' and 'fluid.density'.*nu dt_f / dx\^2 = 4.44e\+303", timeout=10)
    expect(ctx, ["run", SETTLING, "fluid.velocity=[1e300,0,0]"], 2,
           r"scene keys 'fluid.velocity' and 'fluid.inflow_velocity': a gas speed of 1e\+300 m/s "
           r"crosses 6.67e\+299 cells", timeout=10)
    # An adaptive fluid step shortens itself to the gas's Courant number: refused where a run
    # could not count its steps at its first length.
    expect(ctx, ["run", SETTLING, "fluid.dt=0", "fluid.inflow_velocity=[0,1e20,0]"], 2,
           r"'fluid.inflow_velocity'.*: the adaptive fluid step starts at 1.35e-24 s .* needs "
           r"4.44e\+22 such steps, more than a run can count", timeout=10, fresh=True)


@case
def tiny_cfl_refused(ctx):
    """fluid.cfl = 1e-9 is inside the key's range (above 0) but makes the gas take its fixed
    fluid step in millions of sub-steps: the first fluid step never ended, with no progress line
    (the riser starts at rest, so its body force's speed after one fluid step counts). Refused,
    naming the key and the sub-steps; cfl 1e-4 and the scenes' own values run. An adaptive fluid
    step (fluid.dt = 0) starts at 1.3e-11 s, some 1.5e10 steps for the bed's 0.2 s: it takes no
    sub-steps and shows its progress, so it warns."""
    expect(ctx, ["check", BED, "fluid.cfl=1e-9"], 2,
           r"scene key 'fluid.cfl': 1e-09 makes the gas take 7.5e\+06 sub-steps of 1.33e-11 s in "
           r"every fluid step of 0.0001 s \(fluid.dt\)", timeout=10)
    expect(ctx, ["run", RISER, "fluid.cfl=1e-12"], 2,
           r"scene key 'fluid.cfl': 1e-12 makes the gas take 1e\+10 sub-steps", timeout=10,
           fresh=True)
    expect(ctx, ["check", BED, "fluid.cfl=1e-4"], 0, None, timeout=30)
    # A gas at rest that the particles set moving (hcs_gas: no fluid step ended at cfl 1e-9):
    # their speeds are an estimate of the gas's, so a warning, not a refusal.
    expect(ctx, ["check", HCS_GAS, "fluid.cfl=1e-9"], 0,
           r"warning: fluid.cfl = 1e-09: once the particles \(up to 0.316 m/s along an axis\) set "
           r"the gas moving, it may take up to 3.79e\+08 sub-steps in each fluid step of 0.0001 s",
           timeout=10)
    # With the viscous term explicit throughout, a gas at rest takes sub-steps too: 3e8 at cfl
    # 1e-9 on hcs_gas's 200 um cells. Known at set-up, so refused there (it ran for ever).
    expect(ctx, ["check", HCS_GAS, "fluid.cfl=1e-9", "fluid.implicit_viscosity=false"], 2,
           r"scene key 'fluid.cfl': 1e-09 makes the gas take 3e\+08 sub-steps of 3.33e-13 s in "
           r"every fluid step of 0.0001 s \(fluid.dt\) at the gas speed of 0 m/s with the viscous "
           r"term explicit \(nu = 2e-05 m\^2/s\)", timeout=10)
    # Run, it stopped nowhere: the second fluid step, the gas now moving, ran for ever. It stops
    # there (exit 3), naming the sub-steps, fluid.cfl and the fastest face.
    expect(ctx, ["run", HCS_GAS, "fluid.cfl=1e-9", "run.end_time=3e-4"], 3,
           r"run stopped: t = 0.0001 s, fluid step 2: gas step: the gas would take [0-9.]+e\+08 "
           r"sub-steps in this fluid step of 0.0001 s at fluid.cfl = 1e-09 \(a Courant rate of "
           r".*the fastest [0-9.e+-]+ m/s along [xyz] at the face at \(.*\) m\), beyond the "
           r"100000 a fluid step may take: raise fluid.cfl", out_dir=ctx.fresh("tiny_cfl_run"),
           timeout=30)
    # An adaptive fluid step takes no sub-steps, so it runs, showing its progress; the count of
    # steps its first length makes to run.end_time is a warning.
    expect(ctx, ["check", BED, "fluid.dt=0", "fluid.cfl=1e-9"], 0,
           r"warning: fluid.cfl = 1e-09 starts the adaptive fluid step at 1.33e-11 s at the "
           r"scene's gas speeds and body force: about 1.5e\+10 fluid steps to run.end_time = "
           r"0.2 s", timeout=10)
    out = expect(ctx, ["check", BED, "fluid.dt=0", "fluid.cfl=1e-4"], 0, None, timeout=30)
    assert "adaptive fluid step at" not in out, out
    # A long cap on the adaptive step is no reason to refuse it (it was refused as if the gas
    # took sub-steps of a 10 s fluid step).
    out = expect(ctx, ["check", os.path.join(SCENES, "elutriation.toml"), "fluid.dt=0",
                       "fluid.max_dt=10"], 0, None, timeout=30)
    assert "warning" not in out, out


@case
def many_gas_substeps_show_progress(ctx):
    """A fixed fluid step at a small fluid.cfl (warned: tiny_cfl_refused) takes the gas hundreds
    of sub-steps once the particles set it moving; hcs_gas at cfl 1e-6 ran 15 s without a line,
    as the progress lines came only between fluid steps. The gas's sub-steps now say where they
    are (about 3 fluid steps of up to 300 sub-steps here)."""
    expect(ctx, ["run", HCS_GAS, "fluid.cfl=1e-3", "run.end_time=3e-4",
                 "output.progress_seconds=0.02"], 0,
           r"fluid step +\d+ t = [0-9.e+-]+ s: gas sub-step \d+ \([0-9.e+-]+ s\), \d+% of the "
           r"fluid step", out_dir=ctx.fresh("many_substeps"), timeout=60)


@case
def intervals_far_below_the_step_write_every_step(ctx):
    """An output, snapshot or checkpoint interval far below the fluid step: the next output time
    was found by adding the interval until it passed the step, 1e16 additions at 1e-20 s, and at
    1e-300 s additions that never moved the sum (a run that never ended). Now a row, snapshot and
    checkpoint come at every fluid step."""
    out_dir = ctx.fresh("tiny_intervals")
    expect(ctx, ["run", HCS_GAS, "run.end_time=3e-4", "output.interval=1e-300",
                 "output.snapshot_interval=1e-20", "output.checkpoint_interval=1e-300",
                 "--quiet"], 0, None, out_dir=out_dir, timeout=60)
    times = [float(r[0]) for r in rows(out_dir)[1:]]
    assert len(times) == 4 and abs(times[-1] - 3e-4) < 1e-12, times
    names = os.listdir(out_dir)
    assert sum(n.startswith("checkpoint_") for n in names) == 3, sorted(names)
    assert sum(n.startswith("snapshot_") for n in names) >= 3, sorted(names)
    # The gas boxes' recut on R ranks had the same loop.
    r = run_two_ranks(["run", BED, "run.end_time=3e-4", "partition.gas_regrid_interval=1e-300",
                       "--quiet", "--out", ctx.fresh("tiny_regrid")], timeout=60)
    if r is not None:
        assert r[0] == 0, (r[0], r[1][-1500:])  # "timeout": the recut's hang


@case
def restart_at_the_end_writes_the_last_row(ctx):
    """A gas run restarted from a checkpoint at its end time ran no fluid step and so never
    marked the row at the end: its diagnostics stopped at the last row before the checkpoint (a
    run without a gas wrote it). The row at the end is the uninterrupted run's, bit for bit."""
    whole = ctx.fresh("end_whole")
    expect(ctx, ["run", BED, "run.end_time=2e-4", "--quiet"], 0, None, out_dir=whole, timeout=60)
    longer = ctx.fresh("end_longer")  # its checkpoint at 2e-4 has no row due (interval 1e-3)
    expect(ctx, ["run", BED, "run.end_time=3e-4", "output.checkpoint_interval=1e-4", "--quiet"],
           0, None, out_dir=longer, timeout=60)
    again = ctx.fresh("end_again")
    expect(ctx, ["run", BED, "run.end_time=2e-4", "--restart",
                 os.path.join(longer, "checkpoint_000000002.h5"), "--quiet"], 0, None,
           out_dir=again, timeout=60)
    a, b = rows(whole), rows(again)
    wall = a[0].index("wall_seconds")
    strip = lambda t: [[v for i, v in enumerate(r) if i != wall] for r in t]
    assert len(b) == len(a) and float(b[-1][0]) == 2e-4 and strip(b) == strip(a), (a, b)


@case
def key_set_twice_on_the_command_line_warns(ctx):
    """A key given twice among the overrides (a slip when a long command line is edited): the
    last value holds, as before, and check and run say which one."""
    expect(ctx, ["check", SMALL, "run.end_time=1e-3", "dem.restitution=0.5", "run.end_time=2e-3"],
           0, r"warning: scene key 'run.end_time' is set more than once on the command line; "
              r"the last value, 2e-3, is used", timeout=10)


@case
def inlet_that_falls_behind_warns(ctx):
    """An inlet region inside the bed's packing finds room for few particles: 8 of the 38 due in
    1 ms entered, and only the rows' mass_in, summed against the rate by hand, showed it. The run
    says how much of the mass due waits, and run.json's "inlet" holds the counts."""
    import json
    out_dir = ctx.fresh("inlet_behind")
    expect(ctx, ["run", BED, "inlet.mass_rate=2e-5", "inlet.region_lo=[0,1e-3,0]",
                 "inlet.region_hi=[1.6e-3,2e-3,1.6e-3]", "run.end_time=1e-3", "--quiet"], 0,
           r"warning: the inlet placed [0-9.e-]+ kg of the 2e-08 kg due \(\d+%\): [0-9.e-]+ kg "
           r"waits for room in its region", out_dir=out_dir, timeout=120)
    # A rate the region cannot hold in one fluid step is known at set-up.
    expect(ctx, ["check", CFB, "inlet.mass_rate=1e3"], 0,
           r"warning: inlet.mass_rate = 1000 kg/s brings 0.1 kg in each fluid step of 0.0001 s, "
           r"more than the inlet region holds at random packing \(3.04e-06 kg")
    with open(os.path.join(out_dir, "run.json")) as f:
        inlet = json.load(f)["inlet"]
    assert abs(inlet["mass_in_kg"] + inlet["mass_waiting_kg"] - 2e-8) < 1e-12, inlet
    assert inlet["mass_waiting_kg"] > 0.5 * 2e-8, inlet


@case
def fluid_dt_longer_than_the_run(ctx):
    """fluid.dt = 0.01 s with run.end_time = 0.002 s ran silently to t = 0.01 s: refused, naming
    both keys."""
    for cmd in ("check", "run"):
        expect(ctx, [cmd, SETTLING, "fluid.dt=0.01", "run.end_time=0.002"], 2,
               r"scene key 'fluid.dt'.*0.01 s is longer than run.end_time = 0.002 s")


@case
def check_tells_about_the_gas(ctx):
    """`cfddem check` of the fluidized bed: cells per particle diameter (0.5, with a warning once
    the deposition is trilinear), fluid steps, the minimum fluidization velocity (Wen & Yu; in
    the Stokes regime of these 100 um particles it is d^2 (rho_p - rho_g) g / (1652 mu), to
    0.1%) and a rough cost."""
    out = expect(ctx, ["check", BED, "fluid.deposition=trilinear"], 0,
                 r"warning: a gas cell .* is narrower than a particle")
    assert re.search(r"cell_size / particle diameter \(smallest\)\s+0.5\b", out), out
    assert re.search(r"fluid_steps\s+2000 \(fluid.dt = 0.0001 s\)", out), out
    assert "cost_per_fluid_step" in out and "cost_of_run_s" in out, out
    umf = float(re.search(r"minimum_fluidization_velocity_m_s \(Wen & Yu\)\s+(\S+)", out)
                .group(1))
    cfg = dict(re.findall(r"^(\S+) = (.*)$", out, re.M))
    d, rho_p = float(cfg["particles.diameter"]), float(cfg["particles.density"])
    rho_g, mu = float(cfg["fluid.density"]), float(cfg["fluid.viscosity"])
    g = max(abs(float(x)) for x in cfg["gravity"].strip("[]").split(","))
    stokes = d * d * (rho_p - rho_g) * g / (2 * 33.7 / 0.0408 * mu)  # Ar << 33.7^2 / 0.0408
    assert abs(umf / stokes - 1) < 1e-3, (umf, stokes)
    quiet = expect(ctx, ["check", BED], 0, None)
    assert "narrower than a particle" not in quiet  # dpvm spreads the particle: no warning


@case
def check_polydisperse_fluidization_velocity(ctx):
    """`cfddem check` of a polydisperse bed gave U_mf about 5x low: it divided the lightest
    particle's mass by the mean diameter's volume (a density of 222 kg/m3 for 2500). It now takes
    the material's density and the Sauter mean d32: in the Stokes regime U_mf = d32^2 (rho_p -
    rho_g) g / (1652 mu), to 0.1%."""
    out = expect(ctx, ["check", BED, "particles.diameter={distribution='uniform', min=5e-5, "
                                     "max=1e-4}"], 0, None)
    m = re.search(r"minimum_fluidization_velocity_m_s \(Wen & Yu, d32\)\s+(\S+)",
                  out)
    assert m, out
    umf = float(m.group(1))
    d32 = float(re.search(r"sauter_mean_d32_m\s+(\S+)", out).group(1))
    cfg = dict(re.findall(r"^(\S+) = (.*)$", out, re.M))
    rho_p = float(cfg["particles.density"])
    rho_g, mu = float(cfg["fluid.density"]), float(cfg["fluid.viscosity"])
    stokes = d32 * d32 * (rho_p - rho_g) * 9.80665 / (2 * 33.7 / 0.0408 * mu)
    assert abs(umf / stokes - 1) < 1e-3, (umf, stokes)


# ---- legal but almost surely a mistake: a warning, and run.json as typed JSON ----
@case
def snapshot_interval_tiny_warns(ctx):
    expect(ctx, ["check", SMALL, "output.snapshot_interval=1e-12"], 0,
           r"warning: output.snapshot_interval = 1e-12 s writes up to 3e\+10 snapshot files")


@case
def dem_dt_tiny_warns(ctx):
    expect(ctx, ["check", SMALL, "dem.dt=1e-20"], 0,
           r"warning: dem.dt = 1e-20 s makes 3e\+18 steps .* years")


# ---- step counts a run cannot count (issue 38) ----
@case
def step_count_overflow_refused(ctx):
    """A step count past 2^62 (the run's 64-bit counters) is refused by check and run, naming the
    keys and the count it would need (it wrapped to INT64_MIN: 0 steps, exit 0, "done"; orb
    stopped after one sub-iteration; a diameter of 1e-300 m gave a step of 0 s and a NaN row)."""
    for args, needle in (
            (["dem.dt=1e-300"], r"'run.end_time' and 'dem.dt'.* needs 3e\+298 steps"),
            (["run.end_time=1e300"], r"'run.end_time' and 'dem.dt_factor'.* needs 6.91e\+306 "
                                     r"steps"),
            (["dem.scheme=orb", "dem.regrid_interval=1e-300"],
             r"'run.end_time' and 'dem.regrid_interval'.* needs 3e\+299 steps")):
        expect(ctx, ["check", SMALL, *args], 2, needle)
        expect(ctx, ["run", SMALL, *args], 2, needle, fresh=True)
    expect(ctx, ["run", SMALL, "particles.diameter=1e-300"], 2,
           r"'particles.diameter' and 'particles.density'.*mass is 0 kg", fresh=True)


@case
def dt_factor_warns_as_dem_dt(ctx):
    """dem.dt_factor = 0.9 (2.5 steps per contact) and 1e-12 (4e15 steps) passed silently while
    the same step through dem.dt warned: both warn, with the steps per contact, in check and
    run. The default step warns of nothing."""
    expect(ctx, ["check", SMALL, "dem.dt_factor=0.9"], 0,
           r"warning: dem.dt_factor = 0.9 \(dt = 6.51\de-06 s\) resolves a contact of "
           r"1.61e-05 s in 2.47 steps: below 10")
    expect(ctx, ["check", SMALL, "dem.dt=6.5e-6"], 0,
           r"warning: dem.dt = 6.5e-06 s resolves a contact of 1.61e-05 s in 2.4\d steps")
    expect(ctx, ["run", SMALL, *TINY, "dem.dt_factor=0.9", "--quiet"], 0,
           r"warning: dem.dt_factor = 0.9 .* in 2.47 steps", out_dir=ctx.fresh("coarse_step"))
    expect(ctx, ["check", SMALL, "dem.dt_factor=1e-12"], 0,
           r"warning: dem.dt_factor = 1e-12 \(dt = 7.23\de-18 s\) makes 4.15e\+15 steps to "
           r"run.end_time = 0.03 s")
    quiet = expect(ctx, ["check", SMALL], 0, None)
    assert "warning" not in quiet, quiet


@case
def nsubit_finer_than_the_particle_step_warns(ctx):
    """dem.nsubit = 1e9 (a typo's size) made islands step every particle 1e9 times a fluid step
    of 1e-4 s, each 1e-13 s long, with nothing said: the run never ended. check and run warn
    when dt_sp falls below the particle step, naming the largest nsubit that does not; "auto"
    and the scenes' own nsubit warn of nothing."""
    expect(ctx, ["check", BED, "dem.scheme=islands", "dem.nsubit=1e9"], 0,
           r"warning: dem.nsubit = 1000000000 makes the sub-iteration step dt_sp = 1e-13 s "
           r"\(fluid.dt / nsubit\) shorter than the particle step dt = 1.45e-07 s: every particle "
           r"steps 1.45e\+06x .* \(nsubit up to 690 keeps dt_sp >= dt\)")
    expect(ctx, ["check", SMALL, "dem.scheme=orb", "dem.nsubit=1e6"], 0,
           r"warning: dem.nsubit = 1000000 .* \(dem.regrid_interval / nsubit\)")
    for args in (["dem.scheme=islands"], ["dem.scheme=orb", "dem.nsubit=35"]):
        quiet = expect(ctx, ["check", BED, *args], 0, None)
        assert "nsubit" not in "".join(l for l in quiet.splitlines() if "warning" in l), quiet
    expect(ctx, ["run", SMALL, *TINY, "dem.scheme=orb", "dem.nsubit=1e6", "--quiet"], 0,
           r"warning: dem.nsubit = 1000000 makes", out_dir=ctx.fresh("nsubit_fine"))


@case
def huge_neighbor_skin_warns(ctx):
    """dem.neighbor_skin = 10 m on the bed's walled 1 cm column listed every particle as every
    other's neighbour and ran for minutes a fluid step without a word (a periodic axis refuses
    such a skin). check and run warn with the neighbours per particle; the default and a skin of
    a few diameters do not."""
    expect(ctx, ["check", BED, "dem.neighbor_skin=10"], 0,
           r"warning: dem.neighbor_skin = 10 m lists about 1e\+04 neighbours per particle "
           r"\(those within 10 m, the largest diameter plus the skin, of 10000 particles in all\)")
    for args in ([], ["dem.neighbor_skin=3e-4"]):
        quiet = expect(ctx, ["check", BED, *args], 0, None)
        assert "neighbours" not in quiet, quiet
    expect(ctx, ["run", SMALL, *TINY, "domain.periodic=[false,false,false]",
                 "particles.count=2000", "dem.neighbor_skin=1", "--quiet"], 0,
           r"warning: dem.neighbor_skin = 1 m lists about 2e\+03 neighbours",
           out_dir=ctx.fresh("skin"))


@case
def output_interval_below_dt_sp_warns(ctx):
    """dt_sp divides dem.regrid_interval without a gas, fluid.dt with one (the riser's 1e-4 s
    over 20); an adaptive fluid step's length is not known before the run, so no warning (it
    divided dem.regrid_interval, which a run with a gas never divides)."""
    expect(ctx, ["check", SMALL, "dem.scheme=orb", "output.interval=1e-6"], 0,
           r"warning: output.interval = 1e-06 s is shorter than the sub-iteration step dt_sp = "
           r"1e-05 s of dem.scheme = \"orb\"")
    expect(ctx, ["check", RISER, "dem.scheme=orb", "dem.nsubit=20", "output.interval=1e-6"], 0,
           r"warning: output.interval = 1e-06 s is shorter than the sub-iteration step dt_sp = "
           r"5e-06 s of dem.scheme = \"orb\"")
    quiet = expect(ctx, ["check", RISER, "dem.scheme=orb", "output.interval=1e-6", "fluid.dt=0"],
                   0, None)
    assert "sub-iteration step" not in quiet, quiet


@case
def unstable_step_is_a_configuration_error(ctx):
    expect(ctx, ["run", SMALL, "dem.dt_factor=1.5"], 2,
           r"scene key 'dem.dt_factor': unstable time step: omega dt", fresh=True)


@case
def particles_too_fast_at_an_outflow_face_stop(ctx):
    """gravity = 1e10 m/s^2 gives the bed's particles 724 m/s in their first half kick, 5 mm per
    particle step of 1.4e-7 s in a 5 mm column: the outflow face took all 10,000 of them out
    before the particle step could see the speed, and the run ended with exit 0 and no particles.
    A particle leaving faster than the particle step can follow stops the run, as the step's own
    check does (exit 3), naming it."""
    args = ["run", BED, "gravity=[0,-1e10,0]", "run.end_time=2e-4", "--quiet"]
    expect(ctx, args, 3,
           r"t = 0 s, leaving through an outflow face: particle 0 at \(5\.33333e-05, "
           r"5\.10638e-05, 5\.33333e-05\) m: speed 723\.6 m/s moves it more than the smallest "
           r"radius in one step \(dt = 1\.447e-07 s\): contacts could be missed \(tunnelling\)",
           out_dir=ctx.fresh("outflow_too_fast"))


@case
def drag_faster_than_the_fluid_step_refused_or_stopped(ctx):
    """The gas's drag on a particle is held over a fluid step with its velocity frozen, which
    reverses and grows the slip every step once dt_f is twice the drag time m / beta. A gas 5e4
    times as viscous in the bed (m / beta = 5.6e-7 s in still gas against fluid.dt = 1e-4 s) ran
    26 particle steps and stopped with words about the contact spring; particles of 0.5 kg/m^3
    (lighter than the gas) ran to the wall overlap stop. A fixed fluid.dt of twice the still-gas
    drag time is refused at set-up naming the key; one over it warns; the bed's dense drag
    (shorter than in still gas) stops the run at its first fluid step naming a particle."""
    expect(ctx, ["check", BED, "fluid.viscosity=1"], 2,
           r"scene key 'fluid.dt': 0.0001 s is 180 times the shortest drag time m / beta of a "
           r"particle in still gas, 5.56e-07 s \(the particles at the start; drag law \"koch_hill\", "
           r"fluid.viscosity = 1 Pa s\): the drag, held over a fluid step with the particle's velocity frozen, reverses "
           r"and grows its slip every step beyond twice the drag time")
    expect(ctx, ["run", BED, "particles.density=0.5", "run.end_time=2e-4", "--quiet"], 2,
           r"scene key 'fluid.dt': 0.0001 s is 7.2 times the shortest drag time", fresh=True)
    # The smallest particle an inlet adds counts too (it stopped the run at its first fluid step).
    expect(ctx, ["check", CFB, "inlet.mass_rate=1e-6", "inlet.recycle=false", "inlet.diameter=1e-6"],
           2, r"scene key 'fluid.dt': 0.0001 s is 36 times the shortest drag time m / beta of a "
           r"particle in still gas, 2.78e-06 s \(the smallest particle inlet.mass_rate adds; drag "
           r"law \"koch_hill\", fluid.viscosity = 2e-05 Pa s\).*check fluid.viscosity, "
           r"inlet.diameter and inlet.density")
    # 3 kg/m^3: 1.2 still-gas drag times (a warning), 10.6 of the lattice's dense drag.
    expect(ctx, ["run", BED, "particles.density=3", "run.end_time=2e-4", "--quiet"], 3,
           r"(?s)warning: fluid.dt = 0.0001 s is 1.2 times the shortest drag time m / beta of a "
           r"particle in still gas, 8.33e-05 s: the drag, held over a fluid step with the "
           r"particle's velocity frozen, overshoots.*"
           r"run stopped: t = 0 s, fluid step 1: particle 0 at \(5.33333e-05, 5.10638e-05, "
           r"5.33333e-05\) m: its drag time m / beta = 9.43e-06 s \(drag law \"koch_hill\", "
           r"eps_g 0.531\) is less than half the fluid step of 0.0001 s",
           out_dir=ctx.fresh("drag_stopped"))
    # The adaptive fluid step follows the drag time: no warning, no refusal. Particles lighter
    # than the gas have no minimum fluidization velocity (it was -1.5e-6 m/s, the inflow
    # -1e4 times it).
    quiet = expect(ctx, ["check", BED, "particles.density=0.5", "fluid.dt=0"], 0,
                   r"minimum_fluidization_velocity_m_s \(Wen & Yu\)\s+none: the particles "
                   r"\(0.5 kg/m\^3\) are no denser than the gas \(1 kg/m\^3\)")
    assert "drag time" not in quiet.split("# resolved")[0], quiet
    assert "inflow_velocity / U_mf" not in quiet, quiet


@case
def speeds_the_springs_cannot_stop_warn(ctx):
    """A spring stops a head-on impact within dem.max_overlap only below max_overlap r
    sqrt(k / m_eff): 2.93 m/s for two of the paper's particles at k = 10 N/m, 2.07 m/s for one
    on a wall. particles.velocity = [0, 0, 5] on the bed, or an inlet at 100 m/s, ran into the
    overlap stop with no word before; check lists the speeds and both warn."""
    out = expect(ctx, ["check", BED, "particles.velocity=[0,0,5]"], 0,
                 r"warning: particles.velocity moves the particles at 5 m/s toward a wall: the "
                 r"wall's spring stops the largest of them within dem.max_overlap = 0.3 only below "
                 r"2.07 m/s")
    assert re.search(r"impact_speed_held_m_s \(pair, dem.max_overlap\)\s+2.932\n"
                     r"impact_speed_held_m_s \(wall, dem.max_overlap\)\s+2.073\n", out), out
    expect(ctx, ["check", CFB, "inlet.velocity=[0,-100,0]"], 0,
           r"warning: inlet.velocity = 100 m/s: the spring stops a head-on impact of two of the "
           r"largest particles within dem.max_overlap = 0.3 only below 2.93 m/s")
    # Slower, or along periodic axes only (the riser's x): no warning.
    for scene, arg in ((BED, "particles.velocity=[0,0,2]"), (RISER, "particles.velocity=[5,0,0]")):
        quiet = expect(ctx, ["check", scene, arg], 0, None)
        assert "toward a wall" not in quiet, quiet


@case
def speeds_no_step_follows_stop_before_the_gas_step(ctx):
    """The gas step deposits the particles' drag before they take a step: a velocity of 1e300
    m/s on the bed stopped the run with "multigrid: the coarsest operator is not positive
    definite", a thermal speed of 5e4 m/s in hcs_gas with a drag time. A speed no particle step
    follows is named before the gas step, in the particle step's words, with the step it needs."""
    stops(ctx, BED, ["particles.velocity=[1e300,0,0]"],
          r"run stopped: t = 0 s, before fluid step 1: particle 0 at \(5.33333e-05, 5.10638e-05, "
          r"5.33333e-05\) m: speed 1e\+300 m/s moves it more than the smallest radius in one step "
          r"\(dt = 1.447e-07 s\): contacts could be missed \(tunnelling\); a step that follows it "
          r"is below 5e-305 s", "speed_1e300")
    stops(ctx, HCS_GAS, ["particles.temperature=1e9"],
          r"run stopped: t = 0 s, before fluid step 1: particle \d+ at .* m: speed \S+e\+04 m/s "
          r"moves it more than the smallest radius in one step", "speed_T")


@case
def overflowing_projection_names_the_cell(ctx):
    """fluid.outflow_pressure = 1e300 Pa puts 5e303 into the pressure equation's right-hand side,
    whose square overflows: the run stopped with "reached relative residual -nan after 0
    iterations". It names the cell, the terms and the outflow pressure."""
    stops(ctx, BED, ["fluid.outflow_pressure=1e300"],
          r"pressure projection: its equation overflows at gas cell \(0, 49, 0\) \(right-hand "
          r"side 5e\+303: .* next to an outflow face at 1e\+300 Pa \(fluid.outflow_pressure\)",
          "outflow_1e300")


@case
def elongated_cells_warn_and_a_stalled_projection_says_why(ctx):
    """fluid.cells = [1000, 1, 1] on the bed's column makes cells 6250 times longer than wide:
    check and run said nothing, and the run stopped with "reached relative residual 7.55e-10
    after 3 iterations", which reads as an iteration cap. Cells over 500:1 warn; a projection
    that stops making progress says so and names round-off and the cells' shape."""
    cells = "fluid.cells=[1000,1,1]"
    expect(ctx, ["check", BED, cells], 0,
           r"warning: fluid.cells makes gas cells of \[1.6e-06, 0.01, 0.0016\] m, the longest "
           r"side 6.25e\+03x the shortest", timeout=30)
    expect(ctx, ["run", BED, cells, "run.end_time=3e-4", "--quiet"], 3,
           r"multigrid-preconditioned CG stopped making progress at relative residual \S+ after "
           r"\d+ iterations \(tolerance 1e-10\): round-off holds the residual above the "
           r"tolerance \(the cells' longest side is 6.25e\+03x their shortest, the face "
           r"coefficients eps_g x mobility / dx\^2 span \S+x; cells nearer cubes, or a looser "
           r"fluid.tolerance, lower that floor\)", out_dir=ctx.fresh("elongated_cells"))
    # On cubic cells the coefficients' span is the cause: a gas of 1e-9 kg/m^3 under the
    # particles' drag spreads them 7e8-fold (it named the cells' shape, 1:1, as the cause).
    stops(ctx, HCS_GAS, ["fluid.density=1e-9"],
          r"stopped making progress at relative residual \S+ after \d+ iterations \(tolerance "
          r"1e-10\): round-off holds the residual above the tolerance \(the cells' longest side "
          r"is 1x their shortest, the face coefficients eps_g x mobility / dx\^2 span 7.12e\+08x; "
          r"a looser fluid.tolerance lowers that floor\)", "light_gas")


@case
def banner_and_summary_agree(ctx):
    """The orb banner's sub-iteration count is the summary's (which adds the one that completes
    the last row, and says so); a coupled orb banner names dt_sp and the fine dt."""
    out = expect(ctx, ["run", SMALL, "dem.scheme=orb", "run.end_time=2e-4"], 0,
                 r"dt_sp = 1.0000e-05 s \(fine dt = 1.4472e-07 s\), 20 sub-iterations",
                 out_dir=ctx.fresh("orb_banner"))
    assert re.search(r"for 21 sub-iterations with 100 particles \(20 to run.end_time and one "
                     r"that completes the last row\)", out), out
    expect(ctx, ["run", SETTLING, "particles.count=30", "dem.scheme=orb", "run.end_time=2e-4"],
           0, r"dt_f = 1.0000e-04 s, dt_sp = 1.0000e-05 s \(fine dt = 1.4472e-07 s\)",
           out_dir=ctx.fresh("orb_gas_banner"))


@case
def phase_other_not_negative(ctx):
    """run.json phase_seconds: with a gas, start() and the t = 0 outputs were timed in phases
    but fell before the loop's clock started, so 'other' (the loop's untimed rest) came out
    negative."""
    import json
    for sched in ("explicit", "orb"):
        d = ctx.fresh(f"phases_{sched}")
        expect(ctx, ["run", SETTLING, f"dem.scheme={sched}", "run.end_time=2e-4",
                     "output.snapshot_interval=1e-4", "--quiet"], 0, None, out_dir=d)
        with open(os.path.join(d, "run.json")) as f:
            ph = json.load(f)["phase_seconds"]
        assert ph["other"] >= 0, (sched, ph)


@case
def run_json_typed_and_done_line(ctx):
    import json
    d = ctx.fresh("typed")
    out = expect(ctx, ["run", SMALL, *TINY, "output.snapshot_interval=1e-5"], 0,
                 r"done; outputs in .* \(diagnostics.csv, run.json, 3 snapshot\(s\) \+ "
                 r"snapshots.xmf\)", out_dir=d)
    with open(os.path.join(d, "run.json")) as f:
        j = json.load(f)
    c = j["configuration"]
    assert c["name"] == "hcs_small" and c["dem.restitution"] == 0.8, c
    assert c["domain.periodic"] == [True, True, True] and c["particles.count"] == 100, c
    assert j["derived"]["dt_s"] == 1.447203e-07, j["derived"]


# ---- names cannot leave runs/ ----
@case
def name_dotdot(ctx):
    expect(ctx, ["run", SMALL, *TINY, "name=.."], 2, r"scene key 'name'.*plain name", cwd=ctx.tmp)
    assert not os.path.exists(os.path.join(ctx.tmp, "diagnostics.csv"))


@case
def name_absolute(ctx):
    expect(ctx, ["run", SMALL, *TINY, f"name={ctx.tmp}/evil"], 2, r"scene key 'name'")


@case
def name_with_slash(ctx):
    expect(ctx, ["run", SMALL, *TINY, "name=a/../../b"], 2, r"scene key 'name'")


@case
def name_with_control_characters(ctx):
    """A newline (or tab, escape, ...) in a name made a directory with a newline in its name."""
    for name in ("a\nb", "a\tb", "run\x1b[31m"):
        expect(ctx, ["run", SMALL, *TINY, f"name={name}"], 2,
               r"scene key 'name'.*without control characters", cwd=ctx.tmp)
        assert not os.path.exists(os.path.join(ctx.tmp, "runs")), os.listdir(ctx.tmp)


# ---- set-up: refused before placement when it cannot fit, memory of the particles ----
@case
def count_beyond_close_packing(ctx):
    expect(ctx, ["run", SMALL, "particles.count=1000000", "domain.hi=[1e-3,1e-3,1e-3]"], 2,
           r"'particles.count'.*random close packing", timeout=20)


@case
def close_packing_message_reads_right(ctx):
    """The refusal says the solid fraction asked, the limit 0.64 and how many particles fit (its
    format arguments were swapped: "fill 9.99e+03 times the region (solid fraction 0.64) ...
    9990.77 (about 0.64 particles here)"). 1e8 particles of 100 um in a 1.737 mm box ask for
    pi/6 1e-12 1e8 / 1.737e-3^3 = 9991; about 0.64 / 9991 x 1e8 = 6405 fit."""
    out = expect(ctx, ["check", SMALL, "particles.count=100000000"], 2,
                 r"'particles.count'.*ask for a solid fraction of 9.99e\+03 in the region; no "
                 r"packing holds more than random close packing, 0.64 \(about 640\d particles "
                 r"here\)", timeout=20)
    assert "times the region" not in out, out


@case
def count_beyond_random_placement(ctx):
    expect(ctx, ["run", SMALL, "particles.count=4000"], 2,
           r"random placement .* jams near 0.38.*particles.placement = \"lattice\"", timeout=20)


@case
def count_beyond_memory(ctx):
    expect(ctx, ["check", SMALL, "particles.count=1000000000000", "domain.hi=[10,10,10]"], 2,
           r"'particles.count'.*GB, more than this machine", timeout=20)


@case
def size_distribution_huge_count_refused_fast(ctx):
    """A size distribution with 1e10 particles drew every diameter before refusing (more than
    60 s): refused as fast as one size, whether the packing or the memory refuses it."""
    dist = "particles.diameter={distribution='uniform', min=5e-5, max=1e-4}"
    expect(ctx, ["check", SMALL, dist, "particles.count=10000000000"], 2,
           r"'particles.count'.*random close packing", timeout=10)
    expect(ctx, ["check", SMALL, dist, "particles.count=1000000000000", "domain.hi=[10,10,10]"],
           2, r"'particles.count'.*GB, more than this machine", timeout=10)


@case
def long_set_up_shows_progress(ctx):
    # 2000 particles (solid fraction 0.2) with a progress line due at every report.
    expect(ctx, ["check", SMALL, "particles.count=2000", "output.progress_seconds=1e-9"], 0,
           r"set-up \(random placement\): \d+ of 2000 particles placed")


@case
def big_dilute_box_memory(ctx):
    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))  # 1 GiB of address space
    expect(ctx, ["check", SMALL, "particles.count=1000", "domain.hi=[0.1,0.1,0.1]"], 0,
           r"particles\s+1000\b", preexec=limit)


# ---- run directories are never mixed ----
@case
def rerun_into_a_run_directory(ctx):
    expect(ctx, ["run", SMALL, *TINY, "particles.seed=7", "--quiet"], 2,
           r"holds the outputs of an earlier run .*--overwrite")


@case
def two_runs_into_one_directory(ctx):
    """Two runs into the same directory at once both exited 0, run.json from one and
    diagnostics.csv from the other. The run directory is locked while a run writes it: the
    second run exits 2 naming the directory, and the first finishes intact. Started together
    (the race is lost at the directory's creation) and one after the other (the second finds
    the lock; with --overwrite it would have removed the first run's files)."""
    import json
    import time
    def start(d, seed, *extra):  # about 3 s of run
        return subprocess.Popen([BIN, "run", SMALL, "run.end_time=0.5", f"particles.seed={seed}",
                                 "--quiet", "--out", d, *extra], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
    def intact(d, seed):
        with open(os.path.join(d, "run.json")) as f:
            assert json.load(f)["configuration"]["particles.seed"] == seed
        r = rows(d)
        assert abs(float(r[-1][0]) - 0.5) < 1e-6 and all(len(x) == len(r[0]) for x in r), r[-1]
    lock = r"concurrent\S*: another cfddem run is writing into this directory"
    d = ctx.fresh("concurrent_together")
    runs = {seed: start(d, seed) for seed in (3, 4)}
    outs = {seed: p.communicate(timeout=TIMEOUT)[0] for seed, p in runs.items()}
    codes = {seed: p.returncode for seed, p in runs.items()}
    assert sorted(codes.values()) == [0, 2], (codes, outs)
    winner = min(codes, key=codes.get)
    loser = max(codes, key=codes.get)
    assert re.search(lock, outs[loser]) or "holds the outputs of an earlier run" in outs[loser], \
        outs[loser]
    intact(d, winner)
    d = ctx.fresh("concurrent_after")
    first = start(d, 3)
    while not os.path.exists(os.path.join(d, "diagnostics.csv")) and first.poll() is None:
        time.sleep(0.01)
    second = start(d, 4, "--overwrite")
    out = second.communicate(timeout=TIMEOUT)[0]
    running = first.poll() is None
    assert first.wait(timeout=TIMEOUT) == 0, first.communicate()[0]
    assert second.returncode == 2 and re.search(lock, out), (second.returncode, out)
    assert running, "the first run ended before the second was refused: make it longer"
    intact(d, 3)


@case
def lock_released_when_a_run_is_killed(ctx):
    """The run directory's lock is the kernel's (flock): a run killed with SIGKILL leaves no stale
    lock behind, and the next run with --overwrite takes the directory."""
    import time
    d = ctx.fresh("killed_run")
    first = subprocess.Popen([BIN, "run", SMALL, "run.end_time=0.5", "--quiet", "--out", d],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while not os.path.exists(os.path.join(d, "diagnostics.csv")) and first.poll() is None:
        time.sleep(0.01)
    first.kill()
    first.wait(timeout=TIMEOUT)
    expect(ctx, ["run", SMALL, *TINY, "--quiet", "--overwrite"], 0, None, out_dir=d)


@case
def overwrite_removes_the_old_run(ctx):
    d = ctx.fresh("overwritten")
    shutil.copytree(ctx.precious, d)
    with open(os.path.join(d, "notes.txt"), "w") as f:
        f.write("mine\n")
    expect(ctx, ["run", SMALL, "run.end_time=1e-5", "particles.seed=7", "--quiet",
                 "--overwrite"], 0, None, out_dir=d)
    names = sorted(os.listdir(d))
    assert "notes.txt" in names, names  # not a run's output: left alone
    assert not any(n.startswith("checkpoint_") for n in names), names
    assert names.count("snapshots.xmf") == 0, names
    assert rows(d)[-1][0] != rows(ctx.precious)[-1][0]


@case
def output_directory_that_cannot_be_written(ctx):
    """An --out longer than the file system allows, through a file, or on a read-only file system
    started the run and stopped it with exit 3 ("filesystem error ..."): refused with exit 2
    before the run starts, naming the directory and why."""
    expect(ctx, ["run", SMALL, *TINY, "--out", os.path.join(ctx.tmp, "x" * 300)], 2,
           r"output directory .*: the name 'x{20}\.\.\.' is 300 characters long, more than the "
           r"255 the file system allows")
    deep = os.path.join(ctx.tmp, *(["d" * 200] * 25))
    expect(ctx, ["run", SMALL, *TINY, "--out", deep], 2,
           r"output directory .*: the path is \d+ characters long; with the run's file names it "
           r"would pass the system's limit of 4096")
    plain = ctx.file("plain_file", "not a directory\n")
    expect(ctx, ["run", SMALL, *TINY, "--out", os.path.join(plain, "run")], 2,
           r"plain_file' is a file, not a directory")
    if os.path.isdir("/proc/self"):  # writable to root by its mode, yet no directory is made
        expect(ctx, ["run", SMALL, *TINY, "--out", "/proc/no_such_dir/run"], 2,
               r"output directory '/proc/no_such_dir/run' .*(cannot be created|cannot be "
               r"written)")
    with tmpfs(ctx, "read_only", "ro,size=64k") as mnt:
        if mnt is None:
            print("  output_directory_that_cannot_be_written: no read-only tmpfs mount here (not "
                  "root?): its read-only part not run")
            return
        expect(ctx, ["run", SMALL, *TINY, "--out", os.path.join(mnt, "run")], 2,
               r"read_only' cannot be written: Read-only file system")


# ---- faults while running (exit 3, every earlier file intact) ----
@case
def rows_kept_when_a_run_stops(ctx):
    d = ctx.fresh("stopped")
    expect(ctx, ["run", HCS, "particles.file=", "particles.count=1", "particles.diameter=1e-4",
                 "particles.density=1000", "particles.velocity=[0.5,0,0]",
                 "domain.periodic=[false,true,true]", "particles.region_lo=[3.5e-3,0,0]",
                 "dem.wall_spring_constant=1e-3", "output.interval=1e-5", "run.end_time=1e-2",
                 "--quiet"], 3, r"overlap with a wall", out_dir=d)
    r = rows(d)
    assert len(r) == 1 + 73 and all(len(x) == len(r[0]) for x in r), len(r)


@contextlib.contextmanager
def tmpfs(ctx, name, options):
    """A tmpfs mounted with `options` at ctx.tmp/name for the block, unmounted after it; None
    where it cannot be mounted (needs root)."""
    mnt = os.path.join(ctx.tmp, name)
    os.makedirs(mnt)
    if subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", mnt],
                      capture_output=True).returncode != 0:
        yield None
        return
    try:
        yield mnt
    finally:
        subprocess.run(["umount", mnt])


def full_disk_run(ctx, d, preexec=None):
    return expect(ctx, ["run", SETTLING, "run.end_time=0.01", "output.snapshot_interval=1e-3",
                        "--quiet"], 3, None, out_dir=d, preexec=preexec)


def check_intact(d):
    names = sorted(os.listdir(d))
    assert not any(".tmp." in n for n in names), names
    snaps = [n for n in names if n.startswith("snapshot_")]
    assert snaps, names
    for n in snaps:
        with open(os.path.join(d, n), "rb") as f:
            assert f.read(8) == b"\x89HDF\r\n\x1a\n", n
    r = rows(d)
    assert len(r) >= 2 and all(len(x) == len(r[0]) for x in r), r
    with open(os.path.join(d, "snapshots.xmf")) as f:
        xmf = f.read()
    for n in snaps:
        assert n in xmf, n


@case
def disk_full(ctx):
    """A real full disk: a 200 KiB tmpfs (needs root and mount); else says so and is skipped."""
    with tmpfs(ctx, "tmpfs", "size=200k") as mnt:
        if mnt is None:
            print("  disk_full: cannot mount a tmpfs here (not root?); the file-size case covers "
                  "the same error path")
            return
        out = full_disk_run(ctx, os.path.join(mnt, "run"))
        assert "No space left on device" in out, out
        check_intact(os.path.join(mnt, "run"))


@case
def disk_full_two_ranks(ctx):
    """The same full tmpfs with 2 ranks (the snapshots written collectively with MPI-IO): exit 3
    naming the snapshot, no rank left waiting, earlier files intact."""
    if not shutil.which("mpirun"):
        print("  disk_full_two_ranks: no mpirun here: not run")
        return
    with tmpfs(ctx, "tmpfs2", "size=200k") as mnt:
        if mnt is None:
            print("  disk_full_two_ranks: no tmpfs mount here: not run")
            return
        d = os.path.join(mnt, "run")
        code, out = run_two_ranks(["run", SETTLING, "run.end_time=0.01",
                                   "output.snapshot_interval=1e-3", "--quiet", "--out", d],
                                  timeout=120)
        assert code == 3, (code, out[-1500:])
        assert re.search(r"run stopped: writing snapshot .* on 2 ranks failed", out), out[-1500:]
        check_intact(d)


@case
def file_size_limit(ctx):
    """Unprivileged: a 4 MiB file-size limit (SIGXFSZ ignored, so a write past it fails with
    EFBIG; Open MPI's start-up needs about that much) stops the run at its first snapshot, 4.5 MB
    with a 48^3 gas grid: exit 3 naming the file and the cause, no temporary file left, no crash
    in MPI_Finalize (the HDF5 flush failure used to end in SIGSEGV)."""
    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (4 << 20, 4 << 20))
    d = ctx.fresh("fsize")
    out = expect(ctx, ["run", SETTLING, "fluid.cells=[48,48,48]", "run.end_time=1e-3",
                       "output.snapshot_interval=1e-4", "--quiet"], 3,
                 r"snapshot_000000000\.h5.*File too large", out_dir=d, preexec=limit)
    names = os.listdir(d)
    assert not any(".tmp." in n for n in names), names
    assert rows(d)[0][0] == "time", names


def main():
    only = ARGS[ARGS.index("-k") + 1] if "-k" in ARGS else None
    if "--list" in ARGS:
        print("\n".join(c.__name__ for c in CASES))
        return 0
    tmp = tempfile.mkdtemp(prefix="cfddem_hostile_")
    failed = []
    try:
        ctx = Context(tmp)
        ran = 0
        for c in CASES:
            if only and only not in c.__name__:
                continue
            ran += 1
            try:
                c(ctx)
                print(f"ok    {c.__name__}")
            except AssertionError as e:
                failed.append(c.__name__)
                print(f"FAIL  {c.__name__}: {e}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"{ran - len(failed)} of {ran} hostile cases passed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

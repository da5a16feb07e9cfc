#!/usr/bin/python3
"""Render a particle snapshot (snapshot_<step>.h5 written by cfddem) to a PNG, particles coloured
by speed or kinetic energy, as the paper's figures: a 3-D scatter, or a slab projected on a plane.

  tools/render_snapshot.py runs/hcs/snapshot_000006910.h5 -o hcs.png
  tools/render_snapshot.py runs/hcs/snapshot_000006910.h5 --color kinetic_energy --view xy

With a gas (a coupled scene's snapshot holds the cells under /fluid), a planar view can show a
gas field averaged across the view under the particles:

  tools/render_snapshot.py runs/settling/snapshot_000013820.h5 --view xy --cells eps_g
"""
import argparse
import sys

import h5py
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


CELL_LABELS = {"eps_g": "gas volume fraction eps_g", "pressure": "gas pressure [Pa]",
               "gas_speed": "gas speed [m/s]"}


def read_cells(f, a):
    """Node coordinates (x, y, z) and the chosen cell field, shape (nz, ny, nx)."""
    if "fluid" not in f:
        sys.exit(f"{a.snapshot}: no cell data (/fluid): the scene has no gas")
    fl = f["fluid"]
    nodes = [fl[f"{c}_nodes"][()] for c in "xyz"]
    if a.cells == "gas_speed":
        field = np.linalg.norm(fl["gas_velocity"][()], axis=-1)
    else:
        field = fl[a.cells][()]
    return nodes, field


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("snapshot", help="snapshot_<step>.h5")
    ap.add_argument("-o", "--output", help="PNG path (default: the snapshot's name with .png)")
    ap.add_argument("--color", choices=["speed", "kinetic_energy"], default="speed")
    ap.add_argument("--view", choices=["3d", "xy", "xz", "yz"], default="3d",
                    help="3-D scatter or a projection on a plane (default 3d)")
    ap.add_argument("--log", action="store_true", help="logarithmic colour scale")
    ap.add_argument("--cells", choices=["eps_g", "pressure", "gas_speed"],
                    help="planar view of a coupled run: this gas field, averaged across the "
                         "view, drawn under the particles")
    ap.add_argument("--dpi", type=int, default=150)
    a = ap.parse_args()
    if a.cells and a.view == "3d":
        ap.error("--cells needs a planar view (--view xy, xz or yz)")

    with h5py.File(a.snapshot, "r") as f:
        if "particles/position" not in f:
            sys.exit(f"{a.snapshot}: not a cfddem snapshot (no /particles/position)")
        p = f["particles"]
        pos = p["position"][()]
        diam = p["diameter"][()]
        value = p[a.color][()]
        t = float(f.attrs.get("time", np.nan))
        step = int(f.attrs.get("step", -1))
        cells = read_cells(f, a) if a.cells else None
    n = len(pos)
    label = {"speed": "speed [m/s]", "kinetic_energy": "kinetic energy [J]"}[a.color]
    norm = None
    if a.log and n and np.any(value > 0):
        norm = matplotlib.colors.LogNorm(vmin=max(value[value > 0].min(), 1e-300), vmax=value.max())
        value = np.maximum(value, norm.vmin)

    fig = plt.figure(figsize=(6.4, 5.6))
    if a.view == "3d":
        ax = fig.add_subplot(projection="3d")
        # Marker area in points^2 roughly proportional to the particle's projected size.
        span = np.ptp(pos, axis=0).max() if n else 1.0
        size = (diam / max(span, 1e-300) * 300) ** 2 if n else []
        sc = ax.scatter(pos[:, 0], pos[:, 1], pos[:, 2], c=value, s=size, cmap="viridis",
                        norm=norm, depthshade=True, linewidths=0)
        ax.set_xlabel("x [m]"), ax.set_ylabel("y [m]"), ax.set_zlabel("z [m]")
    else:
        i, j = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}[a.view]
        ax = fig.add_subplot()
        if cells is not None:
            nodes, field = cells
            # Average across the view's normal; array axes are (z, y, x), so what is left is
            # (rows, columns) = (j, i).
            k = 3 - i - j
            plane = field.mean(axis=2 - k)
            mesh = ax.pcolormesh(nodes[i], nodes[j], plane, cmap="Greys_r", shading="flat")
            fig.colorbar(mesh, ax=ax, label=CELL_LABELS[a.cells], shrink=0.8, pad=0.12)
        order = np.argsort(value) if n else []
        span = np.ptp(pos, axis=0).max() if n else 1.0
        size = (diam / max(span, 1e-300) * 350) ** 2 if n else []
        if cells is not None and n:
            size = size / 9  # a third of the diameter, so the gas shows between the particles
        sc = ax.scatter(pos[order, i], pos[order, j], c=value[order],
                        s=size[order] if n else [], cmap="viridis", norm=norm, linewidths=0)
        ax.set_aspect("equal")
        ax.ticklabel_format(style="sci", scilimits=(-2, 2))
        ax.set_xlabel("xyz"[i] + " [m]"), ax.set_ylabel("xyz"[j] + " [m]")
    fig.colorbar(sc, ax=ax, label=label, shrink=0.8)
    ax.set_title(f"{n} particles, t = {t:.6g} s (step {step})")
    out = a.output or a.snapshot.rsplit(".", 1)[0] + ".png"
    fig.savefig(out, dpi=a.dpi, bbox_inches="tight")
    print(out)


if __name__ == "__main__":
    main()

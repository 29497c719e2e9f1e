"""Trace the bundled bead under the nozzle's face at one instant: the melt's speed by row
under the face's trailing half against the plane Couette-Poiseuille profile that carries a
full gap's flow, the pressure under the face, and the free surface's pressure against the
traction-free condition p = 2 mu n.D.n that its velocities ask for.

    python validation/strands/trace_face.py [--time-s 0.40] [--resolution standard] [--set KEY=VALUE]

Runs the print through the API to the given print time (about a minute at standard on 2
cores) and prints the figures validation/strands/README.md quotes ("Where the strand thins").
"""
import argparse

import numpy as np

from taichi_mex.core.state import FLUID, INLET, NOZZLE, PLATE, SOLID
from taichi_mex.options import RESOLUTION_PRESETS
from taichi_mex.sim.simulation import Simulation
from taichi_mex.spec import RunSpec


def state_at(time_s: float, resolution: str, changes: dict) -> dict:
    dx_mm = RESOLUTION_PRESETS[resolution]["run"]["spacing_mm"]
    spec = RunSpec.create("print", changes={"run.progress": False, "run.snapshots": False,
                                            "run.spacing_mm": dx_mm,
                                            "scene.until_s": time_s + 1e-4, **changes})
    sim = Simulation.from_spec(spec)
    got = {}

    class Grab:
        def update(self, t, dt, n):
            if not got and t >= time_s:
                st, s = sim.state, sim.solver
                got.update(t=t, x=(st.x.to_numpy()[:n] + st.origin_m) * 1e3, v=st.v.to_numpy()[:n],
                           phase=st.phase.to_numpy()[:n], k=s.dfsph.kappa.to_numpy()[:n],
                           flag=s.stokes.surface.flag.to_numpy()[:n], dx_mm=dx_mm,
                           kernel=sim.kernel, mu=sim.material.viscosity_pa_s,
                           rho0=sim.material.density_kg_m3, gap_mm=0.2)

        def close(self):
            pass

    sim.run(reporter=Grab())
    return got


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--time-s", type=float, default=0.40)
    ap.add_argument("--resolution", default="standard")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a run option, e.g. run.dfsph.stokes_surface_rows=traction")
    a = ap.parse_args()
    d = state_at(a.time_s, a.resolution, dict(kv.split("=", 1) for kv in a.set))
    x, v, ph, k = d["x"], d["v"], d["phase"], d["k"] * d["rho0"]
    noz = ph == NOZZLE
    vn = v[noz].mean(0)
    U = float(np.linalg.norm(vn[:2]))
    ux = vn[:2] / U
    cx, cy = x[noz, 0].mean(), x[noz, 1].mean()
    along = (x[:, 0] - cx) * ux[0] + (x[:, 1] - cy) * ux[1]   # + ahead of the axis
    across = -(x[:, 0] - cx) * ux[1] + (x[:, 1] - cy) * ux[0]
    g = d["gap_mm"]
    melt = ph == FLUID
    print(f"t = {d['t']:.4f} s, nozzle at {U * 1e3:.1f} mm/s, spacing {d['dx_mm']:.3g} mm")
    print("\nunder the face's trailing half (0.25-0.45 mm behind the axis, |across| < 0.1 mm):")
    print("row z mm | lab speed along / U | full-gap Couette-Poiseuille | plain Couette")
    sel = melt & (along > -0.45) & (along < -0.25) & (np.abs(across) < 0.1)
    carried = []
    for zl in np.arange(0.0, g, d["dx_mm"]):
        s = sel & (x[:, 2] >= zl) & (x[:, 2] < zl + d["dx_mm"])
        if not s.any():
            continue
        z = x[s, 2].mean() / g
        lab = float((v[s, :2] @ ux).mean() / U)
        full = 1.0 - ((1 - z) + 3 * z * (1 - z))  # backward: Couette with the face + a parabola
        carried.append(1.0 - lab)
        print(f"  {x[s, 2].mean():.3f} | {lab:+.3f} | {full:+.3f} | {z:+.3f}")
    print(f"  mean backward speed / U under it: {np.mean(carried):.2f} (a full gap's flow: 1.00, "
          "plain Couette: 0.50)")
    need = 6 * d["mu"] * U / (g * 1e-3) ** 2 * 0.3e-3
    print(f"\npressure a full gap's flow needs over the trailing face's 0.3 mm: {need / 1e6:.2f} MPa")
    print("pressure under the face (kPa), melt in the gap, 0.1 mm bins:")
    gap = melt & (x[:, 2] < g)
    for lo in np.arange(-0.5, 0.21, 0.1):
        row = []
        for c in np.arange(-0.35, 0.36, 0.1):
            s = gap & (along >= lo) & (along < lo + 0.1) & (across >= c - 0.05) & (across < c + 0.05)
            row.append(f"{k[s].mean() / 1e3:7.0f}" if s.any() else "      .")
        print(f"  along {lo + 0.05:+.2f} mm:", " ".join(row))
    # the free surface near the nozzle, clear of walls: pressure against 2 mu n.D.n from the
    # corrected velocity gradient (Bonet & Lok), n from the kernel sum's gradient
    K, dxm = d["kernel"], d["dx_mm"] * 1e-3
    H = K.H
    V = dxm**3
    xm = x * 1e-3
    fluid = (ph == FLUID) | (ph == INLET)
    walls = (ph == PLATE) | (ph == NOZZLE) | (ph == SOLID)
    xw = xm[walls]
    rows = []
    for i in np.where(melt & (d["flag"] == 1) & (np.abs(along) < 1.0))[0]:
        if (np.linalg.norm(xw - xm[i], axis=1) < H).any():
            continue
        r = xm[i] - xm[fluid]
        dist = np.linalg.norm(r, axis=1)
        s = (dist < H) & (dist > 0)
        gW = K.F_np(dist[s])[:, None] * r[s]
        M = (V * ((-r[s])[:, :, None] * gW[:, None, :])).sum(0)
        if abs(np.linalg.det(M)) < 1e-12:
            continue
        L = (V * ((v[fluid][s] - v[i])[:, :, None] * gW[:, None, :])).sum(0) @ np.linalg.inv(M)
        n = (V * gW).sum(0)
        n /= np.linalg.norm(n)
        rows.append((k[i], 2 * d["mu"] * n @ (0.5 * (L + L.T)) @ n))
    rows = np.array(rows)
    print(f"\nfree surface within 1 mm of the axis, clear of walls ({len(rows)} particles):")
    print(f"  pressure median {np.median(rows[:, 0]) / 1e3:.0f} kPa (5-95 %: "
          f"{np.percentile(rows[:, 0], 5) / 1e3:.0f} to {np.percentile(rows[:, 0], 95) / 1e3:.0f}); "
          f"2 mu n.D.n median {np.median(rows[:, 1]) / 1e3:.0f} kPa (5-95 %: "
          f"{np.percentile(rows[:, 1], 5) / 1e3:.0f} to {np.percentile(rows[:, 1], 95) / 1e3:.0f}); "
          f"correlation {np.corrcoef(rows[:, 0], rows[:, 1])[0, 1]:.2f}")


if __name__ == "__main__":
    main()

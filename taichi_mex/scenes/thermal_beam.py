"""The seed paper's thermal validation: a square aluminium beam that does not flow.

A beam 0.02 m x 0.02 m x 0.2 m (k = 237 W/m K, rho = 2700 kg/m^3, c = 897 J/kg K) starts
at T(z) = 2500 (z - 0.05)^2 + 150 degC (paper Eq. 9, z in m along the beam) and is compared
after 50 s along its centre line, (a) by conduction only, (b) also losing heat by
convection (h_c = 100 W/m^2 K) and radiation (eps = 1) to T_A = 20 degC on all six faces.
The paper's SPH model matched a finite-element model in (a) and lost far too much heat in
(b), because its eigenvalue rule overestimates the free surface.

References, our own:
(a) an insulated rod: T(z, t) = a_0 + sum_n a_n cos(n pi z / L) exp(-alpha (n pi / L)^2 t),
    alpha = k / (rho c), the a_n of Eq. 9 in closed form;
(b) a finite-volume solution of the 3D beam (a quarter of the cross-section by symmetry,
    explicit Euler), each boundary face losing h_c (T - T_A) + eps sigma (T^4 - T_A^4).
"""

import math
from dataclasses import asdict, dataclass

import numpy as np

from taichi_mex.physics.thermal import STEFAN_BOLTZMANN, diffusion_dt_s
from taichi_mex.core.state import SOLID
from taichi_mex.options import Flag, Positive, Range, opt
from taichi_mex.scenes.registry import SceneEntry, register
from taichi_mex.scenes.base import ParticleBlock, ScenePlan, lattice_block

#: paper values (Sec. "Validation of the Thermal Model")
ALUMINIUM = {"name": "aluminium", "density_kg_m3": 2700.0, "specific_heat_j_kgk": 897.0,
             "conductivity_w_mk": 237.0, "emissivity": 1.0, "viscosity_model": "newtonian"}
PAPER_LOSSES = {"convection_w_m2k": 100.0, "radiation_emissivity": 1.0, "ambient_c": 20.0}
KELVIN = 273.15


def initial_temperature_c(z_m):
    """Paper Eq. 9."""
    z = np.asarray(z_m, dtype=np.float64)
    return 2500.0 * (z - 0.05) ** 2 + 150.0


def analytic_conduction_c(z_m, t_s: float, alpha_m2_s: float, length_m: float,
                          terms: int = 400) -> np.ndarray:
    """Insulated rod of length L from T0 = A (z - z0)^2 + B (Eq. 9): cosine series with
    a_n = (2/L) int_0^L T0 cos(k z) dz = 4 A / (L k^2) [(L - z0)(-1)^n + z0], k = n pi / L."""
    A, z0, B = 2500.0, 0.05, 150.0
    L = float(length_m)
    z = np.asarray(z_m, dtype=np.float64)
    T = np.full_like(z, B + A * ((L - z0) ** 3 + z0**3) / (3.0 * L))
    for n in range(1, terms + 1):
        k = n * math.pi / L
        a_n = 4.0 * A / (L * k * k) * ((L - z0) * (-1) ** n + z0)
        T += a_n * np.cos(k * z) * math.exp(-alpha_m2_s * k * k * t_s)
    return T


def finite_volume_beam_c(z_m, t_s: float, width_m: float, length_m: float,
                         conductivity_w_mk: float, density_kg_m3: float,
                         specific_heat_j_kgk: float, convection_w_m2k: float = 0.0,
                         emissivity: float = 0.0, ambient_c: float = 20.0,
                         cells_half_width: int = 10, cells_along: int = 200) -> np.ndarray:
    """Axis temperature (degC) of the beam at t_s on points z_m: a finite-volume solution on
    a quarter of the cross-section (mirror faces on the axis planes), cell-centred,
    explicit Euler at 0.9 of its stability limit. Losses leave through every outer face of
    the boundary cells, so the beam's edges and corners lose through two and three faces."""
    nx = int(cells_half_width)
    nz = int(cells_along)
    dx = 0.5 * width_m / nx
    dz = length_m / nz
    k, rc = conductivity_w_mk, density_kg_m3 * specific_heat_j_kgk
    zc = (np.arange(nz) + 0.5) * dz
    T = np.broadcast_to(initial_temperature_c(zc), (nx, nx, nz)).copy()
    Ta = ambient_c + KELVIN
    # explicit limit: conduction, plus the linearised loss of a corner cell (three faces)
    h_lin = convection_w_m2k + 4.0 * emissivity * STEFAN_BOLTZMANN * (T.max() + KELVIN) ** 3
    rate = 2.0 * k / rc * (2.0 / dx**2 + 1.0 / dz**2) + h_lin / rc * (2.0 / dx + 1.0 / dz)
    steps = max(int(math.ceil(t_s * rate / 0.9)), 1)
    dt = t_s / steps
    for _ in range(steps):
        q = np.zeros_like(T)  # heat into each cell, W/m^3
        fx = k * np.diff(T, axis=0) / dx  # interior faces, W/m^2 in +x
        q[:-1] += fx / dx
        q[1:] -= fx / dx
        fy = k * np.diff(T, axis=1) / dx
        q[:, :-1] += fy / dx
        q[:, 1:] -= fy / dx
        fz = k * np.diff(T, axis=2) / dz
        q[:, :, :-1] += fz / dz
        q[:, :, 1:] -= fz / dz
        if convection_w_m2k > 0 or emissivity > 0:
            def loss(Tc):
                return convection_w_m2k * (Tc - ambient_c) + emissivity * STEFAN_BOLTZMANN * (
                    (Tc + KELVIN) ** 4 - Ta**4)
            q[-1] -= loss(T[-1]) / dx
            q[:, -1] -= loss(T[:, -1]) / dx
            q[:, :, 0] -= loss(T[:, :, 0]) / dz
            q[:, :, -1] -= loss(T[:, :, -1]) / dz
        T += dt * q / rc
    # the cross-section profile is even about the axis: a + b x^2 through the two cells
    # nearest the axis, in x and in y
    axis = T[0, 0] - (T[1, 0] - T[0, 0]) / 8.0 - (T[0, 1] - T[0, 0]) / 8.0 if nx > 1 else T[0, 0]
    return np.interp(np.asarray(z_m, dtype=np.float64), zc, axis)


class ThermalBeamScene:
    """The beam (or any box: ``width_mm`` x ``width_mm`` x ``length_mm``) as solid particles
    on the static scheme; ``reference_cells`` sets the finite-volume grid for case (b)."""

    name = "thermal-beam"

    def __init__(self, width_mm: float = 20.0, length_mm: float = 200.0, until_s: float = 50.0,
                 centerline_points: int = 201, reference_cells: tuple = (5, 100), losses: bool = True):
        # losses: what the scene implies for the run's heat options (_defaults), kept here so
        # that config.json names the case
        self.options = ThermalBeamOptions(width_mm, length_mm, until_s, losses, centerline_points)
        self.width_m = width_mm * 1e-3
        self.length_m = length_mm * 1e-3
        self.until_s = float(until_s)
        self.points = int(centerline_points)
        self.reference_cells = tuple(reference_cells)
        self._result = None

    def plan(self, run, material) -> ScenePlan:
        from taichi_mex.core.kernels import Kernel

        dx = run.spacing_m
        lo = np.zeros(3)
        hi = np.array([self.width_m, self.width_m, self.length_m])
        beam = lattice_block(lo, hi, dx)
        kind, factor = run.resolved_kernel()
        pad = (factor + 2) * dx
        dt = diffusion_dt_s(Kernel(kind, factor * dx), dx, material.conductivity_w_mk,
                            material.density_kg_m3, material.specific_heat_j_kgk, wall_contact=False)
        self._result = None
        return ScenePlan(
            name=self.name, domain_lo_m=lo - pad, domain_hi_m=hi + pad,
            t_start_s=0.0, t_end_s=self.until_s,
            blocks=[ParticleBlock(beam, SOLID, temperature_c=initial_temperature_c(beam[:, 2]))],
            needs={"thermal"},
            section_point_m=0.5 * (lo + hi), section_direction=np.array([0.0, 0.0, 1.0]),
            max_dt_s=1.0, thermal_dt_s=dt, speed_scale_m_s=0.0,
            info={"beam_width_m": self.width_m, "beam_length_m": self.length_m},
        )

    # ------------------------------------------------------------------ analysis
    def centerline(self, sim) -> tuple[np.ndarray, np.ndarray]:
        """(z, T) on the beam axis: kernel-weighted (Shepard) interpolation of the particle
        temperatures at ``centerline_points`` points from end to end."""
        x = sim.state.numpy("position", SOLID)
        T = sim.state.numpy("temperature", SOLID).astype(np.float64)
        z = np.linspace(0.0, self.length_m, self.points)
        probe = np.zeros((len(z), 3))
        probe[:, 0] = probe[:, 1] = 0.5 * self.width_m
        probe[:, 2] = z
        out = np.empty(len(z))
        for k, p in enumerate(probe):
            w = sim.kernel.W_np(np.linalg.norm(x - p, axis=1))
            out[k] = (w * T).sum() / w.sum()
        return z, out

    def reference(self, sim, z) -> tuple[np.ndarray, str]:
        th = sim.run_opts.thermal
        mat = sim.material
        eps = th.radiation_emissivity or 0.0
        if th.convection_w_m2k <= 0 and eps <= 0:
            alpha = mat.conductivity_w_mk / (mat.density_kg_m3 * mat.specific_heat_j_kgk)
            return analytic_conduction_c(z, sim.time_s, alpha, self.length_m), "analytic series"
        nx, nz = self.reference_cells
        T = finite_volume_beam_c(z, sim.time_s, self.width_m, self.length_m, mat.conductivity_w_mk,
                                 mat.density_kg_m3, mat.specific_heat_j_kgk, th.convection_w_m2k,
                                 eps, th.ambient_c, nx, nz)
        return T, f"finite volume {2 * nx}x{2 * nx}x{nz}"

    def analyse(self, sim) -> dict:
        if self._result is not None and self._result["time_s"] == sim.time_s:
            return self._result["summary"]
        z, T = self.centerline(sim)
        ref, name = self.reference(sim, z)
        err = T - ref
        area = float(sim.thermal.free_surface_areas().sum())
        true_area = 2.0 * self.width_m**2 + 4.0 * self.width_m * self.length_m
        summary = {"thermal_error_max_c": float(np.abs(err).max()),
                   "thermal_error_rms_c": float(np.sqrt(np.mean(err**2))),
                   "thermal_error_mean_c": float(err.mean()),
                   "thermal_reference": name,
                   "centerline_points": len(z),
                   "surface_area_sum_m2": area, "surface_area_true_m2": true_area,
                   "surface_area_ratio": area / true_area}
        self._result = {"time_s": sim.time_s, "summary": summary, "z": z, "T": T, "ref": ref}
        return summary

    def write_outputs(self, sim, out_dir) -> None:
        s = self.analyse(sim)
        r = self._result
        lines = ["z_m,T_C"] + [f"{z:.6g},{t:.6g}" for z, t in zip(r["z"], r["T"])]
        (out_dir / "centerline.csv").write_text("\n".join(lines) + "\n")
        lines = ["z_m,T_C"] + [f"{z:.6g},{t:.6g}" for z, t in zip(r["z"], r["ref"])]
        (out_dir / "reference.csv").write_text("\n".join(lines) + "\n")
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        th = sim.run_opts.thermal
        fig, ax = plt.subplots(figsize=(6.5, 4))
        ax.plot(r["z"], initial_temperature_c(r["z"]), ":", color="0.5", label="initial (Eq. 9)")
        ax.plot(r["z"], r["ref"], "-", color="k", label=s["thermal_reference"])
        ax.plot(r["z"], r["T"], "o", ms=3, label=f"SPH, {th.surface_method}" if sim.thermal.losses else "SPH")
        ax.set_xlabel("z [m]")
        ax.set_ylabel("T on the centre line [degC]")
        losses = (f"h_c = {th.convection_w_m2k:g} W/m^2K, eps = {th.radiation_emissivity or 0:g}"
                  if sim.thermal.losses else "conduction only")
        ax.set_title(f"aluminium beam, t = {sim.time_s:g} s, {losses}\nspacing "
                     f"{sim.run_opts.spacing_mm:g} mm: max error {s['thermal_error_max_c']:.2f} K",
                     fontsize=9)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out_dir / "centerline.png", dpi=120)
        plt.close(fig)


@dataclass
class ThermalBeamOptions:
    width_mm: float = opt(20.0, help="beam width and depth (mm)", check=Positive())
    length_mm: float = opt(200.0, help="beam length (mm)", check=Positive())
    until_s: float = opt(50.0, help="simulated time (s)", check=Positive(), flag="--until",
                         names=("until",))
    losses: bool = opt(True, help="the paper's convection and radiation (case b); off: "
                       "conduction only (case a)", check=Flag(), flag="--no-losses", const=False,
                       flag_help="conduction only (case a)")
    centerline_points: int = opt(201, help="points on the axis the error is taken at",
                                 check=Range(2, 100000, integer=True))


def _defaults(options) -> dict:
    thermal = {"enabled": True}
    if options.losses:
        thermal.update(PAPER_LOSSES)
    else:
        thermal.update(convection_w_m2k=0.0, radiation_emissivity=None)
    return {"run": {"scheme": "static", "spacing_mm": 2.0, "thermal": thermal,
                    "snapshot_field": "temperature"},
            "material": dict(ALUMINIUM)}


register(SceneEntry("thermal-beam", "the seed paper's aluminium beam: heat conduction and surface "
                    "losses against an analytic / finite-volume reference", ThermalBeamOptions,
                    lambda o: ThermalBeamScene(**asdict(o)), _defaults))

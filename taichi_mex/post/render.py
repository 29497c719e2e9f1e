"""Off-screen pyvista snapshots: side, top and a cross-section normal to the extrusion."""

import os
from pathlib import Path

import numpy as np

from taichi_mex.post.output import UNITS

LABELS = {"density": "density", "pressure": "pressure", "temperature": "temperature",
          "velocity": "speed", "bead_id": "bead", "phase": "phase", "viscosity": "viscosity",
          "surface_area": "surface area"}


def _pyvista():
    os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
    if not os.environ.get("DISPLAY"):
        # headless: go straight to EGL instead of failing on X first (and warning about it)
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv

    pv.OFF_SCREEN = True
    return pv


def _scalars(data: dict, field: str) -> np.ndarray:
    value = data[field]
    if value.ndim == 2:
        return np.linalg.norm(value, axis=1)
    return value


def snapshot_set(data: dict, out_dir: Path, tag: str, field: str, spacing_m: float,
                 section_point_m=None, section_direction=None, plate=None, clim=None) -> list[Path]:
    """Write side/top/section PNGs of one frame coloured by ``field``; returns the paths."""
    pv = _pyvista()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if field not in data:
        raise KeyError(f"field {field!r} not in frame (have {', '.join(sorted(data))})")
    melt = data["phase"] <= 1
    pos = data["position"][melt] * 1e3  # mm for readable axes
    if len(pos) == 0:
        return []
    values = _scalars(data, field)[melt]
    unit = UNITS.get(field, "")
    title = f"{LABELS.get(field, field)} [{unit}]" if unit and unit != "1" else LABELS.get(field, field)
    if clim is None:
        lo, hi = np.percentile(values, [1, 99]) if len(values) > 10 else (values.min(), values.max())
        clim = (float(lo), float(hi) if hi > lo else float(lo) + 1e-12)
    radius_px = 6
    paths = []
    direction = np.array([1.0, 0.0, 0.0]) if section_direction is None else np.asarray(section_direction, float)
    direction = direction / np.linalg.norm(direction)
    side = np.cross(direction, [0, 0, 1])
    if np.linalg.norm(side) < 1e-6:  # a vertical direction (the beam scene): look along -y
        side = np.array([0.0, -1.0, 0.0])
    views = {"side": (side, [0, 0, 1]), "top": ([0, 0, 1], np.array([0, 1, 0]))}
    for name, (normal, up) in views.items():
        paths.append(_render(pv, pos, values, out_dir / f"{tag}_{name}.png", title, clim,
                             np.asarray(normal, float), up, radius_px, plate))
    if section_point_m is not None:
        centre = np.asarray(section_point_m, float) * 1e3
        slab = np.abs((pos - centre) @ direction) < 0.75 * spacing_m * 1e3
        section_up = [0, 1, 0] if abs(direction[2]) > 0.9 else [0, 0, 1]
        if slab.any():
            # seen from +direction (the printed bead coming towards the viewer), so that the
            # in-plane axis increases to the right, as in the analysis' section plots
            paths.append(_render(pv, pos[slab], values[slab], out_dir / f"{tag}_section.png",
                                 title, clim, direction, section_up, radius_px + 4, None,
                                 parallel=True))
    return paths


def _render(pv, pos, values, path, title, clim, view_normal, up, point_px, plate, parallel=True):
    cloud = pv.PolyData(pos)
    cloud["v"] = values
    pl = pv.Plotter(off_screen=True, window_size=(1000, 700))
    pl.set_background("white")
    pl.add_mesh(cloud, scalars="v", clim=clim, cmap="viridis", render_points_as_spheres=True,
                point_size=point_px, scalar_bar_args={"title": title, "color": "black",
                                                      "vertical": False, "fmt": "%.4g"})
    if plate is not None and len(plate):
        # the plate surface under the melt only, as a thin grey strip (context, not data)
        lo, hi = pos.min(axis=0), pos.max(axis=0)
        pad = 0.1 * float(np.ptp(pos[:, :2], axis=0).max() or 1.0)
        strip = pv.Box(bounds=(lo[0] - pad, hi[0] + pad, lo[1] - pad, hi[1] + pad,
                               -0.02 * (hi[2] - lo[2] + 1e-3), 0.0))
        pl.add_mesh(strip, color="lightgray", opacity=0.6)
    pl.show_bounds(color="black", xtitle="x [mm]", ytitle="y [mm]", ztitle="z [mm]", font_size=10,
                   fmt="%.3g")  # the default one decimal repeats labels on sub-mm beads
    centre = pos.mean(axis=0)
    span = float(np.ptp(pos, axis=0).max()) or 1.0
    pl.camera.focal_point = centre
    pl.camera.position = centre + view_normal / np.linalg.norm(view_normal) * span * 3
    pl.camera.up = up
    if parallel:
        pl.enable_parallel_projection()
    pl.reset_camera()
    pl.screenshot(str(path))
    pl.close()
    return path

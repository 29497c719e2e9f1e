"""Pictures of a run, off-screen: side, top and oblique views of the melt drawn at its real
particle size, with the build plate and the nozzle for context (pyvista); the particles near
a cross-section as discs (matplotlib); and an animation of the saved frames (imageio: MP4
with its packaged ffmpeg, a GIF where no encoder is available).

Colour ranges are per field and say what they show: density spans rho0 +-5 % (the
free-surface particles' summation density reads low by construction and saturates; a
diverging map with rho0 white),
temperature the plate-to-nozzle range, speed 0 to its 99th percentile."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from taichi_mex.post.output import UNITS

log = logging.getLogger("taichi_mex")

LABELS = {"density": "density", "pressure": "pressure", "temperature": "temperature",
          "velocity": "speed", "bead_id": "bead", "phase": "phase", "viscosity": "viscosity",
          "surface_area": "surface area"}
#: phases drawn as melt (fluid, solidified, the column in the bore) and as the nozzle
MELT_PHASES = (0, 1, 4)
NOZZLE_PHASE = 3
WINDOW_WIDTH_PX = 1200


def _pyvista():
    os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
    if not os.environ.get("DISPLAY"):
        # headless: go straight to EGL instead of failing on X first (and warning about it)
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv

    pv.OFF_SCREEN = True
    return pv


def scalars(data: dict, field: str) -> np.ndarray:
    value = data[field]
    return np.linalg.norm(value, axis=1) if value.ndim == 2 else value


def title(field: str) -> str:
    unit = UNITS.get(field, "")
    unit = {"m/s": "mm/s"}.get(unit, unit)
    name = LABELS.get(field, field)
    return f"{name} [{unit}]" if unit and unit != "1" and "," not in unit else name


def display_values(field: str, values: np.ndarray) -> np.ndarray:
    """Speeds in mm/s (a bead moves at tens of mm/s); everything else as stored."""
    return values * 1e3 if field == "velocity" else values


def colour_range(field: str, values: np.ndarray, reference: dict | None = None) -> tuple[float, float]:
    ref = reference or {}
    if field == "density" and ref.get("density_kg_m3"):
        rho0 = ref["density_kg_m3"]
        return 0.95 * rho0, 1.05 * rho0
    if field == "temperature" and ref.get("temperature_range_c"):
        lo, hi = ref["temperature_range_c"]
        return float(lo), float(hi)
    if len(values) == 0:
        return 0.0, 1.0
    if field in ("velocity", "surface_area"):
        lo, hi = 0.0, float(np.percentile(values, 99))
    elif field in ("phase", "bead_id"):
        lo, hi = float(values.min()), float(values.max())
    else:
        lo, hi = (float(v) for v in np.percentile(values, [1, 99]))
    return lo, hi if hi > lo else lo + 1e-12


# ----------------------------------------------------------------------------- views
def _cmap(field: str) -> str:
    # density: a diverging map centred on rho0, so compression and the free surface's
    # deficit read as opposite colours and the rest-state melt as white
    return "coolwarm" if field == "density" else "viridis"


def _melt_bounds(points_mm: np.ndarray, spacing_mm: float) -> np.ndarray:
    """What a picture frames: the melt, down to the plate, with a margin of 1.5 spacings."""
    lo, hi = points_mm.min(axis=0), points_mm.max(axis=0)
    lo[2] = min(lo[2], 0.0)
    pad = 1.5 * spacing_mm
    return np.array([lo - pad, hi + pad])


def _dominant_positive(v: np.ndarray) -> np.ndarray:
    return v if v[int(np.argmax(np.abs(v)))] >= 0 else -v


def _view_axes(view: str, direction) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(camera normal, up, screen right) of a view; right runs along increasing world
    coordinates where it can, so that the axes read like a drawing."""
    d = np.array([1.0, 0.0, 0.0]) if direction is None else np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    if abs(d[2]) > 0.9:  # a vertical direction (the beam scene)
        d = np.array([1.0, 0.0, 0.0])
    d = _dominant_positive(np.array([d[0], d[1], 0.0]) / np.linalg.norm(d[:2]))
    if view == "side":
        right, up = d, z
    elif view == "top":
        right, up = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    else:  # oblique: from the front-left, above
        lateral = np.cross(z, d)
        normal = -lateral - 0.6 * d + 0.9 * z
        normal /= np.linalg.norm(normal)
        up = z - np.dot(z, normal) * normal
        up /= np.linalg.norm(up)
        return normal, up, np.cross(up, normal)
    return np.cross(right, up), up, right


def _axis_label(v: np.ndarray, fallback: str) -> tuple[str, int | None]:
    k = int(np.argmax(np.abs(v)))
    if abs(v[k]) > 0.999:
        return f"{'xyz'[k]} [mm]", k
    return fallback, None


def raster(pv, data: dict, field: str, view: str, bounds: np.ndarray, spacing_mm: float,
           clim, direction=None) -> tuple[np.ndarray, dict]:
    """An RGB image of the melt at its real particle size (parallel projection), the nozzle
    in translucent grey and the plate as a grey slab, and the image's world frame."""
    normal, up, right = _view_axes(view, direction)
    corners = np.array([[bounds[i, 0], bounds[j, 1], bounds[k, 2]]
                        for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    w = float(np.ptp(corners @ right)) or 1.0
    h = float(np.ptp(corners @ up)) or 1.0
    width = WINDOW_WIDTH_PX
    height = int(np.clip(width * h / w, 240, 900))
    scale = 0.5 * max(h, w * height / width) * 1.04  # half the visible height, mm
    centre = 0.5 * (bounds[0] + bounds[1])
    pos = data["position"] * 1e3
    phase = data["phase"]
    melt = np.isin(phase, MELT_PHASES)
    pl = pv.Plotter(off_screen=True, window_size=(width, height))
    pl.set_background("white")
    point_px = max(spacing_mm * height / (2.0 * scale), 2.0)
    if melt.any():
        cloud = pv.PolyData(pos[melt])
        cloud["v"] = display_values(field, scalars(data, field)[melt])
        pl.add_mesh(cloud, scalars="v", clim=clim, cmap=_cmap(field), render_points_as_spheres=True,
                    point_size=point_px, show_scalar_bar=False)
    near = np.all((pos >= bounds[0] - 5 * spacing_mm) & (pos <= bounds[1] + 5 * spacing_mm), axis=1)
    nozzle = (phase == NOZZLE_PHASE) & near
    if nozzle.any():
        pl.add_mesh(pv.PolyData(pos[nozzle]), color="dimgray", opacity=0.3,
                    render_points_as_spheres=True, point_size=point_px)
    pl.add_mesh(pv.Box(bounds=(bounds[0, 0], bounds[1, 0], bounds[0, 1], bounds[1, 1],
                               -spacing_mm, 0.0)), color="lightgray")
    ext = float(np.ptp(bounds, axis=0).max())
    pl.enable_parallel_projection()
    pl.camera.focal_point = centre
    pl.camera.position = centre + normal * 10 * ext
    pl.camera.up = up
    pl.camera.parallel_scale = scale
    pl.camera.clipping_range = (1e-3 * ext, 30 * ext)
    img = pl.screenshot(return_img=True)
    pl.close()
    half_w = scale * width / height
    u0, v0 = float(centre @ right), float(centre @ up)
    return img, {"right": right, "up": up, "extent": (u0 - half_w, u0 + half_w, v0 - scale, v0 + scale)}


def compose(img: np.ndarray, frame: dict, field: str, clim, caption: str, path=None, view="side"):
    """The raster in a matplotlib figure: axes in mm where the view is axis-aligned, the
    colour bar with units; saved to ``path`` or returned as an RGB array."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    h_px, w_px = img.shape[:2]
    fig_w = 9.0
    fig, ax = plt.subplots(figsize=(fig_w, max(2.6, fig_w * h_px / w_px * 0.82 + 0.9)))
    u0, u1, v0, v1 = frame["extent"]
    if view == "oblique":
        ax.imshow(img)
        ax.set_axis_off()
    else:
        xlabel, kx = _axis_label(frame["right"], "along the bead [mm]")
        ylabel, ky = _axis_label(frame["up"], "[mm]")
        ax.imshow(img, extent=(u0, u1, v0, v1), aspect="equal", interpolation="antialiased")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.locator_params(nbins=6)
    fig.colorbar(ScalarMappable(Normalize(*clim), _cmap(field)), ax=ax, label=title(field),
                 shrink=0.85, pad=0.02)
    ax.set_title(caption, fontsize=10)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=130)
        plt.close(fig)
        return path
    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return rgb


def render_section(data: dict, field: str, path: Path, point_m, direction, spacing_m: float,
                   clim, caption: str = "") -> Path | None:
    """A cross-section: the melt within one spacing of the plane through ``point_m`` normal
    to ``direction``, each particle drawn as a disc of one spacing's diameter (nearest on
    top), the nozzle's particles grey."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import EllipseCollection

    direction = np.asarray(direction, float) / np.linalg.norm(direction)
    lateral = np.cross([0.0, 0.0, 1.0], direction)
    vertical = np.array([0.0, 0.0, 1.0])
    if np.linalg.norm(lateral) < 1e-6:
        lateral, vertical = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    lateral /= np.linalg.norm(lateral)
    pos = data["position"]
    d = (pos - np.asarray(point_m, float)) @ direction
    slab = np.abs(d) < spacing_m
    melt = slab & np.isin(data["phase"], MELT_PHASES)
    if not melt.any():
        return None
    u = (pos @ lateral) * 1e3
    v = (pos @ vertical) * 1e3
    h = 0.5 * spacing_m * 1e3
    fig, ax = plt.subplots(figsize=(7.5, 4.2))

    def discs(sel, **style):
        return EllipseCollection(2 * h, 2 * h, 0.0, units="xy", offsets=np.stack([u[sel], v[sel]], 1),
                                 offset_transform=ax.transData, **style)

    order = np.flatnonzero(melt)[np.argsort(-np.abs(d[melt]))]  # farthest first: nearest on top
    coll = discs(order, array=display_values(field, scalars(data, field)[order]),
                 cmap=_cmap(field), edgecolors="0.3", linewidths=0.3)
    coll.set_clim(*clim)
    ax.add_collection(coll)
    nozzle = slab & (data["phase"] == NOZZLE_PHASE)
    if nozzle.any():
        ax.add_collection(discs(nozzle, facecolors="0.55", edgecolors="none"))
    lo_u, hi_u = u[melt].min() - 4 * h, u[melt].max() + 4 * h
    top = v[melt].max() + 4 * h
    ax.axhspan(v[melt].min() - 6 * h if vertical[2] < 0.5 else -6 * h, 0.0 if vertical[2] > 0.5 else v[melt].min() - 2 * h,
               color="0.85", zorder=-1)
    ax.set_xlim(lo_u, hi_u)
    ax.set_ylim(min(-4 * h, v[melt].min() - 4 * h) if vertical[2] > 0.5 else v[melt].min() - 4 * h, top)
    ax.set_aspect("equal")
    ax.set_xlabel("across the bead [mm]")
    ax.set_ylabel("z [mm]" if vertical[2] > 0.5 else "[mm]")
    fig.colorbar(coll, ax=ax, label=title(field), shrink=0.8)
    ax.set_title(caption, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)
    return path


def snapshot_set(data: dict, out_dir: Path, tag: str, field: str, spacing_m: float,
                 section_point_m=None, section_direction=None, reference: dict | None = None,
                 time_s: float | None = None) -> list[Path]:
    """Side, top and oblique views and the section's particles of one frame, coloured by
    ``field``; returns the paths."""
    if field not in data:
        raise KeyError(f"field {field!r} not in frame (have {', '.join(sorted(data))})")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    melt = np.isin(data["phase"], MELT_PHASES)
    if not melt.any():
        return []
    pv = _pyvista()
    spacing_mm = spacing_m * 1e3
    clim = colour_range(field, display_values(field, scalars(data, field)[melt]), reference)
    bounds = _melt_bounds(data["position"][melt] * 1e3, spacing_mm)
    when = "" if time_s is None else f", t = {time_s:.4g} s"
    paths = []
    for view in ("side", "top", "oblique"):
        img, frame = raster(pv, data, field, view, bounds, spacing_mm, clim, section_direction)
        paths.append(compose(img, frame, field, clim, f"{view} view{when}",
                             out_dir / f"{tag}_{view}.png", view))
    if section_point_m is not None:
        section = render_section(data, field, out_dir / f"{tag}_section.png", section_point_m,
                                 section_direction if section_direction is not None else [1, 0, 0],
                                 spacing_m, clim, f"particles within one spacing of the section{when}")
        if section is not None:
            paths.append(section)
    return paths


def write_animation(frames: list[dict], path: Path, field: str, spacing_m: float,
                    direction=None, reference: dict | None = None, fps: int = 12) -> Path:
    """An oblique view of every frame with a fixed camera fitted to the whole deposition,
    the nozzle visible and a time stamp: MP4 (imageio's ffmpeg) or, without an encoder,
    a GIF next to ``path``. Returns the file written."""
    import imageio.v2 as imageio

    pv = _pyvista()
    spacing_mm = spacing_m * 1e3
    with_melt = [f for f in frames if np.isin(f["phase"], MELT_PHASES).any()]
    if not with_melt:
        raise ValueError("no melt in any frame")
    bounds = _melt_bounds(np.concatenate([f["position"][np.isin(f["phase"], MELT_PHASES)]
                                          for f in with_melt]) * 1e3, spacing_mm)
    last = with_melt[-1]
    clim = colour_range(field, display_values(field, scalars(last, field)[np.isin(last["phase"], MELT_PHASES)]),
                        reference)
    images = []
    for f in frames:
        img, frame = raster(pv, f, field, "oblique", bounds, spacing_mm, clim, direction)
        images.append(compose(img, frame, field, clim, f"t = {f['time_s']:.4f} s", None, "oblique"))
    h = min(img.shape[0] for img in images) // 2 * 2
    w = min(img.shape[1] for img in images) // 2 * 2
    images = [img[:h, :w] for img in images]
    try:
        import imageio_ffmpeg  # noqa: F401 - the encoder imageio writes MP4 with

        imageio.mimwrite(path, images, fps=fps, codec="libx264", quality=7, macro_block_size=2)
        return path
    except (ImportError, OSError, RuntimeError) as exc:
        gif = Path(path).with_suffix(".gif")
        log.warning("no MP4 encoder (%s); writing %s instead", exc, gif.name)
        imageio.mimwrite(gif, images, duration=1.0 / fps, loop=0)
        return gif

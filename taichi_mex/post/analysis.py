"""Mesostructure of printed beads from saved frames: cross-sections, bead sizes, necks, voids.

Pure numpy + matplotlib (Agg); reads ``particles.h5`` (see :mod:`taichi_mex.post.output`) and
needs no Taichi, so it runs on any frame of any run, also one that was interrupted.

How a section is measured (:func:`cross_section`)
-------------------------------------------------
A vertical plane through ``point_m`` with normal ``normal`` (the extrusion direction) is
rasterised on pixels of a quarter particle spacing ``dx``. Section coordinates are ``u``
(horizontal, in the plane) and ``v = z``.

*Occupancy.* Each melt particle (phase 0 fluid, 1 solid) stands for a cell of volume
``dx^3``. Along the normal its weight is a Gaussian of its distance from the plane (sigma
1 dx, cut at 2.5 dx: a slab 5 dx thick, averaging about five particle layers; on a lattice
the weights sum to 1 to well within 1 %). A slab half as thick read the disordered melt of a
simulated bead as holes (on the standard-resolution bead it held 69 particles where the
bead's mean cross-section holds 82). In the plane it spreads its cell, a dx-by-dx square, blurred
by a Gaussian of 0.15 dx. The sum ``phi`` is the material's volume fraction on the plane:
exactly 1 inside a lattice block and 1/2 on its face, which lies dx/2 beyond the last
particle centres (the face of the cells the particles stand for). Pixels with
``phi >= 1/2`` are material. This is the SPH colour function thresholded at one half with a
kernel that tiles: it is unbiased for faces, where painting discs of area dx^2 is not (a
union of discs of radius dx/sqrt(pi) overshoots a face by 0.06 dx, scallops it, and leaves
uncovered specks between lattice neighbours that read as voids), and the small blur keeps
the fillets that any smoothing puts into concave corners below a pixel (a Gaussian of
0.6 dx put 1-2 pixels of fillet at each foot of a bead and widened it by half a spacing). The blur
still bridges cracks narrower than ~0.2 dx between disordered particles. Volumes are
``dx^3`` rather than ``m / rho``: EDAC's summation density falls at a free surface, and
``m / rho`` would push the surface outwards. Each bead also reports ``particle_area_mm2``,
the integral of its volume fraction (its slab particles' weight times dx^2): the area mass
conservation gives, whatever the shape; it exceeds the pixel area where the bead's
particles are too sparse to make material (phi < 1/2).

*Beads.* A material pixel belongs to the label whose particles put the most weight on it
(the nearest particles; bead ids, -1 for a solid substrate, and the plate as one more
label, so the melt-plate interface closes without a gap). Area and centroid are those of
the bead's pixels; width and height are the extents of its *core*, the pixels where its own
particles alone reach 1/2 (a core ends exactly on an interface the bead shares with a
neighbour, where both make 1/2, and takes in no fillet).

*Necks.* The contact between two labels is their shared pixel boundary, counting an edge
where both labels make at least 0.2 of the material on it (on a flat free surface that ends
a neck each makes phi/2, 1/4 at the surface; in a fillet one of them makes next to nothing).
Each connected piece of it measures ``pixel * sqrt(n_h^2 + n_v^2)`` from its numbers of
horizontal and vertical pixel edges: the chord of the interface, exact for straight or
monotone curved necks (what the FFF literature calls the neck or bond width); the neck
width is the sum over pieces longer than half a spacing (shorter ones are below
resolution). A contact is "side" when the two centroids are further apart horizontally than
vertically, else "layer"; "plate" for a bead's footprint on the plate. A bead's ``pieces``
counts the connected parts of its core of at least one particle cell (dx^2).

*Voids.* Empty pixels connected (4-neighbours) to the section's border are air; the plate
closes the bottom. The other empty regions are voids; those smaller than one particle's
cross-section (dx^2) cannot be resolved by the particles and are filled (reported as
``filled_subresolution_area_mm2``). The void fraction is void area over the envelope (melt
plus voids, plate excluded).

Accuracy on lattice beads (tests/test_analysis.py): widths and heights within a pixel,
areas within 1 %, necks and void fractions exact to a pixel. On a simulated frame the limit
is the particles: features smaller than about one spacing are not resolved.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from taichi_mex.errors import UserInputError

#: label image values besides bead ids (which are >= 0, or -1 for solid substrate beads)
PLATE = -2
EMPTY = -3
MELT_PHASES = (0, 1)

SLAB_SIGMA_DX = 1.0      #: Gaussian width along the normal, in spacings
SLAB_CUT_SIGMAS = 2.5    #: slab half-thickness, in normal sigmas (1.25 dx)
BLUR_SIGMA_DX = 0.15     #: in-plane: a particle's cell, blurred by a Gaussian this wide (dx)
PIXEL_DX = 0.25          #: pixel size, in spacings
MAX_PIXELS = 8_000_000   #: a larger section gets coarser pixels
MIN_CONTACT_DX = 0.5     #: contacts shorter than this (in spacings) are not resolved
NECK_SHARE = 0.2         #: an edge is part of a neck where both sides make this fraction


# --------------------------------------------------------------------------- input
def load_frame(h5_path, index: int = -1) -> dict:
    """One frame of a ``particles.h5``: its arrays (SI units, as written), plus ``time_s``,
    ``step``, ``frame_index`` (non-negative), ``frame_name``, ``frame_count``, ``config``
    (dict), ``units`` (dict), ``plate_position`` (m, or None) and ``path``."""
    import h5py

    path = Path(h5_path)
    if not path.is_file():
        raise UserInputError(f"No particles file at {path}: run a simulation with --out into that "
                             "folder first, or point at the folder that holds particles.h5.")
    try:
        h5 = h5py.File(path, "r")
    except BlockingIOError:
        raise UserInputError(f"{path} is locked: a simulation is still writing it. Analyse it "
                             "when the run has ended (or analyse a copy of the file).") from None
    except OSError as exc:
        raise UserInputError(f"{path} is not a readable HDF5 file ({exc}).") from None
    with h5:
        if "frames" not in h5 or not len(h5["frames"]):
            raise UserInputError(f"{path} holds no frames (/frames is missing or empty): the run "
                                 "wrote nothing yet, or this is not a taichi_mex particles file.")
        names = sorted(h5["frames"].keys())
        n = len(names)
        try:
            index = int(index)
        except (TypeError, ValueError):
            raise UserInputError(f"Frame index must be an integer, got {index!r}.") from None
        if not -n <= index < n:
            raise UserInputError(f"{path} has {n} frame(s), numbered 0 to {n - 1} (or -1 for the "
                                 f"last); frame {index} does not exist.")
        index %= n
        g = h5["frames"][names[index]]
        frame = {k: g[k][()] for k in g.keys()}
        if "position" not in frame:
            raise UserInputError(f"Frame {names[index]} of {path} has no position dataset.")
        frame["time_s"] = float(g.attrs.get("time_s", np.nan))
        frame["step"] = int(g.attrs.get("step", -1))
        frame["frame_index"] = index
        frame["frame_name"] = names[index]
        frame["frame_count"] = n
        frame["config"] = json.loads(h5.attrs["config"]) if "config" in h5.attrs else {}
        frame["units"] = json.loads(h5.attrs["units"]) if "units" in h5.attrs else {}
        frame["plate_position"] = h5["plate/position"][()] if "plate/position" in h5 else None
        frame["path"] = str(path)
    return frame


def slicer_model(area_mm2, height_mm):
    """Width (mm) of the slicer's rounded rectangle of this area and height:
    A = (W - H) H + pi H^2 / 4, so W = A / H + H (1 - pi / 4). Works on arrays too."""
    area = np.asarray(area_mm2, float)
    height = np.asarray(height_mm, float)
    if np.any(height <= 0) or np.any(area < 0):
        raise UserInputError(f"The slicer model needs a positive height and a non-negative area "
                             f"(got area {area_mm2} mm^2, height {height_mm} mm).")
    width = area / height + height * (1.0 - math.pi / 4.0)
    return float(width) if width.ndim == 0 else width


def layer_height_mm(plan: dict | None) -> float | None:
    """The height of the first simulated layer (mm) from a run's plan (``plan.json``): the
    gap g of the slicer's rounded rectangle; None where the plan has no layers."""
    if not plan or not plan.get("layer_z_mm"):
        return None
    z = [0.0] + list(plan["layer_z_mm"])
    layers = str(plan.get("selected_layers") or "1")
    try:
        first = int(layers.split(",")[0].split("-")[0])
    except ValueError:
        first = 1
    first = min(max(first, 1), len(z) - 1)
    return z[first] - z[first - 1]


def rounded_rectangle_outline(width_mm: float, height_mm: float, centre_u_mm: float,
                              bottom_mm: float, points: int = 24) -> np.ndarray:
    """(N, 2) closed outline of the slicer's rounded rectangle: a rectangle W - H wide with
    half discs of diameter H at its ends (slicer_model's shape), its base at ``bottom_mm``."""
    r = 0.5 * height_mm
    half = max(0.5 * width_mm - r, 0.0)
    zc = bottom_mm + r
    a = np.linspace(-0.5 * math.pi, 0.5 * math.pi, points)
    right = np.stack([centre_u_mm + half + r * np.cos(a), zc + r * np.sin(a)], axis=1)
    left = np.stack([centre_u_mm - half - r * np.cos(a), zc - r * np.sin(a)], axis=1)
    return np.concatenate([right, left, right[:1]])


# --------------------------------------------------------------------------- section
@dataclass
class Section:
    """A rasterised cross-section and what was measured on it (lengths in mm in the dicts).

    ``label[row, col]`` holds the bead id of a material pixel, :data:`PLATE` or :data:`EMPTY`
    (rows go up in ``v = z``); ``void`` marks the enclosed empty pixels; ``phi`` is the
    material volume fraction, ``own_phi`` the part of it from the pixel's label, and
    ``parts[label] = (row0, col0, image)`` each label's part on its bounding box. Pixel
    (row, col) spans u in ``origin_m[0] + [col, col + 1] * pixel_m`` and v likewise from
    ``origin_m[1]``.
    """

    point_m: np.ndarray
    normal: np.ndarray
    u_axis: np.ndarray
    spacing_m: float
    pixel_m: float
    origin_m: tuple[float, float]
    label: np.ndarray
    void: np.ndarray
    phi: np.ndarray
    own_phi: np.ndarray
    parts: dict
    particles: int
    beads: list[dict] = field(default_factory=list)
    contacts: list[dict] = field(default_factory=list)
    voids: list[dict] = field(default_factory=list)
    totals: dict = field(default_factory=dict)

    def part(self, lab: int, rows, cols) -> np.ndarray:
        """The volume fraction that label ``lab`` alone makes at pixels (rows, cols)."""
        rows, cols = np.asarray(rows), np.asarray(cols)
        if lab not in self.parts:
            return np.zeros(rows.shape)
        r0, c0, img = self.parts[lab]
        r, c = rows - r0, cols - c0
        inside = (r >= 0) & (r < img.shape[0]) & (c >= 0) & (c < img.shape[1])
        out = np.zeros(rows.shape)
        out[inside] = img[r[inside], c[inside]]
        return out

    @property
    def core(self) -> np.ndarray:
        """``label`` where the label's own particles alone make material (own_phi >= 1/2)."""
        return np.where(self.own_phi >= 0.5, self.label, EMPTY)

    @property
    def extent_mm(self) -> tuple[float, float, float, float]:
        """(u_min, u_max, v_min, v_max) of the raster in mm, for imshow."""
        nv, nu = self.label.shape
        u0, v0 = self.origin_m
        return (1e3 * u0, 1e3 * (u0 + nu * self.pixel_m), 1e3 * v0, 1e3 * (v0 + nv * self.pixel_m))

    @property
    def axis_name(self) -> str:
        """'x' or 'y' when u runs along that axis, else 'u'."""
        k = int(np.argmax(np.abs(self.u_axis)))
        return "xyz"[k] if abs(self.u_axis[k]) > 0.999 else "u"

    @property
    def coordinate_mm(self) -> tuple[str, float]:
        """Where the plane sits along the dominant axis of its normal: ('x', 11.5)."""
        k = int(np.argmax(np.abs(self.normal[:2])))
        return "xy"[k], 1e3 * float(self.point_m[k])

    def to_dict(self) -> dict:
        axis, coord = self.coordinate_mm
        return {
            "position": {"axis": axis, "coordinate_mm": coord,
                         "point_mm": [1e3 * float(c) for c in self.point_m],
                         "normal": [float(c) for c in self.normal],
                         "u_axis": [float(c) for c in self.u_axis]},
            "spacing_mm": 1e3 * self.spacing_m,
            "pixel_mm": 1e3 * self.pixel_m,
            "particles_in_slab": self.particles,
            **self.totals,
            "beads": self.beads,
            "contacts": self.contacts,
            "voids": self.voids,
        }


def section_axes(normal) -> tuple[np.ndarray, np.ndarray]:
    """Unit normal (horizontal) and in-plane horizontal axis u, signed so that u's largest
    component is positive (u = +y for a normal along +-x)."""
    n = np.asarray(normal, float).reshape(3).copy()
    horizontal = np.linalg.norm(n[:2])
    if not np.all(np.isfinite(n)) or horizontal < 1e-9 or abs(n[2]) > 1e-6 * np.linalg.norm(n):
        raise UserInputError(f"A section normal must be a horizontal direction (the extrusion "
                             f"direction), got {list(n)}; sections are vertical planes.")
    n /= np.linalg.norm(n)
    u = np.cross([0.0, 0.0, 1.0], n)
    u /= np.linalg.norm(u)
    if u[np.argmax(np.abs(u))] < 0:
        u = -u
    return n, u


def cross_section(frame: dict, point_m, normal, spacing_m: float) -> Section:
    """Rasterise and measure the section of ``frame``'s melt on the vertical plane through
    ``point_m`` (m) with horizontal normal ``normal``. See the module docstring for the
    method. Raises UserInputError when the plane cuts no melt."""
    dx = float(spacing_m)
    if not dx > 0:
        raise UserInputError(f"Particle spacing must be positive, got {spacing_m}.")
    n, u_axis = section_axes(normal)
    point = np.asarray(point_m, float).reshape(3)
    pos = np.asarray(frame["position"], float)
    phase = np.asarray(frame["phase"]) if "phase" in frame else np.zeros(len(pos), int)
    bead = np.asarray(frame.get("bead_id", np.zeros(len(pos))), dtype=np.int64)

    sigma_n = SLAB_SIGMA_DX * dx
    half = SLAB_CUT_SIGMAS * sigma_n
    melt = np.isin(phase, MELT_PHASES)
    s = (pos - point) @ n
    near = melt & (np.abs(s) <= half)
    if not near.any():
        axis = "xy"[int(np.argmax(np.abs(n[:2])))]
        raise UserInputError(
            f"The section at {axis} = {1e3 * point[int(np.argmax(np.abs(n[:2])))]:.4g} mm (normal "
            f"{np.round(n, 3).tolist()}) cuts no melt in this frame ({int(melt.sum())} melt "
            "particles in all): choose a position inside a printed bead, or a later frame.")
    u = pos[near] @ u_axis
    v = pos[near, 2]
    weight = dx**3 * _gauss1d(s[near], sigma_n, half)
    bead_near = bead[near]

    blur = BLUR_SIGMA_DX * dx
    cut = 0.5 * dx + 3.0 * blur
    plate = frame.get("plate_position")
    plate_top = None
    if plate is not None and len(plate):
        plate = np.asarray(plate, float)
        plate_top = float(plate[:, 2].max()) + 0.5 * dx

    # raster: the melt plus a margin; the plate (when there is one) as a strip at the bottom
    pad = cut + 2 * PIXEL_DX * dx
    lo_u, hi_u = u.min() - pad, u.max() + pad
    hi_v = v.max() + pad
    lo_v = v.min() - pad if plate_top is None else min(plate_top - 0.5 * dx, v.min() - 0.5 * dx)
    pixel = PIXEL_DX * dx
    area = (hi_u - lo_u) * (hi_v - lo_v)
    if area / pixel**2 > MAX_PIXELS:
        pixel = math.sqrt(area / MAX_PIXELS)
    nu = int(math.ceil((hi_u - lo_u) / pixel))
    nv = int(math.ceil((hi_v - lo_v) / pixel))
    grid = (lo_u, lo_v, pixel, nu, nv)

    groups = [(int(b), (bead_near == b)) for b in np.unique(bead_near)]
    sources = [(b, u[m], v[m], weight[m]) for b, m in groups]
    if plate_top is not None:
        sp = (plate - point) @ n
        pu = plate @ u_axis
        pm = (np.abs(sp) <= half) & (pu > lo_u - cut) & (pu < hi_u + cut) & (plate[:, 2] > lo_v - cut)
        if pm.any():
            sources.append((PLATE, pu[pm], plate[pm, 2], dx**3 * _gauss1d(sp[pm], sigma_n, half)))

    # per pixel: the total and the largest part from one label; each label's own part is kept
    # on the bounding box where it is non-zero
    phi = np.zeros(nu * nv)
    best = np.zeros(nu * nv)
    owner = np.full(nu * nv, EMPTY, np.int64)
    parts = {}
    for lab, su, sv, sw in sources:
        dens = _spread(su, sv, sw, grid, dx, blur)
        phi += dens
        top = dens > best
        best = np.where(top, dens, best)
        owner = np.where(top, lab, owner)
        parts[lab] = _crop(dens.reshape(nv, nu))
    shape = (nv, nu)
    phi, best, owner = phi.reshape(shape), best.reshape(shape), owner.reshape(shape)
    solid = phi >= 0.5

    # empty regions: air if they reach the border, else voids (tiny ones are sampling noise)
    comp, ncomp = _components(~solid)
    border = np.unique(np.concatenate([comp[0], comp[-1], comp[:, 0], comp[:, -1]]))
    sizes = np.bincount(comp[comp >= 0], minlength=ncomp)
    is_air = np.zeros(ncomp, bool)
    is_air[border[border >= 0]] = True
    min_void_px = (dx / pixel) ** 2
    is_small = ~is_air & (sizes < min_void_px)
    filled = (comp >= 0) & is_small[np.maximum(comp, 0)]
    void = (comp >= 0) & ~is_air[np.maximum(comp, 0)] & ~filled
    label = np.where(solid | filled, owner, EMPTY)
    if not (label >= -1).any():
        raise UserInputError(
            f"The section through {np.round(1e3 * point, 3).tolist()} mm meets only "
            f"{int(near.sum())} scattered melt particle(s), too few to make up any material: "
            "choose a position inside a printed bead, or a later frame.")

    sec = Section(point_m=point, normal=n, u_axis=u_axis, spacing_m=dx, pixel_m=pixel,
                  origin_m=(lo_u, lo_v), label=label, void=void, phi=phi, own_phi=best,
                  parts=parts, particles=int(near.sum()))
    per_bead = {b: (int(m.sum()), 1e6 * float(weight[m].sum())) for b, m in groups}
    _measure(sec, comp, filled, per_bead)
    return sec


def _crop(image: np.ndarray):
    """(row0, col0, the smallest sub-image holding all non-zero values), float32."""
    rows, cols = np.nonzero(image.any(axis=1))[0], np.nonzero(image.any(axis=0))[0]
    if not len(rows):
        return 0, 0, np.zeros((0, 0), np.float32)
    return int(rows[0]), int(cols[0]), image[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1].astype(np.float32)


def _gauss1d(s, sigma, cut):
    """1D Gaussian in s (1/m), normalised over [-cut, cut]."""
    norm = sigma * math.sqrt(2 * math.pi) * math.erf(cut / (sigma * math.sqrt(2)))
    return np.exp(-0.5 * (s / sigma) ** 2) / norm


def _erf(x):
    """Error function (Abramowitz & Stegun 7.1.26, |error| < 1.5e-7); numpy has none."""
    t = 1.0 / (1.0 + 0.3275911 * np.abs(x))
    poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))))
    return np.sign(x) * (1.0 - poly * np.exp(-x * x))


def _cell_profile(d, dx, blur):
    """The indicator of a cell of width dx centred on 0, blurred by a Gaussian of width blur
    (1/m; unit integral): (Phi((d + dx/2) / blur) - Phi((d - dx/2) / blur)) / dx."""
    k = 1.0 / (blur * math.sqrt(2.0))
    return 0.5 * (_erf((d + 0.5 * dx) * k) - _erf((d - 0.5 * dx) * k)) / dx


def _spread(u, v, w, grid, dx, blur, chunk_entries=2_000_000):
    """Sum of w_j * C(u - u_j) C(v - v_j) at the pixel centres (flat array), C the blurred
    cell profile of :func:`_cell_profile`: each particle spreads its cell of side dx."""
    u0, v0, pixel, nu, nv = grid
    cut = 0.5 * dx + 3.0 * blur
    k = int(math.ceil(cut / pixel)) + 1
    off = np.arange(-k, k + 1)
    di, dj = (a.ravel() for a in np.meshgrid(off, off, indexing="ij"))
    col = np.floor((u - u0) / pixel).astype(np.int64)
    row = np.floor((v - v0) / pixel).astype(np.int64)
    out = np.zeros(nu * nv)
    step = max(1, chunk_entries // len(di))
    for a in range(0, len(u), step):
        c = col[a:a + step, None] + dj[None, :]
        r = row[a:a + step, None] + di[None, :]
        du = u0 + (c + 0.5) * pixel - u[a:a + step, None]
        dv = v0 + (r + 0.5) * pixel - v[a:a + step, None]
        ok = (np.abs(du) <= cut) & (np.abs(dv) <= cut) & (c >= 0) & (c < nu) & (r >= 0) & (r < nv)
        val = w[a:a + step, None].repeat(len(di), axis=1)[ok] * _cell_profile(du[ok], dx, blur) \
            * _cell_profile(dv[ok], dx, blur)
        out += np.bincount((r * nu + c)[ok], weights=val, minlength=nu * nv)
    return out


def _interface_chords(doubled: np.ndarray) -> list[float]:
    """Chord lengths (pixels) of the connected pieces of an interface, given its pixel edges in
    doubled coordinates (see _measure): sqrt(n_h^2 + n_v^2) per piece, pieces joined through
    shared pixel corners."""
    if not len(doubled):
        return []
    vertical = doubled[:, 0] % 2 == 1          # edge between horizontal neighbours
    d_r, d_c = np.where(vertical, 1, 0), np.where(vertical, 0, 1)
    cells = np.concatenate([doubled, doubled - np.stack([d_r, d_c], 1), doubled + np.stack([d_r, d_c], 1)])
    lo = cells.min(axis=0)
    shape = tuple(cells.max(axis=0) - lo + 1)
    mask = np.zeros(shape, bool)
    mask[cells[:, 0] - lo[0], cells[:, 1] - lo[1]] = True
    comp, count = _components(mask)
    piece = comp[doubled[:, 0] - lo[0], doubled[:, 1] - lo[1]]
    n_v = np.bincount(piece[vertical], minlength=count)
    n_h = np.bincount(piece[~vertical], minlength=count)
    keep = (n_v + n_h) > 0
    return np.hypot(n_v[keep], n_h[keep]).tolist()


def _components(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """4-connected components of a boolean image: (labels with -1 off the mask, count).

    Vectorised union-find: every round hooks the larger of two adjacent roots under the
    smaller one, then compresses paths completely; edges whose ends share a root are done.
    """
    h, w = mask.shape
    idx = np.arange(h * w).reshape(h, w)
    hm = mask[:, :-1] & mask[:, 1:]
    vm = mask[:-1, :] & mask[1:, :]
    a = np.concatenate([idx[:, :-1][hm], idx[:-1, :][vm]])
    b = np.concatenate([idx[:, 1:][hm], idx[1:, :][vm]])
    parent = np.arange(h * w)
    while a.size:
        ra, rb = parent[a], parent[b]
        open_ = ra != rb
        if not open_.any():
            break
        a, b, ra, rb = a[open_], b[open_], ra[open_], rb[open_]
        np.minimum.at(parent, np.maximum(ra, rb), np.minimum(ra, rb))
        while True:
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
    flat = mask.ravel()
    out = np.full(h * w, -1, np.int64)
    roots, inverse = np.unique(parent[flat], return_inverse=True)
    out[flat] = inverse
    return out.reshape(h, w), len(roots)


def _column_tops(crop: np.ndarray) -> np.ndarray:
    """Per pixel column of the middle half of a bead's bounding box (crop: True where the
    bead is, row 0 its lowest row), the height of its highest bead pixel above the box's
    floor, in pixels: the issue's flat-top test reads every column of the middle half, not
    the bead's extreme."""
    nu = crop.shape[1]
    middle = crop[:, nu // 4:nu - nu // 4]  # never empty: nu - 2 (nu // 4) >= 1
    rows = np.arange(middle.shape[0])[:, None]
    return np.where(middle, rows + 1, 0).max(axis=0)


def _measure(sec: Section, comp, filled, per_bead: dict) -> None:
    """Fill sec.beads, sec.contacts, sec.voids and sec.totals from the label image;
    ``per_bead`` maps a bead id to (particles in the slab, their area in mm^2)."""
    p_mm = 1e3 * sec.pixel_m
    px_area = p_mm * p_mm
    label = sec.label
    nv, nu = label.shape
    uc = sec.extent_mm[0] + (np.arange(nu) + 0.5) * p_mm
    vc = sec.extent_mm[2] + (np.arange(nv) + 0.5) * p_mm

    core = sec.core
    min_piece_px = (sec.spacing_m / sec.pixel_m) ** 2     # one particle's cell
    beads = []
    centroid = {}
    for b in sorted(int(x) for x in np.unique(label) if x not in (PLATE, EMPTY)):
        rows, cols = np.nonzero(label == b)
        area = len(rows) * px_area
        cu, cv = float(uc[cols].mean()), float(vc[rows].mean())
        centroid[b] = (cu, cv)
        core_rows, core_cols = np.nonzero(core == b)
        if len(core_rows):
            rows, cols = core_rows, core_cols
        width = (cols.max() - cols.min() + 1) * p_mm
        height = (rows.max() - rows.min() + 1) * p_mm
        crop = core[rows.min():rows.max() + 1, cols.min():cols.max() + 1] == b
        tops = _column_tops(crop) * p_mm
        piece, count = _components(crop)
        pieces = int((np.bincount(piece[piece >= 0], minlength=count) >= min_piece_px).sum())
        beads.append({
            "bead_id": b, "substrate": b < 0, "area_mm2": area, "width_mm": width,
            "height_mm": height, "centroid_mm": [cu, cv],
            "top_min_mm": float(tops.min()), "top_median_mm": float(np.median(tops)),
            "top_max_mm": float(tops.max()),
            "bounds_mm": [float(uc[cols.min()] - p_mm / 2), float(uc[cols.max()] + p_mm / 2),
                          float(vc[rows.min()] - p_mm / 2), float(vc[rows.max()] + p_mm / 2)],
            "particle_area_mm2": per_bead.get(b, (0, 0.0))[1],
            "slicer_width_mm": slicer_model(area, height),
            "pieces": max(pieces, 1), "particles": per_bead.get(b, (0, 0.0))[0]})

    # shared pixel edges (P, Q) between regions a and b where both make at least a share of
    # the material (phi_a, phi_b >= NECK_SHARE on the edge, the mean of P and Q). At a flat free
    # surface that ends a neck each makes phi / 2. Edges in doubled coordinates: the one between
    # (r, c) and (r, c + 1) sits at (2r + 1, 2c + 2), the one between (r, c) and (r + 1, c) at
    # (2r + 2, 2c + 1); pixel corners have both coordinates even.
    edges: dict[tuple[int, int], list[np.ndarray]] = {}
    rows, cols = np.indices(label.shape)
    for step in ((0, 1), (1, 0)):
        a = label[:nv - step[0], :nu - step[1]]
        b = label[step[0]:, step[1]:]
        m = (a != b) & (a != EMPTY) & (b != EMPTY)
        pr, pc = rows[:nv - step[0], :nu - step[1]][m], cols[:nv - step[0], :nu - step[1]][m]
        qr, qc = pr + step[0], pc + step[1]
        lo, hi = np.minimum(a[m], b[m]), np.maximum(a[m], b[m])
        if not len(lo):
            continue
        keys, which = np.unique(np.stack([lo, hi], axis=1), axis=0, return_inverse=True)
        which = which.ravel()
        for k, (ka, kb) in enumerate(keys.tolist()):
            sel = which == k
            phi_a = 0.5 * (sec.part(ka, pr[sel], pc[sel]) + sec.part(ka, qr[sel], qc[sel]))
            phi_b = 0.5 * (sec.part(kb, pr[sel], pc[sel]) + sec.part(kb, qr[sel], qc[sel]))
            ok = np.minimum(phi_a, phi_b) >= NECK_SHARE
            doubled = np.stack([pr[sel][ok] + qr[sel][ok] + 1, pc[sel][ok] + qc[sel][ok] + 1], axis=1)
            edges.setdefault((ka, kb), []).append(doubled)
    min_chord_px = MIN_CONTACT_DX * sec.spacing_m / sec.pixel_m
    contacts = []
    for (ka, kb), parts in sorted(edges.items()):
        chords = [c for c in _interface_chords(np.concatenate(parts)) if c >= min_chord_px]
        if not chords:
            continue
        if PLATE in (ka, kb):
            kind, pair = "plate", [kb if ka == PLATE else ka, "plate"]
        else:
            du = abs(centroid[ka][0] - centroid[kb][0])
            dv = abs(centroid[ka][1] - centroid[kb][1])
            kind, pair = ("side" if du >= dv else "layer"), [ka, kb]
        contacts.append({"beads": pair, "kind": kind, "neck_width_mm": p_mm * float(sum(chords)),
                         "pieces": len(chords)})

    voids = []
    for c in np.unique(comp[sec.void]):
        rows, cols = np.nonzero(comp == c)
        voids.append({"area_mm2": len(rows) * px_area,
                      "centroid_mm": [float(uc[cols].mean()), float(vc[rows].mean())],
                      "width_mm": (cols.max() - cols.min() + 1) * p_mm,
                      "height_mm": (rows.max() - rows.min() + 1) * p_mm})
    voids.sort(key=lambda d: -d["area_mm2"])

    melt_area = float((label >= -1).sum()) * px_area
    void_area = float(sec.void.sum()) * px_area
    envelope = melt_area + void_area
    real = [d for d in beads if not d["substrate"]]

    def mean(values):
        return float(np.mean(values)) if values else None

    sec.beads, sec.contacts, sec.voids = beads, contacts, voids
    sec.totals = {
        "beads_count": len(real),
        "melt_area_mm2": melt_area,
        "envelope_area_mm2": envelope,
        "void_area_mm2": void_area,
        "void_fraction": void_area / envelope if envelope > 0 else 0.0,
        "voids_count": len(voids),
        "filled_subresolution_area_mm2": float(filled.sum()) * px_area,
        "mean_width_mm": mean([d["width_mm"] for d in real]),
        "mean_height_mm": mean([d["height_mm"] for d in real]),
        "top_min_mm": min((d["top_min_mm"] for d in real), default=None),
        "top_median_mm": mean([d["top_median_mm"] for d in real]),
        "top_max_mm": max((d["top_max_mm"] for d in real), default=None),
        "mean_area_mm2": mean([d["area_mm2"] for d in real]),
        "mean_particle_area_mm2": mean([d["particle_area_mm2"] for d in real]),
        "mean_neck_side_mm": mean([c["neck_width_mm"] for c in contacts if c["kind"] == "side"]),
        "mean_neck_layer_mm": mean([c["neck_width_mm"] for c in contacts if c["kind"] == "layer"]),
    }


# --------------------------------------------------------------------------- run level
def section_points(config: dict, positions_mm=None, direction=None,
                   fallback_point_m=None) -> list[tuple[np.ndarray, np.ndarray]]:
    """(point_m, normal) of the default section and of each position in ``positions_mm``.

    The default section goes through the config's ``section_point_m`` (or, in runs that name
    none, ``fallback_point_m``) with the extrusion direction as its normal: ``direction``
    when given, else the config's ``section_direction``, else x. A position is the G-code
    coordinate (mm) along the dominant axis of that direction (x for beads along x).
    """
    if direction is None:
        direction = config.get("section_direction") or [1.0, 0.0, 0.0]
    n, _ = section_axes(direction)
    point = config.get("section_point_m")
    point = np.asarray(fallback_point_m if point is None else point, float)
    out = [(point, n)]
    k = int(np.argmax(np.abs(n[:2])))
    for x_mm in positions_mm or []:
        x_mm = float(x_mm)
        if not math.isfinite(x_mm):
            raise UserInputError(f"Section position {x_mm} is not a finite number of mm.")
        t = (1e-3 * x_mm - point[k]) / n[k]
        out.append((point + t * n, n))
    return out


#: sections over a bead's steady middle whose figures the summary reports: at 2-3 particles
#: per layer one section's width varies 10-30 % along a settled bead and moved up to 20 %
#: between two solvers that agree to their tolerance (measured 2026-12-02, strands); nine
#: over the middle half read the bead, not the particles that happen to sit in one slab
ALONG_SECTIONS = 9


def along_middle(frame: dict, point_m, normal, spacing_m: float, count: int = ALONG_SECTIONS):
    """Sections at ``count`` evenly spaced positions over the middle half of the melt's extent
    along ``normal`` (planes normal to it, through ``point_m`` shifted along it): mean,
    smallest and largest of each bead figure. Sections that cut no melt or no bead are left
    out; None when none is left or ``count`` < 1."""
    if count < 1:
        return None
    n, _ = section_axes(normal)
    point = np.asarray(point_m, float).reshape(3)
    pos = np.asarray(frame["position"], float)
    melt = np.isin(frame["phase"], MELT_PHASES) if "phase" in frame else np.ones(len(pos), bool)
    if not melt.any():
        return None
    s = (pos[melt] - point) @ n
    quarter = 0.25 * (s.max() - s.min())
    k = int(np.argmax(np.abs(n[:2])))
    coords, totals = [], []
    for t in np.linspace(s.min() + quarter, s.max() - quarter, count):
        try:
            sec = cross_section(frame, point + t * n, n, spacing_m)
        except UserInputError:
            continue
        if sec.totals["beads_count"]:
            coords.append(1e3 * float(point[k] + t * n[k]))
            totals.append(sec.totals)
    if not totals:
        return None

    def values(key):
        return [t[key] for t in totals if t.get(key) is not None]

    out = {"axis": "xy"[k], "coordinates_mm": coords, "sections": len(totals)}
    for key, name in (("mean_width_mm", "width"), ("mean_height_mm", "height"),
                      ("mean_area_mm2", "area")):
        v = values(key)
        unit = "mm2" if name == "area" else "mm"
        out[key] = float(np.mean(v))
        out[f"{name}_min_{unit}"], out[f"{name}_max_{unit}"] = float(min(v)), float(max(v))
    out["top_min_mm"] = float(min(values("top_min_mm")))
    out["top_median_mm"] = float(np.mean(values("top_median_mm")))
    out["top_max_mm"] = float(max(values("top_max_mm")))
    out["void_fraction"] = float(np.mean(values("void_fraction")))
    out["void_fraction_max"] = float(max(values("void_fraction")))
    return out


def headline_section(meso: dict) -> dict:
    """What a run's summary and a sweep's table report of ``mesostructure.json``: the default
    section's figures (necks, counts), its bead figures (width, height, area, tops, void
    fraction and their ranges) replaced by the means over the melt's middle where those were
    measured (one section is not a reproducible measure). A dict without ``sections`` is
    read as one section."""
    sections = meso.get("sections")
    first = sections[0] if isinstance(sections, list) and sections and isinstance(sections[0], dict) else meso
    middle = meso.get("along_middle")
    return {**first, **middle} if isinstance(middle, dict) else dict(first)


def analyse_run(out_dir, frame: int = -1, positions=None, direction=None,
                along: int = ALONG_SECTIONS) -> dict:
    """Sections of one frame of ``out_dir/particles.h5``: the default one (through the
    config's section point, normal to the extrusion direction) plus one per position in
    ``positions`` (mm along that direction); ``direction`` (horizontal vector) overrides the
    config's extrusion direction. See :func:`section_points`. ``along`` more sections over
    the melt's middle half (no pictures) give ``along_middle`` (:func:`along_middle`). Writes
    ``out_dir/mesostructure.json`` and ``out_dir/sections/section_NN.png``; returns the dict
    that went into the JSON."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise UserInputError(f"No run folder at {out_dir}: give the --out folder of a simulation.")
    data = load_frame(out_dir / "particles.h5", frame)
    config = data["config"]
    spacing = config.get("spacing_m") or 1e-3 * config.get("run", {}).get("spacing_mm", float("nan"))
    if not (isinstance(spacing, (int, float)) and spacing > 0):
        raise UserInputError(f"{data['path']} does not record the particle spacing (config "
                             "'spacing_m'); it was not written by taichi_mex.")
    melt = np.isin(data["phase"], MELT_PHASES) if "phase" in data else slice(None)
    if not len(data["position"][melt]):
        raise UserInputError(f"Frame {data['frame_index']} (t = {data['time_s']:.4g} s) of "
                             f"{data['path']} holds no melt yet: choose a later frame.")
    centre = data["position"][melt].mean(axis=0)
    # measure every section before writing anything: a bad position leaves old results alone
    planes = section_points(config, positions, direction, centre)
    sections = [cross_section(data, point, normal, spacing) for point, normal in planes]
    middle = along_middle(data, *planes[0], spacing, along)  # about the default section
    sections_dir = out_dir / "sections"
    sections_dir.mkdir(exist_ok=True)
    for old in sections_dir.glob("section_*.png"):
        old.unlink()
    results = []
    plan_json = out_dir / "plan.json"
    layer = layer_height_mm(json.loads(plan_json.read_text())) if plan_json.is_file() else None
    for i, sec in enumerate(sections):
        png = sections_dir / f"section_{i:02d}.png"
        plot_section(sec, png, time_s=data["time_s"], layer_mm=layer)
        d = sec.to_dict()
        d["source"] = "default" if i == 0 else "position"
        d["png"] = str(png.relative_to(out_dir))
        results.append(d)
    report = {
        "particles_file": str(out_dir / "particles.h5"),
        "frame": {"index": data["frame_index"], "name": data["frame_name"],
                  "time_s": data["time_s"], "step": data["step"], "count": data["frame_count"]},
        "units": {"lengths": "mm", "areas": "mm^2", "void_fraction": "1 (of melt + voids)"},
        "method": ("vertical plane normal to the extrusion direction; melt volume fraction from "
                   f"particle cells (dx^3) weighted along the normal by a Gaussian (sigma "
                   f"{SLAB_SIGMA_DX} dx, slab +-{SLAB_CUT_SIGMAS * SLAB_SIGMA_DX} dx) and blurred in "
                   f"the plane (sigma {BLUR_SIGMA_DX} dx); material where >= 1/2, pixels of {PIXEL_DX} "
                   "dx; beads by largest weight; widths, heights and necks on each bead's own core; "
                   "neck = chord of the shared boundary; voids = enclosed empty regions >= dx^2, "
                   "the plate closes the bottom"),
        "sections": results,
    }
    if middle is not None:
        report["along_middle"] = middle
    (out_dir / "mesostructure.json").write_text(json.dumps(report, indent=2))
    return report


def plot_section(sec: Section, path, time_s: float | None = None,
                 layer_mm: float | None = None) -> Path:
    """PNG of a section: beads coloured by id with black outlines, plate grey, voids red;
    with ``layer_mm`` (the gap g), each bead's reference dashed over it: the slicer's rounded
    rectangle of the bead's own area and height g, centred on the bead, on its base. Drawn
    on a bare Figure (Agg canvas), so no pyplot state or display is involved."""
    import matplotlib
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    label = sec.label
    colours = matplotlib.colormaps["tab20"]
    rgb = np.ones(label.shape + (3,))
    rgb[label == PLATE] = (0.75, 0.75, 0.75)
    ids = sorted(int(x) for x in np.unique(label) if x not in (PLATE, EMPTY))
    for b in ids:
        rgb[label == b] = (0.55, 0.45, 0.35) if b < 0 else colours(b % 20)[:3]
    rgb[sec.void] = (0.9, 0.05, 0.05)

    # show the melt and a little plate, not the whole raster
    rows, cols = np.nonzero(label >= -1)
    r0, r1 = max(rows.min() - 6, 0), min(rows.max() + 7, label.shape[0])
    c0, c1 = max(cols.min() - 6, 0), min(cols.max() + 7, label.shape[1])
    p_mm = 1e3 * sec.pixel_m
    e = sec.extent_mm
    ext = (e[0] + c0 * p_mm, e[0] + c1 * p_mm, e[2] + r0 * p_mm, e[2] + r1 * p_mm)
    crop = (slice(r0, r1), slice(c0, c1))
    span_u, span_v = ext[1] - ext[0], ext[3] - ext[2]
    fig = Figure(figsize=(min(max(4.0, 9.0 * span_u / max(span_u, span_v)) + 1.5, 14.0),
                          min(max(3.0, 9.0 * span_v / max(span_u, span_v)) + 1.5, 10.0)), dpi=130)
    ax = fig.subplots()
    ax.imshow(rgb[crop], origin="lower", extent=ext, interpolation="nearest")
    uc = ext[0] + (np.arange(c1 - c0) + 0.5) * p_mm
    vc = ext[2] + (np.arange(r1 - r0) + 0.5) * p_mm
    lab = label[crop]
    for b in ids:
        ax.contour(uc, vc, (lab == b).astype(float), levels=[0.5], colors="k", linewidths=0.8)
    if sec.void.any():
        ax.contour(uc, vc, sec.void[crop].astype(float), levels=[0.5], colors="darkred", linewidths=0.8)
    reference = None
    if layer_mm:
        for d in sec.beads:
            if d["substrate"] or d["area_mm2"] <= 0:
                continue
            u0, u1, v0, _ = d["bounds_mm"]
            ring = rounded_rectangle_outline(slicer_model(d["area_mm2"], layer_mm), layer_mm,
                                             0.5 * (u0 + u1), v0)
            reference, = ax.plot(ring[:, 0], ring[:, 1], color="k", lw=1.1, ls=(0, (4, 2.5)))
    size = max(5, min(9, int(60 / max(len(ids), 1) ** 0.5)))
    for d in sec.beads:
        text = "sub" if d["substrate"] else str(d["bead_id"])
        ax.text(*d["centroid_mm"], text, ha="center", va="center", fontsize=size,
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.7})
    ax.set_aspect("equal")
    name = sec.axis_name
    ax.set_xlabel(f"{name} [mm]" if name != "u" else
                  f"u [mm] (along {np.round(sec.u_axis, 3).tolist()})")
    ax.set_ylabel("z [mm]")
    t = sec.totals
    axis, coord = sec.coordinate_mm
    head = f"section at {axis} = {coord:.3f} mm" + (f", t = {time_s:.4g} s" if time_s is not None else "")

    ax.set_title(f"{head}: {t['beads_count']} bead(s), void {100 * t['void_fraction']:.2f} %\n"
                 f"mean W {_mm(t['mean_width_mm'])}, H {_mm(t['mean_height_mm'])}, "
                 f"A {_mm(t['mean_area_mm2'], 'mm²')}; necks side {_mm(t['mean_neck_side_mm'])}, "
                 f"layer {_mm(t['mean_neck_layer_mm'])}", fontsize=9)
    handles = [Patch(color=(0.9, 0.05, 0.05), label="void"),
               Patch(color=(0.75, 0.75, 0.75), label="plate")]
    if reference is not None:
        reference.set_label(f"slicer's rounded rectangle\n(same area, H = {layer_mm:.3g} mm)")
        handles.append(reference)
    ax.legend(handles=handles,
              loc="upper right", fontsize=7, framealpha=0.8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    return path


def _mm(value, unit="mm") -> str:
    return "-" if value is None else f"{value:.3f} {unit}"

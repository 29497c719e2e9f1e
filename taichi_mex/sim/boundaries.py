"""Solid walls as particle lattices: the build plate and the nozzle tip."""

import math

import numpy as np


def plate_lattice(xmin_m: float, xmax_m: float, ymin_m: float, ymax_m: float, spacing_m: float,
                  layers: int) -> np.ndarray:
    """Cell-centred lattice under z = 0 (the plate surface): layer k at z = -(k + 1/2) dx.

    With fluid particles starting at z >= dx/2, the first fluid layer sits one spacing above
    the first wall layer, exactly as inside the fluid.
    """
    nx = max(1, int(round((xmax_m - xmin_m) / spacing_m)))
    ny = max(1, int(round((ymax_m - ymin_m) / spacing_m)))
    xs = xmin_m + (np.arange(nx) + 0.5) * spacing_m
    ys = ymin_m + (np.arange(ny) + 0.5) * spacing_m
    zs = -(np.arange(layers) + 0.5) * spacing_m
    X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)


def disc_lattice(radius_m: float, spacing_m: float) -> np.ndarray:
    """(k, 2) square-lattice points inside a disc, centred on the origin.

    The lattice cross-section (k * dx^2) is what the inlet uses for flow bookkeeping, so
    the bore radius need not be a multiple of the spacing.
    """
    m = int(math.ceil(radius_m / spacing_m)) + 1
    ij = (np.arange(-m, m) + 0.5) * spacing_m
    X, Y = np.meshgrid(ij, ij, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel()], axis=1)
    inside = np.linalg.norm(pts, axis=1) < radius_m
    if not inside.any():  # coarser than the bore: one particle on the axis
        return np.zeros((1, 2))
    return pts[inside]


def annulus_lattice(inner_radius_m: float, outer_radius_m: float, spacing_m: float) -> np.ndarray:
    """(k, 2) lattice points with inner <= r < outer (the nozzle's flat tip face)."""
    m = int(math.ceil(outer_radius_m / spacing_m)) + 1
    ij = (np.arange(-m, m) + 0.5) * spacing_m
    X, Y = np.meshgrid(ij, ij, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel()], axis=1)
    r = np.linalg.norm(pts, axis=1)
    return pts[(r >= inner_radius_m) & (r < outer_radius_m)]

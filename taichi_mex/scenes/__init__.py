"""Scenes: each sets up particles, domain, times and the physics it needs, and registers
itself (:mod:`taichi_mex.scenes.registry`); :func:`taichi_mex.spec.scene_entries` loads them."""

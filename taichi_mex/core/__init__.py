"""Particle state, neighbour grid, kernels, reductions."""

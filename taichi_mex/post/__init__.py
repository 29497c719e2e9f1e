"""What a run leaves: HDF5 frames, snapshots, mesostructure analysis."""

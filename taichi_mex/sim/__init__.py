"""The run loop, the time step per scheme, the moving inlet and the walls."""

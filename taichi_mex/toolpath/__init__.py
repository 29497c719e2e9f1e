"""From G-code to a sampled nozzle path: normalise, plan (pyGCodeDecode), select, generate."""

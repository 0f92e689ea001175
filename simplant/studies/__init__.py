"""Studies run on the simulated plant (they need its truth: the noise-free scene)."""

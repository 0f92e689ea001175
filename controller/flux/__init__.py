"""Flux maps from a sun image (PHLUX) and glare hazard ratings. Pure functions."""

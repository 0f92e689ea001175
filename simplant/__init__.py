"""The simulated plant: optics of the beam spot, camera sensors, error cases, plant assembly.

Only simulation code lives here; the controller's runner never imports it.
"""

"""The simulated plant's devices: cameras (ray-traced and cheap) and their sensors and grids,
GigE Vision imagers, drives on their wires or in process, the Modbus lamp panel and a noisy
serial line. May import the rest of :mod:`simplant` below the plant's assembly and
:mod:`controller`'s foundation, devices and pure domain; never the product's orchestration.
"""

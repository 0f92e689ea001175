"""Wire level: codecs for our serial frame protocol, the Modbus register map, fault and
error codes shared by both ends, and the simulated actuator firmware (physics + servers).

Nothing here imports from :mod:`controller`: the simulated firmware shares only the wire
with the controller.
"""

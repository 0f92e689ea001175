"""The PAINT database's formats: measurements exported as PAINT calibration-properties records,
a PAINT folder read and checked, its records imported into a store, and the plant configuration
of a field known only by its PAINT files. May import :mod:`controller.storage` and the layers
below it.
"""

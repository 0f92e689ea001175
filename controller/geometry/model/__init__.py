"""The tracking model of one heliostat: its parameters and prediction, the fit (start, robust
weights, drift between nights), the field prior, the data splits and the validation of a fit.

Pure domain like the rest of :mod:`controller.geometry` (``field_prior_io`` reads and writes its
file); may import the other geometry modules, never a layer above.
"""

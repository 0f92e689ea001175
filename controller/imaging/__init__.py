"""Pure imaging maths: camera response, weighting functions, HDR merge, beam analysis, moments."""

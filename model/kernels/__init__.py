"""numba kernels of the model: pure functions of floats and arrays in SI units."""

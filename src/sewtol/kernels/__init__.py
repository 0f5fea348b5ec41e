"""Compiled hot kernels (numba). The numpy engine stays the reference they are tested against."""

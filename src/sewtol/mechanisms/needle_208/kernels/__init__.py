"""Fused numba kernels of the needle drive (fast paths; the numpy engine is the reference they are
tested against)."""

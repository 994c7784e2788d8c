"""Private numba kernels: tight loops only, no validation and no defaults (see the public wrappers)."""

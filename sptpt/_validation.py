"""Checks shared by the public wrappers of the kernels."""

from __future__ import annotations

import numpy as np


def positive_int(value: object, name: str) -> int:
    """``value`` as an int >= 1, or an error naming it."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be a positive integer, got {value!r}")
    if value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value}")
    return int(value)

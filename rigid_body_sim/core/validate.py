"""Validation at the boundary: turn user values into float arrays or raise SpecError."""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import SpecError


def finite_array(value: Any, field: str, shape: tuple[int, ...]) -> np.ndarray:
    """
    Return ``value`` as a float array of ``shape``, all finite.

    Raises
    ------
    SpecError
        If the value is not numeric, has another shape, or holds NaN or inf.

    """
    try:
        if isinstance(value, (str, bytes)) or np.asarray(value).dtype.kind not in 'iuf':
            raise TypeError
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        what = 'a number' if shape == () else f'numbers of shape {shape}'
        raise SpecError(field, f'expected {what}, got {value!r}') from None
    if arr.shape != shape:
        raise SpecError(field, f'expected shape {shape}, got shape {arr.shape} ({value!r})')
    if not np.all(np.isfinite(arr)):
        raise SpecError(field, f'must be finite, got {value!r}')
    return arr


def finite_scalar(value: Any, field: str) -> float:
    """Return ``value`` as a finite float, or raise SpecError naming ``field``."""
    if isinstance(value, bool):
        raise SpecError(field, f'expected a number, got {value!r}')
    return float(finite_array(value, field, ()))


def positive_scalar(value: Any, field: str) -> float:
    """Return ``value`` as a finite float > 0, or raise SpecError naming ``field``."""
    x = finite_scalar(value, field)
    if not x > 0.0:
        raise SpecError(field, f'must be positive, got {x!r}')
    return x


def nonnegative_scalar(value: Any, field: str) -> float:
    """Return ``value`` as a finite float >= 0, or raise SpecError naming ``field``."""
    x = finite_scalar(value, field)
    if not x >= 0.0:
        raise SpecError(field, f'must be non-negative, got {x!r}')
    return x


def unit_quaternion(value: Any, field: str) -> np.ndarray:
    """Return a (4,) quaternion (x, y, z, w) normalized; its norm must be 1 within 1e-6."""
    q = finite_array(value, field, (4,))
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 1e-6:
        raise SpecError(field, f'quaternion (x, y, z, w) must have unit norm, got norm {norm:.9g}')
    return q / norm

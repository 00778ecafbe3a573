"""The one real-array check and the one aligned allocation, below every layer (generated/bundle.py and runtime
import them; NumPy only)."""
from __future__ import annotations

import warnings

import numpy as np

__all__ = ["aligned_zeros", "real_array"]


def real_array(value, name: str) -> np.ndarray:
    """value as a float64 array (no copy when it already is one); TypeError naming `name` for None, complex,
    string or other non-numeric values (NumPy would drop an imaginary part with only a warning)."""
    if value is None:
        raise TypeError(f"{name} is required (got None)")
    arr = value if isinstance(value, np.ndarray) else np.asarray(value)
    kind = arr.dtype.kind
    if kind in "fiub":
        return arr.astype(np.float64, copy=False)
    if kind == "c":
        raise TypeError(f"{name} must be an array of real numbers, got complex ({arr.dtype}): abyssal computes in real "
                        "float64; pass the real part explicitly if that is what you mean")
    if kind == "O":
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", np.exceptions.ComplexWarning)
                return np.array(arr, dtype=np.float64)  # complex entries raise TypeError or ComplexWarning
        except (TypeError, ValueError, np.exceptions.ComplexWarning):
            pass
    raise TypeError(f"{name} must be an array of real numbers, got {type(value).__name__} of {arr.dtype}")


def aligned_zeros(shape, alignment: int = 64) -> np.ndarray:
    """A zeroed float64 array whose data starts on an `alignment`-byte boundary (vectorised loops then split a
    row the same way in every instance, so results never depend on where an allocation landed)."""
    count = int(np.prod(shape))
    raw = np.zeros(count + alignment // 8)
    start = (-raw.ctypes.data % alignment) // 8
    return raw[start:start + count].reshape(shape)

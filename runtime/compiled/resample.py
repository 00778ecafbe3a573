"""Resampling in C (runtime/c/abyssal_resample.h) from the caller's uniforms: ancestors and gathers.

    anc = Ancestors(capacity)                            # buffers for up to `capacity` particles
    anc.systematic(weights, rng.random())                # the ancestors of resampling.systematic_resample, bit for bit
    anc.multinomial(weights, rng.random(m))              # ... of multinomial_resample
    KLDSampler(capacity, n_max, dims).ancestors(weights, rows, rng, params)   # ... of kld_resample
    gather_rows(dst, src, anc)                           # dst[:, :m] = src[:, anc]
    gather_items(dst, src, anc)                          # dst[..., :m] = src[..., anc] (a block per particle)

The uniforms are the same draws of the same numpy Generator as the Python schemes', so the ancestors (and the
Generator's state after them) are theirs; the C replaces only the cumulative sums, the searches, the sort and, for
KLD-resampling, the bin count (tests/runtime/test_kld.py and test_resampling.py compare them).
"""
from __future__ import annotations

import ctypes
from functools import lru_cache

import numpy as np

from . import sir

_P, _LL, _D, _I, _SZ = ctypes.c_void_p, ctypes.c_longlong, ctypes.c_double, ctypes.c_int, ctypes.c_size_t


@lru_cache(maxsize=1)
def library() -> ctypes.CDLL:
    """The SIR step's library (abyssal_resample.c is one of its sources), with these functions declared."""
    lib = sir.library()
    for name, restype, argtypes in (
            ("abyssal_resample_systematic", None, [_LL, _P, _LL, _D, _P, _P]),
            ("abyssal_resample_multinomial", None, [_LL, _P, _LL, _P, _P, _P, _P]),
            ("abyssal_resample_inverse_cdf", None, [_LL, _P, _LL, _P, _P, _P]),
            ("abyssal_kld_bytes", _SZ, [_LL, _LL, _I]),
            ("abyssal_kld_start", _I, [_P, _SZ, _LL, _P, _P, _LL, _I, _P, _LL, _P]),
            ("abyssal_kld_draw", _LL, [_P, _P, _LL, _P]),
            ("abyssal_gather_rows", None, [_I, _LL, _P, _P, _LL, _P, _LL]),
            ("abyssal_gather_items", None, [_LL, _P, _LL, _P, _P])):
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = restype, argtypes
    return lib


class Ancestors:
    """Systematic and multinomial ancestors of up to `capacity` particles into one int64 buffer (a view is returned:
    valid until the next call)."""

    def __init__(self, capacity: int):
        self._lib = library()
        self.buffer = np.zeros(capacity, dtype=np.int64)
        self._cdf = np.zeros(capacity)
        self._order = np.zeros(capacity + 1, dtype=np.int64)
        self._u = np.zeros(capacity)

    def _fits(self, n: int, m: int) -> None:
        if not (n <= self.buffer.size and m <= self.buffer.size):
            raise ValueError(f"Ancestors({self.buffer.size}): weights of at most {self.buffer.size} particles and at most "
                             f"that many ancestors, got {n} weights and {m} ancestors")

    def systematic(self, weights: np.ndarray, u0: float, m: int | None = None) -> np.ndarray:
        """inverse_cdf(weights, (arange(m) + u0) / m) (schemes.systematic_resample with its one uniform u0)."""
        n = weights.shape[0]
        m = n if m is None else m
        self._fits(n, m)
        w = np.ascontiguousarray(weights, dtype=np.float64)
        self._lib.abyssal_resample_systematic(n, w.ctypes.data, m, u0, self.buffer.ctypes.data, self._cdf.ctypes.data)
        return self.buffer[:m]

    def multinomial(self, weights: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
        """inverse_cdf(weights, sort(uniforms)) (schemes.multinomial_resample with its uniforms)."""
        n, m = weights.shape[0], uniforms.shape[0]
        self._fits(n, m)
        w = np.ascontiguousarray(weights, dtype=np.float64)
        u = self._u[:m]
        u[...] = uniforms
        self._lib.abyssal_resample_multinomial(n, w.ctypes.data, m, u.ctypes.data, self.buffer.ctypes.data,
                                               self._cdf.ctypes.data, self._order.ctypes.data)
        return self.buffer[:m]


class KLDSampler:
    """KLD-sampling (kld.py's rule) with the bins counted in C on the drawn particles only (abyssal_resample.h).
    One sampler per filter: it keeps its hash set of occupied bins between resamplings."""

    def __init__(self, capacity: int, n_max: int, dims: int):
        self._lib = library()
        self.capacity, self.n_max, self.dims = int(capacity), int(n_max), int(dims)
        self._bytes = int(self._lib.abyssal_kld_bytes(self.capacity, self.n_max, self.dims))
        self._memory = np.zeros(self._bytes // 8 + 1)
        self._ancestors = np.zeros(self.n_max, dtype=np.int64)
        self._rows = None

    def ancestors(self, weights: np.ndarray, states: np.ndarray, rng: np.random.Generator, params) -> np.ndarray:
        """Ancestor indices (a new int64 array, n_min <= length <= n_max) of kld_resample(weights, states, rng,
        params): the same uniforms of rng in the same chunks. states (n, N) whose rows params.coordinates are binned."""
        n = weights.shape[0]
        if n > self.capacity:
            raise ValueError(f"KLDSampler: {n} particles, more than its capacity {self.capacity}")
        rows = self._binned_rows(states, params.coordinates, n)
        w = np.ascontiguousarray(weights, dtype=np.float64)
        widths = np.asarray(params.bin_size, dtype=np.float64)
        limit = params.limit_table()
        status = self._lib.abyssal_kld_start(self._memory.ctypes.data, self._bytes, n, w.ctypes.data, rows.ctypes.data,
                                             rows.strides[0] // 8, self.dims, widths.ctypes.data, int(params.n_max),
                                             limit.ctypes.data)
        if status == -1:
            raise ValueError("kld_resample: states must be finite along the binned coordinates")
        if status != 0:
            raise ValueError("kld_resample: the sampler does not fit these weights, states or parameters")
        n_max, n_min, chunk, done = int(params.n_max), max(int(params.n_min), 1), int(params.chunk), 0
        while True:
            # the first chunk is n_min draws (never fewer are kept), later ones params.chunk (kld.py)
            size = min(chunk if done else n_min, n_max - done)
            u = rng.random(size)
            drawn = self._lib.abyssal_kld_draw(self._memory.ctypes.data, u.ctypes.data, size, self._ancestors.ctypes.data)
            if drawn:
                return self._ancestors[:drawn].copy()
            done += size

    def _binned_rows(self, states: np.ndarray, coordinates, n: int) -> np.ndarray:
        """The binned rows of states as one (dims, ld) array: a view of states when they are rows of one buffer in
        order, else a copy."""
        rows = list(coordinates)
        if (isinstance(states, np.ndarray) and states.dtype == np.float64 and states.strides[1] == 8
                and rows == list(range(rows[0], rows[0] + len(rows)))):
            return states[rows[0]:rows[0] + len(rows)]
        return np.ascontiguousarray(np.asarray(states, dtype=np.float64)[rows, :n])


def gather_rows(dst: np.ndarray, src: np.ndarray, ancestors: np.ndarray) -> None:
    """dst[:, :m] = src[:, ancestors] for (rows, *) float64 arrays with contiguous rows (m = len(ancestors))."""
    library().abyssal_gather_rows(src.shape[0], ancestors.shape[0], ancestors.ctypes.data, src.ctypes.data,
                                  src.strides[0] // 8, dst.ctypes.data, dst.strides[0] // 8)


def gather_items(dst: np.ndarray, src: np.ndarray, ancestors: np.ndarray, size: int) -> None:
    """The ancestors' blocks of `size` doubles of src into the first len(ancestors) blocks of dst (contiguous)."""
    library().abyssal_gather_items(ancestors.shape[0], ancestors.ctypes.data, size, src.ctypes.data, dst.ctypes.data)


__all__ = ["Ancestors", "KLDSampler", "gather_items", "gather_rows", "library"]

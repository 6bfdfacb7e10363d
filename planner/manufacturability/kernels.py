"""Numba kernel of the collision Monte Carlo (:mod:`planner.manufacturability.monte_carlo`):
which told-apart pairs collide on which sampled chip, without the (chips, pairs) float
tables NumPy's version gathered four of per call."""

from __future__ import annotations

import numpy as np

# before the kernels are decorated: an installed copy caches outside site-packages
from model.numba_cache import cache_outside_installed_copy

cache_outside_installed_copy()

from numba import njit  # noqa: E402


@njit(cache=True, nogil=True)
def collisions_kernel(nu, tone, below, above, lo, hi, g, pairs, split):  # pragma: no cover - jit
    """(chips, pairs) bool: pair k collides on chip c.

    ``g`` (chips, n): every impacter's as-built factor; ``split`` (chips, n), or shape
    (0, 0) for none: half the relative difference of a pair's halves.  Each chip's
    impacter k has its silent band [nu_c - below - w, nu_c + above + w] and its tone
    window [t_c - (lo - w), t_c + (hi - w)] with nu_c = nu g, t_c = tone g and
    w = |split| nu_c; a pair collides where either's whole window lies inside the
    other's band.  The operations are NumPy's elementwise ones, one at a time, so
    the booleans are the same bit for bit (no fused or reassociated arithmetic:
    ``fastmath`` is off)."""
    chips = g.shape[0]
    n = g.shape[1]
    m = pairs.shape[0]
    has_split = split.shape[0] > 0
    win_lo = np.empty(n)
    win_hi = np.empty(n)
    band_lo = np.empty(n)
    band_hi = np.empty(n)
    out = np.empty((chips, m), dtype=np.bool_)
    for c in range(chips):
        for k in range(n):
            nu_c = nu[k] * g[c, k]
            t_c = tone[k] * g[c, k]
            wide = abs(split[c, k]) * nu_c if has_split else 0.0
            b_lo = below[k] + wide
            b_hi = above[k] + wide
            w_lo = lo[k] - wide
            w_hi = hi[k] - wide
            win_lo[k] = t_c - w_lo
            win_hi[k] = t_c + w_hi
            band_lo[k] = nu_c - b_lo
            band_hi[k] = nu_c + b_hi
        for q in range(m):
            i = pairs[q, 0]
            j = pairs[q, 1]
            out[c, q] = ((win_lo[i] > band_lo[j] and win_hi[i] < band_hi[j])
                         or (win_lo[j] > band_lo[i] and win_hi[j] < band_hi[i]))
    return out

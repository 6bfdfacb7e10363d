"""The one place a ``seed`` becomes a :class:`numpy.random.Generator`.

``None`` means the default seed :data:`DEFAULT_SEED` (0), everywhere: vibroplan's
results are reproducible unless the caller passes its own Generator.
"""

from __future__ import annotations

import numbers

import numpy as np

#: The seed ``None`` stands for.
DEFAULT_SEED = 0


def as_generator(seed) -> np.random.Generator:
    """A random generator from ``seed``.

    Parameters
    ----------
    seed : None, int or numpy.random.Generator
        ``None`` is :data:`DEFAULT_SEED` (reproducible); a non-negative int gives a
        reproducible stream; a Generator is used as is.

    Returns
    -------
    numpy.random.Generator

    Raises
    ------
    ValueError
        If ``seed`` is negative, a bool or of another type.
    """
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None:
        seed = DEFAULT_SEED
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise ValueError(f"seed must be None, an int or a numpy Generator, {seed!r} was given")
    if seed < 0:
        raise ValueError(f"seed must be a non-negative integer, {seed} was given")
    return np.random.default_rng(int(seed))

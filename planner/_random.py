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


def try_seed(seed: int, index: int) -> int:
    """The seed of a search's ``index``-th retry: ``seed`` itself for index 0, else an
    int drawn from ``SeedSequence([seed, index])``.

    ``seed + index`` would make plan seeds overlap: the second try of seed 2 would be
    the first try of seed 3, so consecutive plan seeds shared most of their designs
    (29 of the default plan's 50 for seeds 2 and 3).  Spawned this way, no two
    (seed, index) pairs share a stream.
    """
    seed, index = int(seed), int(index)
    if seed < 0 or index < 0:
        raise ValueError(f"seed and index must be >= 0, {seed!r} and {index!r} were given")
    if index == 0:
        return seed
    return int(np.random.SeedSequence([seed, index]).generate_state(1, dtype=np.uint64)[0]
               >> np.uint64(1))

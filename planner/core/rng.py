"""The one place a ``seed`` becomes a :class:`numpy.random.Generator`.

``None`` means the default seed :data:`DEFAULT_SEED` (0), everywhere: vibroplan's
results are reproducible unless the caller passes its own Generator.
"""

from __future__ import annotations

import numbers
import struct

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


def chip_seed(seed: int, scale: float, chip: int) -> np.random.SeedSequence:
    """The seed sequence of chip ``chip`` of a yield study at sigma scale ``scale``: the
    run's seed, the scale's exact value (its IEEE 754 bits) and the chip's index.

    Seeded by the scale's value, not by its place in a list of scales: a scale's chips
    are the same alone or listed among others, and two scales that differ in the 7th
    digit are two streams.

    >>> chip_seed(0, 1.0000001, 3).entropy != chip_seed(0, 1.0000002, 3).entropy
    True
    """
    bits = struct.unpack("<Q", struct.pack("<d", float(scale) + 0.0))[0]  # -0.0 is 0.0
    return np.random.SeedSequence([int(seed), int(bits), int(chip)])

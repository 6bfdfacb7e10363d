"""Yield statistics that know nothing of a plan: the 95 % confidence interval of a
measured yield (the Wilson score interval of a binomial proportion, also
:mod:`planner.manufacturability`'s predicted yield's) and the margin in sigmas that a
target yield asks of many independent pairs (:func:`z_for`: the tolerance channel grid's
and the assignment's)."""

from __future__ import annotations

import math

#: z of the two-sided 95 % normal quantile.
Z95 = 1.959963984540054


def wilson_interval(passed: int, n: int, z: float = Z95) -> list[float]:
    """Wilson score interval [low, high] of a binomial proportion ``passed / n``.

    >>> [round(x, 4) for x in wilson_interval(10, 10)]
    [0.7225, 1.0]
    """
    if n <= 0:
        return [0.0, 1.0]
    p = passed / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    # exact ends at 0 and n passes (the formula leaves round-off there)
    return [0.0 if passed == 0 else max(0.0, centre - half),
            1.0 if passed == n else min(1.0, centre + half)]


def z_for(target_yield: float, pairs: int) -> float:
    """The normal quantile z that makes ``pairs`` independent one-sided margins of z sigma
    all hold with probability ``target_yield``: 1 - p per pair, (1 - p)^pairs = target.

    >>> round(z_for(0.95, 49), 3)
    3.077
    """
    # scipy.stats.norm.isf(p) is -ndtri(p), bit for bit; scipy.special alone spares a
    # plan's re-run the import of scipy.stats (~0.5 s), which nothing else of it needs
    from scipy.special import ndtri

    if not 0.0 < target_yield < 1.0:
        raise ValueError(f"target_yield must be in (0, 1), {target_yield!r} was given")
    pairs = max(int(pairs), 1)
    p = -math.expm1(math.log(target_yield) / pairs)
    return float(-ndtri(p))

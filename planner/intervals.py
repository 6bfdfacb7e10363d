"""The 95 % confidence interval of a yield: the Wilson score interval of a binomial
proportion (also :func:`planner.manufacturability`'s predicted yield's)."""

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

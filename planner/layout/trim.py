"""Trim tabs: plate area drawn to be cut away after fabrication, raising nu_n in steps.

A measured impacter whose natural frequency came out low is trimmed *up* by cutting
plate mass away (a laser or a probe breaks a tab off); one that came out high is
trimmed *down* by cutting into a beam (less stiffness), which needs no drawn feature.
The spec's ``trim:`` section (``range_pct``, ``direction``, ``precision_pct``) says how
far and how finely; for ``direction: up`` every plate gets ``n`` tabs, all part of the
designed plate area A (the as-drawn impacter is the designed one), sized so that
removing the first ``k`` of them raises nu_n by the factor (1 + range)^(k / n):
equal steps of at most ``precision_pct``, and the whole range once all are gone.

Through eq. (2) only the mass moves (k of eq. (4) depends on the beams alone), so
nu_n ~ m^(-1/2): the mass after ``k`` tabs is m (1 + range)^(-2 k / n) and tab ``k``
has the area (m_(k-1) - m_k) / (rho t).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: The trim directions: ``up`` removes plate mass (tabs), ``down`` cuts a beam.
DIRECTIONS = ("up", "down")


@dataclass(frozen=True)
class TrimPlan:
    """The spec's ``trim:`` section in SI fractions.

    Attributes
    ----------
    range : float
        How far a trim may move nu_n, as a fraction (``range_pct`` / 100) [-].
    precision : float
        The largest step of one cut, as a fraction [-].
    direction : str
        ``"up"`` or ``"down"``.
    """

    range: float
    precision: float
    direction: str

    @property
    def tabs(self) -> int:
        """Tabs per plate: the fewest equal frequency steps of at most ``precision``
        that span ``range`` (0 for ``down``)."""
        if self.direction != "up":
            return 0
        return max(1, math.ceil(math.log1p(self.range) / math.log1p(self.precision) - 1e-9))


def trim_from_spec(spec: dict) -> TrimPlan | None:
    """The ``trim`` section of a plan.json spec (a dict), or None when it has none.

    Read defensively: the section is not part of the validated spec model yet.

    Raises
    ------
    ValueError
        A malformed section, naming the field.

    Examples
    --------
    >>> trim_from_spec({"trim": {"range_pct": 10, "direction": "up", "precision_pct": 1}}).tabs
    10
    """
    section = spec.get("trim")
    if section is None:
        return None
    if not isinstance(section, dict):
        raise ValueError(f"spec.trim must be a mapping, {section!r} was given")

    def pct(key, default=None):
        value = section.get(key, default)
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"spec.trim.{key} must be a number, {value!r} was given") from None
        if not (math.isfinite(value) and 0.0 < value < 100.0):
            raise ValueError(f"spec.trim.{key} must be in (0, 100) %, {value!r} was given")
        return value / 100.0

    direction = section.get("direction")
    if direction not in DIRECTIONS:
        raise ValueError(f"spec.trim.direction must be one of {', '.join(DIRECTIONS)}, "
                         f"{direction!r} was given")
    rng = pct("range_pct")
    precision = pct("precision_pct") if section.get("precision_pct") is not None else rng
    if precision > rng:
        raise ValueError(f"spec.trim.precision_pct ({100 * precision:g}) must not exceed "
                         f"range_pct ({100 * rng:g})")
    return TrimPlan(rng, precision, direction)


def tab_areas(mass: float, density: float, thickness: float, trim: TrimPlan) -> tuple:
    """Areas [m^2] of one plate's tabs, in cutting order.

    Parameters
    ----------
    mass : float
        The impacter's mass m of eq. (2) [kg].
    density : float
        rho [kg/m^3].
    thickness : float
        The plate's thickness t [m].
    trim : TrimPlan

    Returns
    -------
    tuple of float
        Empty unless ``trim.direction`` is ``up``.

    Examples
    --------
    >>> a = tab_areas(1.0, 1.0, 1.0, TrimPlan(0.21, 0.1, "up"))
    >>> [round(x, 4) for x in a]      # nu_n up 21 % in two steps of 10 %: m -> m / 1.21^2
    [0.1736, 0.1434]
    """
    n = trim.tabs
    if n == 0:
        return ()
    masses = [mass * (1.0 + trim.range) ** (-2.0 * k / n) for k in range(n + 1)]
    return tuple((masses[k - 1] - masses[k]) / (density * thickness) for k in range(1, n + 1))

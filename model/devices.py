"""Impacter and slider parameters: value objects built from the paper's eqs. (2)-(4).

Notes
-----
**The paper's inconsistency.**  Eq. (4) as printed does not reproduce the natural
frequencies the paper reports: Fig. 7's device (A = 1.5e4 um^2, w = 4 um,
l = 1242 um) gives about 4.6 kHz with (2) and (4) where the paper says 5.2 kHz,
and Table II's designs give 16.1 and 6.0 kHz where the table says 5.82 and
2.04 kHz.  We implement (2)-(4) exactly as printed and let every impacter take a
natural-frequency override, k = m (2 pi nu_n)^2 (:meth:`Impacter.with_natural_frequency`,
or ``natural_frequency=`` in :meth:`Impacter.from_geometry`), which is what the paper
itself does in Section IV ("k obtained from the natural frequency of the actual device").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

# Process and environment constants (Table I and Section III-B), SI units.
DENSITY = 2330.0                #: rho, LPCVD poly-Si [kg/m^3]
YOUNGS_MODULUS = 169e9          #: E, poly-Si [Pa]
BEAM_HEIGHT = 2.0e-6            #: h, beam height = Poly1 thickness [m]
MASS_THICKNESS = 3.5e-6         #: t, impacter mass thickness, Poly1 + Poly2 [m]
SUBSTRATE_GAP = 0.75e-6         #: d, gap between substrate and mass [m]
BEAM_ANGLE = math.radians(15.0)  #: phi, half angle between the V-beam segments [rad]
IMPACT_ANGLE = math.pi / 4      #: theta, impact angle [rad]
RESTITUTION = 0.5               #: e, poly-Si side walls [-]
STATIC_FRICTION = 20e-6         #: F_s [N]
DYNAMIC_FRICTION = 5e-6         #: F_d [N]
VISCOSITY_VACUUM = 0.0          #: mu at 10 mTorr [Pa s]
VISCOSITY_AIR = 0.0179e-3       #: mu of air at room temperature [Pa s]
SLIDER_THICKNESS = 2.0e-6       #: Poly1 slider [m]


# Plausibility at the API's edge.  Everything here is in SI units; a value that is
# impossible in its documented unit is almost always a value in another unit (um for
# m, kHz for Hz), which would otherwise give nonsense without a word.
MIN_FREQUENCY = 10.0            #: below this a frequency [Hz] was probably given in kHz
MAX_AREA = 1e-4                 #: 1 cm^2: an area [m^2] above it was probably in um^2
MAX_WIDTH = 1e-3                #: 1 mm: a beam width, thickness or gap [m] above it was in um
MAX_LENGTH = 1e-2               #: 1 cm: a beam length [m] (Fig. 7's is 1.242 mm)
MAX_AMPLITUDE = 1e-2            #: 1 cm: a drive amplitude [m] above it was in um
# (1 cm, not 1 mm: the chattering stress cases press an impacter on its wall with a
# 2.3 mm, 100 Hz shake; a die moved more than a centimetre is no longer a MEMS drive)
UNUSUAL_FREQUENCY = 10e6        #: above 10 MHz a MEMS resonance is unusual: warned [Hz]
UNUSUAL_AMPLITUDE = 1e-3        #: a die displacement above 1 mm is unusual: warned [m]


class UnitWarning(UserWarning):
    """A value that is possible but unusual in its documented SI unit."""


def _plausible(name, value, unit, *, low=None, high=None, warn_above=None):
    """Check ``value`` [unit] against the bounds of physical plausibility.

    Raises a ValueError saying which unit was expected when ``value`` lies outside
    [low, high]; warns (:class:`UnitWarning`) above ``warn_above``.
    """
    if low is not None and value < low:
        raise ValueError(f"{name} = {value!r} {unit} is implausibly small: {name} is in {unit} "
                         f"(SI), at least {low:g} {unit}; was it given in another unit?")
    if high is not None and value > high:
        raise ValueError(f"{name} = {value!r} {unit} is implausibly large: {name} is in {unit} "
                         f"(SI), at most {high:g} {unit}; was it given in another unit "
                         "(um for m)?")
    if warn_above is not None and value > warn_above:
        import warnings

        warnings.warn(f"{name} = {value!r} {unit} is unusually large for a MEMS device "
                      f"(above {warn_above:g} {unit}); {name} is in {unit}", UnitWarning,
                      stacklevel=4)
    return value


def _number(name, value):
    """``value`` as a float, or a ValueError naming ``name``."""
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, {value!r} was given") from None


def _positive(name, value, allow_zero=False):
    value = _number(name, value)
    if not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be finite and {bound}, {value!r} was given")
    return value


def _acute(name, value):
    """An angle in [0, pi/2) [rad]: at pi/2 the V-beam's cos(phi) and the impact's cos(theta) vanish."""
    value = _number(name, value)
    if not (math.isfinite(value) and 0.0 <= value < math.pi / 2):
        raise ValueError(f"{name} must be in [0, pi/2) rad, {value!r} was given")
    return value


@dataclass(frozen=True)
class Geometry:
    """Impacter geometry p = (A, w, l, c) of the paper's design problem (13)-(17).

    Attributes
    ----------
    area : float
        Planar area A of the impacter mass [m^2].
    width : float
        Width w of the V-beams [m].
    length : float
        Total length l of the two segments of a V-beam [m].
    gap : float
        Distance c from the impacter tip to the slider wall [m].
    """

    area: float
    width: float
    length: float
    gap: float


@dataclass(frozen=True)
class Impacter:
    """One impacter of a pair, as the lumped model of eq. (1).

    Parameters
    ----------
    mass : float
        m [kg].
    stiffness : float
        k [N/m].
    damping : float
        b [N s/m].
    gap : float
        Distance c from the tip to the slider wall [m].
    impact_angle : float, default pi/4
        theta [rad], in [0, pi/2).
    restitution : float, default 0.5
        Coefficient of restitution e of eq. (8), in [0, 1].
    geometry : Geometry, optional
        The geometry the parameters came from, if any (for reports).

    Examples
    --------
    >>> imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6)
    >>> round(imp.natural_frequency)           # eq. (4) as printed
    4644
    >>> round(imp.with_natural_frequency(5200.0).natural_frequency)
    5200
    """

    mass: float
    stiffness: float
    damping: float
    gap: float
    impact_angle: float = IMPACT_ANGLE
    restitution: float = RESTITUTION
    geometry: Geometry | None = field(default=None, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "mass", _positive("mass", self.mass))
        object.__setattr__(self, "stiffness", _positive("stiffness", self.stiffness))
        object.__setattr__(self, "damping", _positive("damping", self.damping, allow_zero=True))
        object.__setattr__(self, "gap", _positive("gap", self.gap))
        object.__setattr__(self, "impact_angle", _acute("impact_angle", self.impact_angle))
        e = _number("restitution", self.restitution)
        if not (math.isfinite(e) and 0.0 <= e <= 1.0):
            raise ValueError(f"restitution must be in [0, 1], {e!r} was given")
        object.__setattr__(self, "restitution", e)
        # no plausibility bounds here: the raw (m, k, b, c) form is also the numerical
        # analyst's (m = 1, a wall 1 m away that is never reached); the geometric
        # constructors below, which take lab quantities, check the units

    @classmethod
    def from_geometry(cls, area, width, length, gap, *, thickness=MASS_THICKNESS,
                      beam_height=BEAM_HEIGHT, density=DENSITY,
                      youngs_modulus=YOUNGS_MODULUS, viscosity=VISCOSITY_VACUUM,
                      substrate_gap=SUBSTRATE_GAP, beam_angle=BEAM_ANGLE,
                      impact_angle=IMPACT_ANGLE, restitution=RESTITUTION,
                      natural_frequency=None):
        """Impacter from its geometry by eqs. (2)-(4).

        Parameters
        ----------
        area, width, length, gap : float
            A [m^2], w [m], l [m], c [m].
        thickness : float
            Mass thickness t [m] (Poly1 + Poly2 by default).
        beam_height : float
            Beam height h [m].
        density, youngs_modulus : float
            rho [kg/m^3], E [Pa].
        viscosity : float
            mu [Pa s]: 0 in vacuum (Table I), 1.79e-5 in air.
        substrate_gap : float
            d [m].
        beam_angle : float
            phi [rad], in [0, pi/2).
        impact_angle : float
            theta [rad], in [0, pi/2).
        restitution : float
            e [-], in [0, 1].
        natural_frequency : float, optional
            If given, k = m (2 pi nu_n)^2 replaces eq. (4) [Hz].

        Raises
        ------
        ValueError
            Naming the argument, if a length, area or material constant is not finite
            and > 0 (``viscosity`` may be 0), an angle is outside [0, pi/2) or ``e``
            outside [0, 1].  Every argument is checked here, before it is combined into
            m, b and k, so the message names what the caller passed.  Values that are
            impossible in their SI unit are refused too, saying which unit was
            expected: an area above 1 cm^2, a width, thickness or gap above 1 mm, a
            length above 1 cm, a natural frequency below 10 Hz (a call in um or kHz).

        Notes
        -----
        m = rho A t + 2 rho h w l          (2)
        b = mu A / d                       (3)
        k = E h (w/l)^3 (4/cos phi) (2/cos phi + 1)   (4)
        """
        area = _plausible("area", _positive("area", area), "m^2", high=MAX_AREA)
        width = _plausible("width", _positive("width", width), "m", high=MAX_WIDTH)
        length = _plausible("length", _positive("length", length), "m", high=MAX_LENGTH)
        gap = _plausible("gap", _positive("gap", gap), "m", high=MAX_WIDTH)
        thickness = _plausible("thickness", _positive("thickness", thickness), "m",
                               high=MAX_WIDTH)
        beam_height = _plausible("beam_height", _positive("beam_height", beam_height), "m",
                                 high=MAX_WIDTH)
        density = _positive("density", density)
        youngs_modulus = _positive("youngs_modulus", youngs_modulus)
        viscosity = _positive("viscosity", viscosity, allow_zero=True)
        substrate_gap = _positive("substrate_gap", substrate_gap)
        beam_angle = _acute("beam_angle", beam_angle)
        if natural_frequency is not None:
            natural_frequency = _plausible(
                "natural_frequency", _positive("natural_frequency", natural_frequency), "Hz",
                low=MIN_FREQUENCY, warn_above=UNUSUAL_FREQUENCY)
        mass = density * area * thickness + 2.0 * density * beam_height * width * length
        damping = viscosity * area / substrate_gap
        cphi = math.cos(beam_angle)
        stiffness = (youngs_modulus * beam_height * (width / length) ** 3
                     * (4.0 / cphi) * (2.0 / cphi + 1.0))
        if natural_frequency is not None:
            stiffness = mass * (2.0 * math.pi * natural_frequency) ** 2
        return cls(mass, stiffness, damping, gap, impact_angle, restitution,
                   Geometry(area, width, length, gap))

    def with_natural_frequency(self, hz):
        """A copy with k = m (2 pi hz)^2 [hz in Hz, at least 10 Hz]."""
        hz = _plausible("natural_frequency", _positive("natural_frequency", hz), "Hz",
                        low=MIN_FREQUENCY, warn_above=UNUSUAL_FREQUENCY)
        return replace(self, stiffness=self.mass * (2.0 * math.pi * hz) ** 2)

    @property
    def natural_frequency(self):
        """Undamped natural frequency sqrt(k/m) / (2 pi) [Hz]."""
        return math.sqrt(self.stiffness / self.mass) / (2.0 * math.pi)

    @property
    def omega_n(self):
        """Undamped natural angular frequency [rad/s]."""
        return math.sqrt(self.stiffness / self.mass)

    @property
    def sigma(self):
        """b / (2 m) [1/s]."""
        return self.damping / (2.0 * self.mass)

    @property
    def damping_ratio(self):
        """b / (2 sqrt(k m)) [-]."""
        return self.damping / (2.0 * math.sqrt(self.stiffness * self.mass))


@dataclass(frozen=True)
class PairHalves:
    """An impacter pair whose two cantilevers differ (a fabricated pair).

    The paper's impacter is a pair of identical cantilevers that strike the slider
    together, modelled as one oscillator whose kicks count twice (:class:`Impacter`;
    the gain 2 (m/M) cos(theta) of eq. (10)).  Fabricated, the two halves differ by the
    local scatter: each is its own oscillator of eq. (1), and each strikes the same slider
    alone, with its own mass, its kicks counting once.  Use :func:`pair_of` to build one:
    two equal halves are an :class:`Impacter` again, so that identical halves reproduce
    the symmetric pair's results exactly.

    Parameters
    ----------
    a, b : Impacter
        The two halves.

    Examples
    --------
    >>> imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6)
    >>> pair_of(imp, imp) is imp
    True
    >>> p = pair_of(imp, imp.with_natural_frequency(4700.0))
    >>> round(p.natural_frequency)
    4672
    """

    a: Impacter
    b: Impacter

    def __post_init__(self):
        for name in ("a", "b"):
            if not isinstance(getattr(self, name), Impacter):
                raise ValueError(f"{name} must be a model.Impacter, "
                                 f"{type(getattr(self, name)).__name__} was given")

    @property
    def halves(self):
        """((half, share), ...): each half and the fraction of the pair it is (1/2)."""
        return ((self.a, 0.5), (self.b, 0.5))

    @property
    def natural_frequency(self):
        """The mean of the halves' natural frequencies [Hz]."""
        return 0.5 * (self.a.natural_frequency + self.b.natural_frequency)

    @property
    def gap(self):
        """The larger of the halves' gaps [m] (the initial states span both)."""
        return max(self.a.gap, self.b.gap)

    @property
    def mass(self):
        """The mean of the halves' masses [kg] (one cantilever's, as Impacter.mass)."""
        return 0.5 * (self.a.mass + self.b.mass)


def pair_of(a, b):
    """The pair of two halves: ``a`` itself when they are equal (the symmetric pair of
    the paper), else a :class:`PairHalves`."""
    return a if a == b else PairHalves(a, b)


def halves(impacter):
    """The halves of a pair as ((Impacter, share), ...): ((impacter, 1.0),) for the
    symmetric pair (one oscillator whose kicks count for both cantilevers), the two
    halves at 1/2 each for :class:`PairHalves`."""
    if isinstance(impacter, PairHalves):
        return impacter.halves
    return ((impacter, 1.0),)


@dataclass(frozen=True)
class Slider:
    """The linear slider of eqs. (6)-(7).

    Parameters
    ----------
    mass : float
        M [kg].
    damping : float, default 0.0
        B [N s/m].
    static_friction : float, default 20e-6
        F_s [N] (Table I).
    dynamic_friction : float, default 5e-6
        F_d [N] (Table I).
    """

    mass: float
    damping: float = 0.0
    static_friction: float = STATIC_FRICTION
    dynamic_friction: float = DYNAMIC_FRICTION

    def __post_init__(self):
        object.__setattr__(self, "mass", _positive("mass", self.mass))
        object.__setattr__(self, "damping", _positive("damping", self.damping, allow_zero=True))
        object.__setattr__(self, "static_friction",
                           _positive("static_friction", self.static_friction, allow_zero=True))
        object.__setattr__(self, "dynamic_friction",
                           _positive("dynamic_friction", self.dynamic_friction, allow_zero=True))

    @classmethod
    def from_geometry(cls, area, thickness=SLIDER_THICKNESS, *, density=DENSITY,
                      viscosity=VISCOSITY_VACUUM, substrate_gap=SUBSTRATE_GAP,
                      static_friction=STATIC_FRICTION, dynamic_friction=DYNAMIC_FRICTION):
        """Slider from its planar area [m^2] and thickness [m], "similarly to (2) and (3)".

        M = rho A t_s and B = mu A / d.  Every argument is checked before it is combined,
        so a ValueError names what the caller passed.
        """
        area = _plausible("area", _positive("area", area), "m^2", high=MAX_AREA)
        thickness = _plausible("thickness", _positive("thickness", thickness), "m",
                               high=MAX_WIDTH)
        density = _positive("density", density)
        viscosity = _positive("viscosity", viscosity, allow_zero=True)
        substrate_gap = _positive("substrate_gap", substrate_gap)
        return cls(density * area * thickness, viscosity * area / substrate_gap,
                   static_friction, dynamic_friction)

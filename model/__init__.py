"""vibroplan's model: the per-device physics of Saitou, Wang & Wou (JMEMS 2000).

Impacter and slider parameters from eqs. (2)-(4), the substrate drive as a sum of
tones, an exact event-driven simulator (closed form between impacts, rigorous
impact detection, chattering and sticking), the paper's RK4 as a reference, the
response r of eq. (12) and parallel sweeps.  SI units throughout.
"""

# before any kernel is decorated: an installed copy caches outside site-packages
from model.numba_cache import cache_outside_installed_copy

cache_outside_installed_copy()

from model.devices import (  # noqa: E402
    Geometry,
    Impacter,
    PairHalves,
    Slider,
    UnitWarning,
    halves,
    pair_of,
)
from model.drive import POWER, Drive, amplitude_from_power  # noqa: E402
from model.impacter import (  # noqa: E402
    METHODS,
    ImpactResult,
    SolverWarning,
    response,
    responses,
    simulate,
    sweep,
)
from model.slider import (  # noqa: E402
    CONTACTS,
    Kicks,
    SliderResult,
    kick,
    simulate_slider,
    slider_motion,
)

__all__ = [
    "CONTACTS", "Drive", "Geometry", "Impacter", "ImpactResult", "Kicks", "METHODS", "POWER",
    "PairHalves", "Slider", "SliderResult", "SolverWarning", "UnitWarning",
    "amplitude_from_power", "halves", "kick", "pair_of", "response",
    "responses", "simulate", "simulate_slider", "slider_motion", "sweep",
]

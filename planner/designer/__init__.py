"""Impacter design by the paper's max-min problem, eqs. (13)-(18).

For an impacter with target drive frequency nu and forbidden frequencies {nu_j}:

    maximise over p = (A, w, l, c)     min_{x0 in D} r(x0, p, nu)                 (13)
    subject to                         max_{x0 in D} r(x0, p, nu_j) = 0  for all j  (14)
                                       D = {x(t0) in [-c, c], v(t0) = 0}          (15), (18)
                                       p in P (bounds, (17) below)                (16), (17)

r is the response of eq. (12), computed by the exact event-driven simulator of
:mod:`model`; k, m and b follow from the geometry by eqs. (2)-(4) *as printed* (the
design variables really are geometry, see :mod:`model.devices` on the paper's
inconsistency).  Only impacter dynamics enter the objective, as the paper argues;
the slider is simulated once, for the report.

Public API
----------
:func:`design_impacter`, :func:`design_pair`, :func:`response_band`,
:func:`response_curves`, :func:`x0_grid`, :class:`DesignBounds`, :class:`DesignResult`,
:class:`PairDesign`, :data:`BUDGETS`, :func:`recheck_design`, :func:`response_alone`.

Layout of this package (each module imports only those listed above it)

- :mod:`~planner.designer.bounds`: :class:`DesignBounds`, the paper's lower bounds (17)
  and the documented upper bounds.
- :mod:`~planner.designer.budget`: :class:`Budget` and the named :data:`BUDGETS`.
- :mod:`~planner.designer.result`: :class:`DesignResult`, :class:`PairDesign`.
- :mod:`~planner.designer.runs`: the drive convention (:class:`Ensemble`, one tone per
  frequency), the x0 grid of D (:func:`x0_grid`) and batched calls of :mod:`model`.
- :mod:`~planner.designer.response`: response analysis -- :func:`response_band`,
  :func:`response_curves` and the margins of a finished design.
- :mod:`~planner.designer.problem`: the optimisation problem -- search coordinates,
  cached simulations, the tiered energy.
- :mod:`~planner.designer.search`: Sobol seeding, annealing chains, SQP polish, the
  re-checks and the exchange method.
- :mod:`~planner.designer.design`: :func:`design_impacter`, :func:`design_pair`.
- :mod:`~planner.designer.recheck`: :func:`recheck_design`, a finished design kept when
  some of its forbidden tones or drives change, re-checked where they changed;
  :func:`response_alone`, a design's response to its own tone without the summed drives.

Notes
-----
**Search coordinates.**  The annealer moves in z in [0, 1]^4, the normalised logarithms
of (A, w, nu_n, c); the beam length l is recovered from (A, w, nu_n) through eqs. (2)
and (4) (k = m (2 pi nu_n)^2 has exactly one root in l, since k falls and m grows with
l).  This is a smooth bijection of the paper's p, so the optimum is the same, but it
decouples the two things the response depends on: where the response curve sits
(nu_n and c set the dynamics per unit mass; b / 2m is nearly fixed by mu / (rho t d))
and how large it is (r is proportional to m).  A move in A at fixed nu_n leaves the
curve in place, which a random walk in (A, l) would almost never do.  nu_n is searched
in NATURAL_RATIO times nu; a proposal whose l would leave its bounds is projected onto
them (nu_n then follows from the clipped l).

The gap is not searched in metres but as kappa = c / X, X the linear steady-state
amplitude of eq. (1) at the target tone (no wall), in GAP_AMPLITUDE_RATIO, then clipped
to the gap bounds. The feasible gaps form a sliver (silent under a neighbour 2-3 % away
needs c not far below X, responding from rest needs c below X) whose position in c moves
with A and nu_n but hardly in kappa: the default plan's designs, 4.5-51 kHz, all sit at
kappa = 0.60-0.65. Searched in c, a first fast try found no feasible design on 16 of the
default plan's 50 impacters (and escalated to wider searches on 32); in kappa, on none
(none escalated). A proposal over the mass cap is projected onto it (the area lowered
until m meets the cap), where the fastest designs sit, instead of being penalised.

**Constraint handling.**  The annealer minimises a tiered energy (feasibility first,
Deb's rule made scalar):

- a design that responds at a forbidden frequency from some x0 of the grid:
  E = 2 PENALTY + (fraction of x0 that respond at the first violated frequency);
- a feasible design that does not respond at nu from every x0:
  E = PENALTY + (fraction of x0 with r = 0);
- a feasible design that responds from every x0: E = -ln(r_min / 1 N).

PENALTY dwarfs any difference of ln r, so a chain that has found the feasible region
never leaves it, while the fractions give infeasible chains a slope towards
feasibility.  The SQP polish (SLSQP) minimises the same energy with the constraint
also passed explicitly (``-violation >= 0``); r is discontinuous (the paper's Fig. 9),
so its finite-difference gradients are only locally meaningful and its line search
is guarded by the cache: every point it evaluates joins the archive, and the best
feasible point seen, annealed or polished, wins.

**The x0 grid.**  D is sampled on a uniform grid of u = x0 / c in [-1, 1] (odd point
count, so -c, 0 and +c are nodes), plus points just inside the wall, and the target
response is refined by bisection wherever it jumps between neighbours (Fig. 9's
discontinuities, the paper's "bifurcations").  x0 = +c is evaluated at
c (1 - WALL_OFFSET): the limit x0 -> c from inside is the stricter case (from just
inside, a drive that presses on the wall at t0 produces counted chatter; a start
stuck on the wall produces none).  It also kept the designer clear of a solver fault
at x0 == gap exactly (spurious zero-time impacts of noise velocity when the net force
pulls away from the wall), fixed in the kernels since.

**Constraint checks are cheap.**  A forbidden frequency is checked with
``stop_at_first`` (a run stops at its first counted impact), frequencies are tried
nearest the target first with move-to-front on a violation, the check stops at the
first violated frequency, and every kernel call is cached by its inputs.  With the
"fast" budget only the ``active_forbidden`` most dangerous frequencies are checked
during the search; the final design is checked against all of them, and any that it
violates joins the active set for another search round (constraint generation).  A
check that :func:`model.bounds.silence_bound` proves silent (every start, every phasing,
any window) is answered without a run; the designs are the same with it and without it
(``problem.SILENCE_BOUND``), the runs it saves are the cheap ones.

**The family.**  A design may be given designs of the same spec at other tones
(``design_impacter(family=)``, the plan passes the reach probes' designs): scaled to its
tone (the same A, width or sensitivity, nu_n / tone and kappa) they join the first
round's Sobol samples, and the chains walk ``Budget.family_steps`` moves from the best
(with matched sensitivities a spec's designs are close to one family; on the default
plan 154 candidate evaluations a design instead of 624, benchmarks/results/
design_family.md).

**Re-checks.**  The best designs of the archive are re-checked on a grid about eight
times finer (with more refinement) and over a window LONG_WINDOW_FACTOR times longer;
the design reported is the best that passes both.  ``checks`` in the result says
how many designs passed on the optimiser's grid but failed a re-check.

References
----------
K. Saitou, D.-A. Wang, S. J. Wou, "Externally resonated linear microvibromotor for
microassembly", J. Microelectromech. Syst. 9(3), 2000, Section III-C.

Examples
--------
>>> from planner.designer import design_impacter
>>> res = design_impacter(6000.0, forbidden=(3000.0,), budget="fast", seed=1)  # doctest: +SKIP
>>> res.feasible, res.r_min_n > 0                                              # doctest: +SKIP
(True, True)
"""

from __future__ import annotations

from planner.designer.bounds import DEFAULT_UPPER, PAPER_LOWER, UM, DesignBounds
from planner.designer.budget import BUDGETS, Budget
from planner.designer.design import GUARD, design_impacter, design_pair
from planner.designer.problem import NATURAL_RATIO, natural_ratio
from planner.designer.recheck import recheck_design, response_alone
from planner.designer.response import response_band, response_curves
from planner.designer.result import DesignResult, PairDesign
from planner.designer.runs import Ensemble, x0_grid

__all__ = ["BUDGETS", "Budget", "DEFAULT_UPPER", "DesignBounds", "DesignResult", "Ensemble",
           "GUARD", "NATURAL_RATIO", "PAPER_LOWER", "PairDesign", "UM", "design_impacter",
           "design_pair", "natural_ratio", "recheck_design", "response_alone", "response_band",
           "response_curves", "x0_grid"]

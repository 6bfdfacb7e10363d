"""How hard the designer searches: :class:`Budget` and the named :data:`BUDGETS`."""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class Budget:
    """How hard the designer searches; named budgets are in :data:`BUDGETS`.

    Attributes
    ----------
    x0_points : int
        Uniform x0 grid of the optimiser's objective over [-c, c] (odd: -c, 0 and +c
        are nodes).
    forbidden_x0_points : int
        Uniform x0 grid of the optimiser's constraint checks (odd).
    refine_levels : int
        Bisection levels where the target response jumps between neighbours.
    initial : int
        Scrambled-Sobol samples that seed the annealing chains.
    chains : int
        Annealing chains, started from the best distinct initial samples.
    anneal_steps : int
        Moves per chain.
    t_start, t_end : float
        Geometric temperature schedule, in units of ln r.
    step : float
        Initial move size in z (adapted to the acceptance rate).
    sqp_maxiter : int
        SLSQP iterations of the polish (0: no polish).
    verify_x0_points, verify_refine_levels : int
        Grid and refinement of the re-check.
    rounds : int
        Search rounds: after the first, the x0 where a re-check failed join the
        optimiser's grids and the search resumes from the archive (exchange method).
    resume_steps : int
        Annealing moves per chain in a resumed round.
    archive : int
        Distinct feasible designs kept for the re-check.
    active_forbidden : int or None
        Forbidden frequencies checked during the search (the nearest to the target);
        None checks all.  The final design is always checked against all.
    margin_points : int
        Frequencies per side of each forbidden frequency scanned for its margin (the
        nearest responding one is then bisected).
    margin_tol : float
        Tolerance of the margins' bisection, relative to the forbidden frequency.
    guard_points : int
        Frequencies checked across each forbidden frequency's guard band (odd).
    escalations : int
        Further searches, each with 4x the samples and 2x the moves of the last, when a
        search finds no feasible design at all.
    area_face : float
        Share of the initial samples placed at the largest area (see ``_search``).
    family_steps : int or None
        Moves per chain in the first round when the design is given its family
        (designs of the same spec at other tones, ``design_impacter``'s ``family``): the
        chains then start next to a good design and need a short walk (None:
        ``anneal_steps``).  On the default plan 60 of the fast budget's 160 halved the
        design stage (every design still feasible, speeds 0.16-0.37 mm/s).
    violations_counted : int or None
        The constraint check of a candidate stops at this many violated frequencies
        (None: checks all): 1 is cheapest; more gives the annealer a slope towards
        feasibility when many frequencies are forbidden.
    """

    x0_points: int = 65
    forbidden_x0_points: int = 129
    refine_levels: int = 3
    initial: int = 128
    chains: int = 4
    anneal_steps: int = 1000
    t_start: float = 0.3
    t_end: float = 0.003
    step: float = 0.08
    sqp_maxiter: int = 20
    verify_x0_points: int = 1025
    verify_refine_levels: int = 5
    rounds: int = 4
    resume_steps: int = 150
    archive: int = 6
    active_forbidden: int | None = None
    margin_points: int = 48
    margin_tol: float = 1e-4
    guard_points: int = 5
    escalations: int = 1
    area_face: float = 0.25
    violations_counted: int | None = 1
    family_steps: int | None = None

    def __post_init__(self):
        for name in ("x0_points", "forbidden_x0_points", "verify_x0_points"):
            n = getattr(self, name)
            if n < 3 or n % 2 == 0:
                raise ValueError(f"{name} must be odd and >= 3, {n!r} was given")
        if self.verify_x0_points < max(self.x0_points, self.forbidden_x0_points):
            raise ValueError("verify_x0_points must be >= the optimiser's grids")
        for name in ("initial", "chains", "archive"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, {getattr(self, name)!r} was given")
        if not 0 < self.t_end <= self.t_start:
            raise ValueError("temperatures must satisfy 0 < t_end <= t_start")


#: Named budgets.  "full" (the CLI's default) meets the Table II check; "fast" is for
#: the array planner's ~50 designs (aim ~1 s each, up to ~50 forbidden frequencies).
BUDGETS = {
    "full": Budget(),
    "fast": Budget(x0_points=17, forbidden_x0_points=17, refine_levels=1, initial=16,
                   chains=1, anneal_steps=160, t_start=0.3, t_end=0.01, step=0.1,
                   sqp_maxiter=4, verify_x0_points=129, verify_refine_levels=3, rounds=3,
                   resume_steps=40, archive=3, active_forbidden=6, margin_points=8,
                   margin_tol=2e-3, guard_points=3, escalations=2, area_face=0.5,
                   violations_counted=3, family_steps=60),
}


def widened(budget, level):
    """``budget`` searching wider, for a design whose earlier tries were infeasible.

    Level 1 draws 4x the initial samples and runs 3x the chains, each 2x as long;
    level 2 (and above) 8x the samples, 4x the chains, 2.5x as long, and re-checks
    twice the archive.  A widened search does not escalate again when it finds no
    feasible design on its grid (``escalations`` 0): it is the escalation, and an array
    plan's loop changes the design's inputs instead (a vacuum design escalated to 46
    first tries' worth of candidates).  The fast budget's single chain settles in the
    first basin it finds; where the feasible region is small (the default plan's lowest tone, 4.3 kHz
    with a neighbour 500 Hz away: 0 of 4 fast tries feasible) the wider searches found
    it in 2 of 3 and 2 of 2 tries, at 2-4x the cost of a fast try.

    Parameters
    ----------
    budget : str or Budget
        A name of :data:`BUDGETS` or a :class:`Budget`.
    level : int
        0 returns the budget unchanged.

    Returns
    -------
    Budget
    """
    b = _as_budget(budget)
    level = int(level)
    if level <= 0:
        return b
    if level == 1:
        return replace(b, initial=4 * b.initial, chains=3 * b.chains,
                       anneal_steps=2 * b.anneal_steps, escalations=0)
    return replace(b, initial=8 * b.initial, chains=4 * b.chains,
                   anneal_steps=round(2.5 * b.anneal_steps), archive=2 * b.archive,
                   escalations=0)


def search_cost(budget) -> int:
    """Candidate evaluations of one search round: initial samples plus annealing moves
    (the cost unit that :func:`widened` multiplies; the re-checks are extra)."""
    b = _as_budget(budget)
    return b.initial + b.chains * b.anneal_steps


def escalated_cost(budget) -> int:
    """Candidate evaluations of one search round and every escalation it may make when
    it finds no feasible design on its grid (the k-th: 4^k x the samples, 2^k x the
    moves per chain): a try's most."""
    b = _as_budget(budget)
    return search_cost(b) + sum(b.initial * 4 ** (k + 1)
                                + b.chains * b.anneal_steps * 2 ** (k + 1)
                                for k in range(b.escalations))


def _as_budget(budget, x0_points=None):
    b = BUDGETS.get(budget, budget) if isinstance(budget, str) else budget
    if not isinstance(b, Budget):
        raise ValueError(f"budget must be one of {sorted(BUDGETS)} or a Budget, "
                         f"{budget!r} was given")
    if x0_points is not None:
        n = int(x0_points)
        b = replace(b, x0_points=n, forbidden_x0_points=max(n, b.forbidden_x0_points),
                    verify_x0_points=max(b.verify_x0_points, 4 * (n - 1) + 1))
    return b

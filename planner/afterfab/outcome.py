"""What the after-fabrication loop found of one chip, as declared types, and the one
list of its outcomes and causes.

The loop (:func:`planner.afterfab.loop.run_loop`) runs on a simulated chip of a yield
study (its truth known) and on a measured die of the test floor (no truth) alike, and
returns one :class:`LoopResult`: the plan's drive checked on the chip
(:class:`DriveCheck`), the re-plan's outcome (:class:`ReplanOutcome`, with the tuned
re-plan's, :class:`TuneOutcome`), the trim's (:class:`TrimOutcome`), the pairs no drive
tells apart (:class:`Collision`) and the stages' wall times (:class:`Seconds`).  A yield
study's :class:`planner.yield_.ChipResult` holds these same records with the chip's
place in the study; the wafer batch writes a die's ``result.json`` from them.

Every outcome (:data:`OUTCOMES`) and every cause (:data:`CAUSES`) a chip can be given is
declared here, and so is the rule that gives them (:func:`outcome_of`,
:func:`replan_causes`).

The types are frozen dataclasses at module level: a Dask worker pickles them back to the
client.  Each stage's record has a ``to_dict()`` giving the plain dict yield.json's
chips were made of before these types; an optional field that is None is a key that
dict does not hold.
"""

from __future__ import annotations

from dataclasses import dataclass, field

#: A chip's outcomes, best first: the first stage of the loop that makes it work -- the
#: plan's drive as it is, the drive re-planned from its measurement, the chip trimmed
#: and re-planned -- or none (yield.json's ``wafer`` words).
OUTCOMES = ("as designed", "after re-plan", "after trim", "fails")
#: The test floor's word for a die nothing rescued (a study's chip ``fails``; the lab
#: scraps a die): the last of the wafer batch's outcomes.
SCRAPPED = "scrapped"
#: The wafer batch's outcomes (summary.csv, report.md): :data:`OUTCOMES` in the lab's
#: words.
FLOOR_OUTCOMES = OUTCOMES[:-1] + (SCRAPPED,)
#: The outcome of a die that would work but was not measured whole: what the loop found
#: holds only if its unmeasured impacters are as designed.  Counted apart, listed after
#: :data:`FLOOR_OUTCOMES` when a wafer has one.
PARTLY_MEASURED = "partly measured"
#: The cause naming a die's unmeasured impacters (followed by their ids).
NOT_MEASURED = "not measured, taken as designed: "

#: Why a re-plan failed, in the order reports list them (a chip may have several):
#: two impacters the spec must tell apart can no longer be (the re-plan's unresolved
#: conflict: the idle one responds at every candidate tone of the other -- close
#: resonances, or response bands that overlap although the resonances do not); a
#: scaled tone fell beyond ``drive.band_hz``; the re-plan does not verify even on the
#: measured models it was made for; it verifies there but not on the chip's true
#: models (measurement noise, or what the re-plan's model does not know: the as-built
#: mass, damping, gap and sliders); its steps pass on the true models but the
#: carried-state check fails (the re-plan does not simulate the scenes); the chip
#: cannot be built; its tones fit no loop the synthesis may play.  The last three words
#: of the list need the truth: the test floor judges a re-plan on the measured models.
REPLAN_CAUSES = ("cannot be told apart", "outside band", "fails on the measured models",
                 "fails only on the true models", "carried state", "unbuildable",
                 "drive not playable")
#: A trim that cannot be made: a move beyond ``trim.range_pct`` (on the test floor
#: also, followed by ``": not measured: "`` and ids, a die not measured whole).
CANNOT_TRIM = "cannot be trimmed"
#: The test floor's trimmed die whose re-planned drive verifies on the trims' targets
#: but whose odds over the cuts' errors fall short of ``fabrication.target_yield``.
TRIMMED_FAILS = "fails on the trimmed models"
#: Every cause of the loop, in the order reports list them (besides these, a re-plan
#: that cannot be made says why: ``"no re-plan: "`` and the error).
CAUSES = REPLAN_CAUSES + (CANNOT_TRIM, TRIMMED_FAILS)
#: The cause of a re-plan that could not be made, followed by the error.
NO_REPLAN = "no re-plan: "


def replan_causes(ok: bool, rp, got: dict | None = None, *, collisions: bool = False,
                  truth_known: bool = False) -> tuple:
    """Why a re-planned drive fails (:data:`REPLAN_CAUSES`, in that order); empty when it
    works.

    Parameters
    ----------
    ok : bool
        The re-plan verified on the models it was made from (the measured ones).
    rp : planner.planfile.schema.Replan
        The re-plan's ``replan`` block (plan.json's, typed).
    got : dict, optional
        :func:`planner.afterfab.checks.check_drive` of the drive on the chip's true
        models, where the truth is known; the drive is then judged there.  Without it
        (the test floor), on the measured models (``ok``).
    collisions : bool
        The re-plan found impacters no drive tells apart: nothing was simulated.  With
        the truth known, that collision is the chip's one cause (yield.json has counted a
        colliding chip under it alone); on the test floor, the tones that fell beyond the
        band are named with it.
    truth_known : bool
        The loop runs on a simulated chip (a yield study).
    """
    if collisions:
        return ("cannot be told apart",) + (
            ("outside band",) if rp.outside_band and not truth_known else ())
    passed = ok if got is None else got["passed"]
    causes = []
    if not passed:
        if rp.outside_band:
            causes.append("outside band")
        if not ok:
            causes.append("fails on the measured models")
        elif got["steps_passed"]:
            causes.append("carried state")
        else:
            causes.append("fails only on the true models")
    return tuple(causes)


def outcome_of(passed: bool, failures: dict, replan: ReplanOutcome | None,
               trim: TrimOutcome | None) -> tuple[str, tuple]:
    """``(outcome, causes)`` of one chip: the first of :data:`OUTCOMES` it reaches, and
    for the last the causes of the last stage run (the trim's, the re-plan's, or the
    failing checks of the plan's drive, in the order of
    :data:`planner.afterfab.checks.KINDS`).

    Parameters
    ----------
    passed, failures :
        The plan's drive on the chip (:class:`DriveCheck`'s).
    replan, trim :
        The stages' outcomes, None where the stage was not run.
    """
    if passed:
        return OUTCOMES[0], ()
    if replan is not None and replan.passed:
        return OUTCOMES[1], ()
    if trim is not None and trim.passed:
        return OUTCOMES[2], ()
    if trim is not None:
        return OUTCOMES[3], tuple(trim.causes)
    if replan is not None:
        return OUTCOMES[3], tuple(replan.causes)
    from planner.afterfab.checks import KINDS

    rank = {k: i for i, k in enumerate(KINDS)}
    return OUTCOMES[3], tuple(sorted(failures, key=lambda k: (rank.get(k, 99), k)))


@dataclass(frozen=True)
class Collision:
    """Impacters no drive can tell apart on a chip (the re-plan's ``inseparable``,
    :func:`planner.afterfab.drive.inseparable`).

    Attributes
    ----------
    pair : tuple of str
        The impacter ids, lower measured resonance first: two for a pair too close,
        or one impacter followed by those whose silent bands together cover its whole
        window.
    as_built_hz : tuple of float
        Their measured resonances, in the order of ``pair`` [Hz].
    apart_hz : float or None
        How far apart the two resonances are [Hz]; None for an impacter blocked by
        several.
    needs_hz : float or None
        How far apart they would have to be [Hz]; None as ``apart_hz``.
    """

    pair: tuple
    as_built_hz: tuple
    apart_hz: float | None
    needs_hz: float | None

    @classmethod
    def from_inseparable(cls, c) -> "Collision":
        """From one entry of a re-plan's ``inseparable`` list (a
        :class:`planner.planfile.schema.Inseparable`; its ``message`` left out)."""
        return cls(tuple(c.pair), tuple(c.as_built_hz), c.apart_hz, c.needs_hz)

    def to_dict(self) -> dict:
        """``{"pair", "as_built_hz", "apart_hz", "needs_hz"}``, as yield.json's
        ``collisions`` lists it."""
        return {"pair": list(self.pair), "as_built_hz": list(self.as_built_hz),
                "apart_hz": self.apart_hz, "needs_hz": self.needs_hz}


@dataclass(frozen=True)
class _DriveOutcome:
    """What a re-planned drive did on a chip (the fields the re-plan's outcome and the
    tuned re-plan's share)."""

    #: the re-planned drive works: passes every check on the chip's true models where
    #: they are known, else verifies on the measured ones [-]
    passed: bool
    #: it verifies on the models it was made from (the measured ones) [-]
    measured_passed: bool
    #: why it fails (:data:`REPLAN_CAUSES`, in that order); empty when it works
    causes: tuple
    #: check kind -> number of failed checks on the true models [-] (empty on the test
    #: floor, where no truth is known)
    failures: dict
    #: the pairs no drive tells apart (then nothing was simulated)
    collisions: tuple = ()
    #: impacter ids whose re-planned tone fell beyond ``drive.band_hz``
    outside_band: tuple = ()
    #: step keys played as sub-steps (sorted); None when no re-plan was made (the chip
    #: cannot be built)
    split_steps: tuple | None = None
    #: impacters whose tone the re-plan moved [-]; None as ``split_steps``
    tones_moved: int | None = None
    #: the re-plan's repairs, kind -> count (plan.json's ``replan.repairs``; only the
    #: kinds that fired, :data:`planner.afterfab.replan.REPAIR_KINDS`)
    repairs: dict = field(default_factory=dict)

    def _common(self) -> dict:
        out = {"passed": self.passed, "measured_passed": self.measured_passed,
               "causes": list(self.causes), "failures": self.failures,
               "collisions": [c.to_dict() for c in self.collisions],
               "outside_band": list(self.outside_band)}
        if self.split_steps is not None:
            out["split_steps"] = list(self.split_steps)
        if self.tones_moved is not None:
            out["tones_moved"] = self.tones_moved
        if self.repairs:
            out["repairs"] = dict(self.repairs)
        return out


@dataclass(frozen=True)
class TuneOutcome(_DriveOutcome):
    """A re-planned chip tuned on the chip (``yield --tune``, the loop's tune stage): a
    speed sweep around each re-planned tone, the tones far from their working window's
    middle moved to it, the drive re-planned and checked again on the true models.

    Attributes
    ----------
    passed : bool
        The tuned drive passes every check on the chip's true models [-].
    measured_passed : bool
        It verifies on the models it was made from [-].
    causes : tuple of str
        Why it fails (:data:`REPLAN_CAUSES`); empty when it passes.
    failures : dict
        Check kind -> number of failed checks on the true models [-].
    collisions : tuple of Collision
        Pairs no drive tells apart (no sweep separates them: the re-plan's own).
    outside_band : tuple of str
        Impacter ids whose tone fell beyond ``drive.band_hz``.
    split_steps : tuple of str or None
        Step keys played as sub-steps, sorted; None for a chip that cannot be built.
    tones_moved : int or None
        Impacters whose tone the re-plan moved from the plan's [-]; None as
        ``split_steps``.
    windows : int
        Impacters whose tone was moved to its working window's middle [-] (0: the
        re-plan stands as it was).
    kept_replan : bool
        The tuned drive, played on the chip, failed where the re-plan before the sweep
        worked, and the lab kept that re-plan (``windows`` is then 0) [-].
    """

    windows: int = 0
    kept_replan: bool = False

    def to_dict(self) -> dict:
        """The re-plan's keys plus ``windows`` (and ``kept_replan`` where true)."""
        return {**self._common(), "windows": self.windows,
                **({"kept_replan": True} if self.kept_replan else {})}


@dataclass(frozen=True)
class ReplanOutcome(_DriveOutcome):
    """A chip measured, its drive re-planned from the measurement and judged: on the
    chip's true models where they are known (``yield --replan``), else on the measured
    ones (the test floor).

    Attributes
    ----------
    passed : bool
        The re-planned drive works: passes every check on the chip's true models, or
        (no truth) verifies on the measured ones [-].
    measured_passed : bool
        It verifies on the models it was made from (the measured ones) [-].
    causes : tuple of str
        Why it fails (:data:`REPLAN_CAUSES`, in that order); empty when it works.
    failures : dict
        Check kind -> number of failed checks on the true models [-]; empty without
        the truth.
    collisions : tuple of Collision
        Pairs no drive tells apart (the drive is then not simulated).
    outside_band : tuple of str
        Impacter ids whose re-planned tone fell beyond ``drive.band_hz``.
    split_steps : tuple of str or None
        Step keys played as sub-steps, sorted; None when no re-plan was made (the chip
        cannot be built).
    tones_moved : int or None
        Impacters whose tone the re-plan moved from the plan's [-]; None as
        ``split_steps``.
    tuned : TuneOutcome or None
        With ``--tune``, the re-planned chip tuned (a chip with nothing to tune -- it
        cannot be built, its pairs collide, its tones fit no loop -- fails tuned as it
        failed re-planned, ``windows`` 0); None without ``--tune``.
    """

    tuned: TuneOutcome | None = None

    @property
    def final(self) -> "_DriveOutcome":
        """The last drive the lab ends with: the tuned one when the chip was tuned, else
        this re-plan."""
        return self if self.tuned is None else self.tuned

    def to_dict(self) -> dict:
        """``passed``, ``measured_passed``, ``causes``, ``failures``, ``collisions``,
        ``outside_band``, ``split_steps`` and ``tones_moved`` (both absent for a chip
        that cannot be built), ``tuned`` (with ``--tune``)."""
        out = self._common()
        if self.tuned is not None:
            out["tuned"] = self.tuned.to_dict()
        return out


@dataclass(frozen=True)
class TrimOutcome:
    """A chip the re-plan could not rescue because two of its impacters cannot be told
    apart, trimmed and re-planned (the loop's trim stage): with the truth known, cut,
    measured again pass by pass and verified on its trimmed true models; on the test
    floor, the cuts chosen, the drive re-planned for their targets and weighed over the
    cuts' errors (:func:`planner.afterfab.trim.trim_chip`).  A chip that needed no trim
    carries the re-plan's (or the tuned re-plan's) outcome.

    Attributes
    ----------
    passed : bool
        The chip works after the trims and the re-plan (or without a trim) [-].
    trimmed : tuple of str
        Impacter ids trimmed (empty when none was).
    passes : int or None
        Trim passes made [-]; None for a chip that cannot be built (no trim tried).
    causes : tuple of str
        Why it fails: :data:`CANNOT_TRIM` (a move beyond the trim range), or the
        re-plan's causes after the trims (:data:`REPLAN_CAUSES`), or on the test floor
        :data:`TRIMMED_FAILS`.
    failures : dict
        Check kind -> number of failed checks on the trimmed true models [-] (empty
        without the truth).
    beyond_range : tuple of str or None
        Impacter ids whose move lies beyond ``trim.range_pct``; None unless the chip
        cannot be trimmed.
    """

    passed: bool
    trimmed: tuple
    passes: int | None
    causes: tuple
    failures: dict
    beyond_range: tuple | None = None

    def to_dict(self) -> dict:
        """``passed``, ``trimmed``, ``passes`` (absent for a chip that cannot be built),
        ``causes``, ``failures``, ``beyond_range`` (only when it cannot be trimmed)."""
        out = {"passed": self.passed, "trimmed": list(self.trimmed)}
        if self.passes is not None:
            out["passes"] = self.passes
        out.update(causes=list(self.causes), failures=self.failures)
        if self.beyond_range is not None:
            out["beyond_range"] = list(self.beyond_range)
        return out


@dataclass(frozen=True)
class Seconds:
    """Wall times of one chip's work (kept out of ``yield.json``: the numbers depend on
    the seed only).

    Attributes
    ----------
    nominal : float
        Checking the plan's drive on the chip (a study adds sampling the chip) [s].
    replan : float
        Measuring and re-planning it, tuning included [s].
    trim : float or None
        Trimming it (``--trim``) [s]; None without, or for a chip that cannot be built.
    """

    nominal: float
    replan: float
    trim: float | None = None

    def to_dict(self) -> dict:
        """``{"nominal", "replan"}``, and ``trim`` when it was timed."""
        out = {"nominal": self.nominal, "replan": self.replan}
        if self.trim is not None:
            out["trim"] = self.trim
        return out


@dataclass(frozen=True)
class DriveCheck:
    """The plan's own drive checked on a chip: on its true models where they are known,
    else on its as-built models (:func:`planner.afterfab.checks.check_drive`, stopped
    at the first failing step when the chip is to be re-planned).

    Attributes
    ----------
    passed : bool
        Every check passes, the carried-state check included [-].
    failures : dict
        Check kind (:data:`planner.afterfab.checks.KINDS`, or ``unbuildable``) ->
        number of failed checks [-] (for ``unbuildable``: of devices and impacters
        that cannot be built).
    nodes : tuple of planner.core.nodes.Node
        The impacter pairs implicated in a failure, sorted.
    checks, checks_passed : int
        Step x device checks run, and those that passed [-].
    """

    passed: bool
    failures: dict
    nodes: tuple = ()
    checks: int = 0
    checks_passed: int = 0

    @classmethod
    def of(cls, got: dict) -> "DriveCheck":
        """From :func:`~planner.afterfab.checks.check_drive`'s dict."""
        return cls(got["passed"], got["failures"], tuple(sorted(got["nodes"])),
                   len(got["rows"]), sum(1 for r in got["rows"] if r["passed"]))


@dataclass(frozen=True)
class LoopResult:
    """One chip through the after-fabrication loop (:func:`planner.afterfab.loop.
    run_loop`): each stage's outcome, and the outcome and causes they give.

    Attributes
    ----------
    nominal : DriveCheck
        The plan's drive on the chip.
    replan : ReplanOutcome or None
        The chip measured and re-planned (None: not asked for, or on the test floor a
        chip the plan's drive works on).
    trim : TrimOutcome or None
        The trim stage (None: not asked for, or on the test floor a re-plan that works).
    seconds : Seconds
        The stages' wall times.
    on_floor : bool
        No truth was known (a measured die of the test floor): its last outcome is
        :data:`SCRAPPED`.
    not_measured : tuple of str
        On the test floor, the impacters the measurement left out (taken at their
        design).
    replanned, trimmed :
        On the test floor with outputs asked for, what the lab plays and cuts: the
        re-plan (:class:`planner.planning.result.Plan`) and the trim
        (:class:`planner.afterfab.trim.TrimResult`); None otherwise.
    """

    nominal: DriveCheck
    replan: ReplanOutcome | None = None
    trim: TrimOutcome | None = None
    seconds: Seconds = field(default_factory=lambda: Seconds(0.0, 0.0))
    on_floor: bool = False
    not_measured: tuple = ()
    replanned: object = field(default=None, compare=False, repr=False)
    trimmed: object = field(default=None, compare=False, repr=False)

    @property
    def reached(self) -> str:
        """The first of :data:`OUTCOMES` the loop reached (:func:`outcome_of`), whatever
        was measured."""
        return outcome_of(self.nominal.passed, self.nominal.failures, self.replan,
                          self.trim)[0]

    @property
    def outcome(self) -> str:
        """The chip's outcome: :attr:`reached`, in the test floor's words there
        (:data:`SCRAPPED`), and :data:`PARTLY_MEASURED` for a die that would work but
        was not measured whole."""
        found = self.reached
        if found == OUTCOMES[-1]:
            return SCRAPPED if self.on_floor else found
        return PARTLY_MEASURED if self.not_measured else found

    @property
    def causes(self) -> tuple:
        """Why: for a chip that fails, the causes of the last stage run; a die not
        measured whole names its unmeasured impacters (after those causes when it is
        scrapped; with what the loop found when it would work)."""
        found, causes = outcome_of(self.nominal.passed, self.nominal.failures,
                                   self.replan, self.trim)
        if not self.not_measured:
            return causes
        missing = " ".join(self.not_measured)
        named = NOT_MEASURED + missing
        if found == OUTCOMES[-1]:
            return causes + (named,)
        # what the loop found holds only if the unmeasured impacters are as designed
        return (named, f"works {found} if {missing} "
                       + ("are at their design" if len(self.not_measured) > 1 else
                          "is at its design"))

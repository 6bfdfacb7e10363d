"""The results of one chip of a yield run, as declared types: what
:func:`planner.yield_.verify_chip` returns (:class:`ChipResult`) and what it holds --
the re-plan's outcome (:class:`ReplanOutcome`), the tuned re-plan's
(:class:`TuneOutcome`), the trim's (:class:`TrimOutcome`), a pair no drive tells apart
(:class:`Collision`) and the wall times (:class:`Seconds`).

They are frozen dataclasses at module level: a Dask worker pickles them back to the
client.  Each has a ``to_dict()`` giving the plain dict the chip's result was before
these types (the keys and values :func:`planner.yield_.statistics.yield_record` turns
into ``yield.json``); an optional field that is None is a key that dict does not hold.
"""

from __future__ import annotations

from dataclasses import dataclass


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
    """What a re-planned drive did on a chip's true models (the fields the re-plan's
    outcome and the tuned re-plan's share)."""

    #: the re-planned drive passes every check on the chip's true models [-]
    passed: bool
    #: it verifies on the models it was made from (the measured ones) [-]
    measured_passed: bool
    #: why it fails (:data:`planner.yield_.REPLAN_CAUSES`, in that order); empty when
    #: it passes
    causes: tuple
    #: check kind -> number of failed checks on the true models [-]
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

    def _common(self) -> dict:
        out = {"passed": self.passed, "measured_passed": self.measured_passed,
               "causes": list(self.causes), "failures": self.failures,
               "collisions": [c.to_dict() for c in self.collisions],
               "outside_band": list(self.outside_band)}
        if self.split_steps is not None:
            out["split_steps"] = list(self.split_steps)
        if self.tones_moved is not None:
            out["tones_moved"] = self.tones_moved
        return out


@dataclass(frozen=True)
class TuneOutcome(_DriveOutcome):
    """A re-planned chip tuned on the chip (``--tune``,
    :func:`planner.yield_.chip._tune_and_check`): a speed sweep around each re-planned
    tone, the tones far from their working window's middle moved to it, the drive
    re-planned and checked again on the true models.

    Attributes
    ----------
    passed : bool
        The tuned drive passes every check on the chip's true models [-].
    measured_passed : bool
        It verifies on the models it was made from [-].
    causes : tuple of str
        Why it fails (:data:`planner.yield_.REPLAN_CAUSES`); empty when it passes.
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
    """

    windows: int = 0

    def to_dict(self) -> dict:
        """The re-plan's keys plus ``windows``."""
        return {**self._common(), "windows": self.windows}


@dataclass(frozen=True)
class ReplanOutcome(_DriveOutcome):
    """A chip measured, its drive re-planned from the measurement and verified on the
    chip's true models (``--replan``, :func:`planner.yield_.replan_chip_on`).

    Attributes
    ----------
    passed : bool
        The re-planned drive passes every check on the chip's true models [-].
    measured_passed : bool
        It verifies on the models it was made from (the measured ones) [-].
    causes : tuple of str
        Why it fails (:data:`planner.yield_.REPLAN_CAUSES`, in that order); empty when
        it passes.
    failures : dict
        Check kind -> number of failed checks on the true models [-].
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
    apart, trimmed, measured again, re-planned and verified on its trimmed true models
    (``--trim``, :func:`planner.yield_.trim_chip_on`); a chip that needed no trim
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
        Why it fails: ``cannot be trimmed`` (a move beyond the trim range), or the
        re-plan's causes after the trims (:data:`planner.yield_.REPLAN_CAUSES`).
    failures : dict
        Check kind -> number of failed checks on the trimmed true models [-].
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
        Sampling the chip and checking the plan's drive on it [s].
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
class ChipResult:
    """One sampled chip of a yield run: the plan's drive checked on it, and with
    ``--replan`` the re-plan (tuned with ``--tune``) and with ``--trim`` the trim
    (:func:`planner.yield_.verify_chip`).

    Attributes
    ----------
    scale_index : int
        Index of the chip's sigma scale in the run's scales [-]
        (:data:`planner.yield_.run.NOMINAL_INDEX` for the nominal chip).
    chip : int
        The chip's index within its scale [-].
    passed : bool
        The plan's drive passes every check on the chip, the carried-state check
        included [-].
    carried_passed : bool
        Equal to ``passed`` (the carried-state check is part of the pass) [-].
    failures : dict
        Check kind (:data:`planner.afterfab.checks.KINDS`, or ``unbuildable``) ->
        number of failed checks [-] (for ``unbuildable``: of devices and impacters
        that cannot be built).
    nodes : tuple of planner.core.nodes.Node
        The impacter pairs implicated in a failure, sorted.
    replan : ReplanOutcome or None
        With ``--replan``, the chip measured and re-planned; else None.
    trim : TrimOutcome or None
        With ``--trim``, the chip trimmed where the re-plan needed it; else None.
    seconds : Seconds or None
        With ``--replan``, the wall times of the chip's work; else None.
    """

    scale_index: int
    chip: int
    passed: bool
    carried_passed: bool
    failures: dict
    nodes: tuple
    replan: ReplanOutcome | None = None
    trim: TrimOutcome | None = None
    seconds: Seconds | None = None

    def to_dict(self) -> dict:
        """``scale_index``, ``chip``, ``passed``, ``carried_passed``, ``failures``,
        ``nodes`` (a list of Node), then ``replan``, ``trim`` and ``seconds`` when
        present."""
        out = {"scale_index": self.scale_index, "chip": self.chip, "passed": self.passed,
               "carried_passed": self.carried_passed, "failures": self.failures,
               "nodes": list(self.nodes)}
        for key in ("replan", "trim", "seconds"):
            value = getattr(self, key)
            if value is not None:
                out[key] = value.to_dict()
        return out

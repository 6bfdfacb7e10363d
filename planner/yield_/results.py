"""The result of one chip of a yield run: what :func:`planner.yield_.verify_chip`
returns (:class:`ChipResult`): the chip's place in the study and what the
after-fabrication loop found of it -- the records of :mod:`planner.afterfab.outcome`,
the re-plan's outcome (:class:`ReplanOutcome`), the tuned re-plan's
(:class:`TuneOutcome`), the trim's (:class:`TrimOutcome`), a pair no drive tells apart
(:class:`Collision`) and the wall times (:class:`Seconds`), named here too.

A frozen dataclass at module level: a Dask worker pickles it back to the client.  Its
``to_dict()`` gives the plain dict the chip's result was before these types (the keys
and values :func:`planner.yield_.statistics.yield_record` turns into ``yield.json``); an
optional field that is None is a key that dict does not hold.
"""

from __future__ import annotations

from dataclasses import dataclass

from planner.afterfab.outcome import (Collision, ReplanOutcome, Seconds, TrimOutcome,
                                      TuneOutcome)

__all__ = ["ChipResult", "Collision", "ReplanOutcome", "Seconds", "TrimOutcome",
           "TuneOutcome"]


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
    passed, failures, nodes :
        The plan's drive on the chip's true models, as the loop checked it
        (:class:`~planner.afterfab.outcome.DriveCheck`'s fields of those names).
    carried_passed : bool
        Equal to ``passed`` (the carried-state check is part of the pass) [-].
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

"""The inputs of a yield run: the worker payload built from a plan, and the checks of
the command's numbers (chip count, sigma scales, noise levels)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from planner.fabrication.tolerances import ChipDesign, design_from_plan
from planner.core.nodes import Node
from planner.afterfab.checks import drive_of
from planner.planfile.reader import PlanRecord
from planner.arrayspec import FabricationSpec, LoadedSpec

#: Memory one chip's task and result hold until the end of a run [bytes]: its result
#: (a few hundred bytes, a few KB with --replan) and, on Dask, the scheduler's and the
#: client's bookkeeping of its task (~10 KB); an upper estimate.
CHIP_BYTES = 16 * 1024
#: Standard deviations of a measurement's noise a study's readings must stay sound at
#: (:func:`check_measure_noise`): with a thousand chips of 25 impacters, a reading
#: beyond 5 sigma comes once in ~20 studies.
NOISE_SIGMAS = 5.0


@dataclass(frozen=True)
class Payload:
    """Everything a worker needs to verify chips; sent to each worker once."""

    design: ChipDesign
    loaded: LoadedSpec
    waveforms: dict
    fabrication: FabricationSpec
    seed: int
    #: Numba threads per chip (None: numba's default); :func:`planner.yield_.run_yield`
    #: sets 1.
    threads: int | None = None
    #: Settle dwell [s] of every step key (plan.json's ``settle_s``, the dwell the
    #: plan's own carried-state check used).
    dwells: dict = dataclasses.field(default_factory=dict)
    #: Measure, re-plan and re-verify every chip (``--replan``).
    replan: bool = False
    #: One sigma of the relative measurement noise of a natural frequency [%].
    measure_noise_pct: float = 0.0
    #: The plan the re-plan starts from (only with ``replan``).
    record: "PlanRecord | None" = None
    #: Trim the chips the re-plan cannot rescue (``--trim``, needs ``replan``).
    trim: bool = False
    #: One sigma of a trim's error [%] (``--trim-precision``; None: the spec's
    #: ``trim.precision_pct``).
    trim_precision_pct: float | None = None
    #: The plan's :class:`~planner.planning.settings.Settings`, resolved once here for
    #: every chip (:func:`~planner.planning.settings.plan_settings`).
    settings: object = None
    #: Tune every re-planned chip (``--tune``, needs ``replan``): a speed sweep around
    #: each re-planned tone on the true chip, the tones moved to the middle of the
    #: working windows, re-planned and checked again (:mod:`planner.afterfab.tune`).
    tune: bool = False
    #: Tones per impacter of the tuning sweep (``--tune-tones``).
    tune_tones: int = 7
    #: One sigma of the relative noise of a speed reading [%] (``--tune-noise``).
    tune_noise_pct: float = 5.0

    @property
    def nodes(self) -> tuple[Node, ...]:
        """The plan's impacters, in its order."""
        return tuple(Node(n.device, n.direction) for n in self.design.nodes)


def check_noise(pct, option: str = "--measure-noise") -> float:
    """``pct`` as a relative sigma [%] (a measurement noise, a trim's precision): a finite
    number >= 0.

    Raises
    ------
    ValueError
        Naming ``option``.
    """
    try:
        x = float(pct)
    except (TypeError, ValueError):
        raise ValueError(f"{option}: {pct!r} is not a number") from None
    if not (math.isfinite(x) and x >= 0):
        raise ValueError(f"{option}: must be a finite number >= 0 [%], {pct} was given")
    return x


def check_measure_noise(pct: float, drive, option: str = "--measure-noise") -> float:
    """``pct`` (a measurement's noise [%], :func:`check_noise`) if a reading
    :data:`NOISE_SIGMAS` sigma high stays a measurement of the chip: within the factor
    :data:`~planner.afterfab.measurement.MAX_MEASURED_FACTOR` of the resonance that a
    lab's measured.csv may give, and a tone moved with it from the top of the band
    below the Nyquist frequency of the drive's sample rate (``drive``: the spec's
    drive section), where no waveform can play it.

    Raises
    ------
    ValueError
        Naming ``option``, the bound and the limit that sets it; before any work.
    """
    from planner.afterfab.measurement import MAX_MEASURED_FACTOR

    x = check_noise(pct, option)
    nyquist = 0.5 * float(drive.sample_rate_hz)
    top = float(drive.band_hz[1])
    by_factor = 100.0 * (MAX_MEASURED_FACTOR - 1.0) / NOISE_SIGMAS
    by_nyquist = 100.0 * (nyquist / top - 1.0) / NOISE_SIGMAS
    if x > min(by_factor, by_nyquist):
        if by_nyquist < by_factor:
            why = (f"a reading {NOISE_SIGMAS:g} sigma high moves a tone at the band's top "
                   f"{top:g} Hz past the Nyquist frequency {nyquist:g} Hz of "
                   f"drive.sample_rate_hz {float(drive.sample_rate_hz):g}")
        else:
            why = (f"a reading {NOISE_SIGMAS:g} sigma high is {MAX_MEASURED_FACTOR:g} x the "
                   "resonance, the most a lab's measured.csv may be off its design")
        raise ValueError(f"{option}: {x:g} % is beyond what a lab measures: at most "
                         f"{min(by_factor, by_nyquist):.3g} % ({why})")
    return x


def make_payload(record: PlanRecord, seed: int, fabrication: FabricationSpec | None = None, *,
                 replan: bool = False, measure_noise_pct: float = 0.0,
                 allow_zero: bool = False, trim: bool = False,
                 trim_precision_pct: float | None = None, tune: bool = False,
                 tune_tones: int = 7, tune_noise_pct: float = 5.0) -> Payload:
    """The worker payload of a plan (:func:`planner.planfile.reader.read_plan`);
    ``fabrication`` overrides the plan's.

    ``replan``: measure, re-plan and re-verify every chip; ``measure_noise_pct``: one
    sigma of the relative noise of each measured natural frequency [%] (>= 0).
    ``allow_zero``: accept a tolerance model whose every sigma is 0 (every chip is then
    the nominal one: the yield is 1 or 0 by construction, not a measurement).
    ``tune``: sweep each re-planned chip's tones on the chip and re-plan at the working
    windows' middles (``tune_tones`` tones per impacter, a speed reading's noise
    ``tune_noise_pct`` [%]).

    Raises
    ------
    ValueError
        A zero tolerance model without ``allow_zero``; noise without ``replan``.
    """
    noise = check_measure_noise(measure_noise_pct, record.spec.drive)
    if noise and not replan:
        raise ValueError("--measure-noise needs --replan (only a re-plan measures the chip)")
    if trim and not replan:
        raise ValueError("--trim needs --replan (a trimmed chip's drive is re-planned)")
    if tune and not replan:
        raise ValueError("--tune needs --replan (the sweep is around the re-planned tones)")
    if not 3 <= int(tune_tones) <= 50:
        raise ValueError(f"--tune-tones must be 3-50 tones per impacter, {tune_tones!r} was "
                         "given")
    tune_noise_pct = check_noise(tune_noise_pct, "--tune-noise")
    if trim_precision_pct is not None:
        trim_precision_pct = check_noise(trim_precision_pct, "--trim-precision")
        if not trim:
            raise ValueError("--trim-precision needs --trim")
    fab = fabrication if fabrication is not None else record.spec.fabrication
    if fab.wafer is not None:
        from planner.fabrication.wafer import wafer_layout

        wafer_layout(record.spec.array, fab.wafer)     # no die fits: refused before any work
    if fab.zero and not allow_zero:
        raise ValueError("every fabrication tolerance is 0 (the spec has no fabrication: "
                         "section, or only zero sigmas): every chip would be the nominal one "
                         "and the yield 1 or 0 by construction. Give the tolerances with "
                         "--spec FILE (its fabrication: section), or pass --allow-zero to "
                         "check the nominal chip alone")
    from planner.planning.settings import plan_settings

    steps, waveforms, dwells = drive_of(record)
    loaded = LoadedSpec(record.spec, steps, str(record.path or "plan.json"))
    return Payload(design_from_plan(record), loaded, waveforms, fab, int(seed),
                   dwells=dwells, replan=bool(replan), measure_noise_pct=noise,
                   record=record if replan else None, trim=bool(trim),
                   trim_precision_pct=trim_precision_pct, settings=plan_settings(record),
                   tune=bool(tune), tune_tones=int(tune_tones), tune_noise_pct=tune_noise_pct)


def parse_scales(text: str | None) -> list[float]:
    """``"0.5,1,2"`` -> [0.5, 1.0, 2.0]; None -> [1.0].

    Raises
    ------
    ValueError
        An entry is not a finite number >= 0, or an entry repeats.
    """
    if text is None or str(text).strip() == "":
        return [1.0]
    out = []
    for part in str(text).split(","):
        try:
            x = float(part)
        except ValueError:
            raise ValueError(f"--sigma-scale: {part.strip()!r} is not a number") from None
        if not (math.isfinite(x) and x >= 0):
            raise ValueError(f"--sigma-scale: {part.strip()} must be a finite number >= 0")
        if x in out:
            raise ValueError(f"--sigma-scale: {part.strip()} is given twice")
        out.append(x)
    return out


def check_chip_count(chips: int, n_scales: int = 1) -> None:
    """Refuse, before any work, a Monte Carlo whose chips the memory cannot hold.

    Raises
    ------
    ValueError
        ``chips`` < 1; :class:`planner.core.errors.LimitError` with the figures when
        ``chips`` x ``n_scales`` chips (plus the nominal one) need more memory than the
        machine has (:data:`CHIP_BYTES` each).
    """
    from planner.runtime.limits import check_memory

    if int(chips) < 1:
        raise ValueError(f"chips must be >= 1, {chips} was given")
    n = int(chips) * int(n_scales) + 1
    check_memory(n * CHIP_BYTES, f"--chips {chips} x {n_scales} sigma scale"
                                 f"{'s' if n_scales != 1 else ''} ({n} chips in all)")


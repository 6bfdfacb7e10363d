"""Stage 4, drives: the summed-tone drive of every step (tone amplitudes, synthesis), its
peaks and the acceleration limit."""

from __future__ import annotations

from model import Drive
from planner.core.nodes import Node
from planner.planning.settings import Settings, tone_amplitudes


#: The snapping tolerance of a single-tone step's tone, relative to it [-]: 5 Hz at 50 kHz.
SINGLE_TONE_TOLERANCE_REL = 1e-4
#: Tones of one step closer than this are played as one tone, at their mean [Hz]: the
#: synthesis' loop (at most ``MAX_LOOP_LENGTH`` = 1 s) resolves 1 Hz, so two tones
#: closer than that cannot stay distinct in it.  A plan's tones sit on its channel grid
#: and never come this close; a re-plan's do when impacters driven together (a row
#: sharing one design, one tone in the plan) each follow their own measured resonance:
#: one tone then drives them all, moved by under 1 Hz, well inside their tone windows
#: and inside the 1 Hz the re-plan keeps off every silent band's edge
#: (planner.afterfab.drive.EDGE_MARGIN_HZ).
MERGE_HZ = 1.0


def merged_tones(freqs):
    """``(played, tone_of)``: the distinct tones ``freqs`` [Hz] as played, each run of
    tones within :data:`MERGE_HZ` of its first merged into its mean, and a map from
    every tone of ``freqs`` to the tone that plays it.

    >>> merged_tones([4853.04, 4853.47, 4853.56, 8091.25])[0]
    [4853.356666666667, 8091.25]
    """
    groups = []
    for f in sorted(set(freqs)):
        if groups and f - groups[-1][0] < MERGE_HZ:
            groups[-1].append(f)
        else:
            groups.append([f])
    played = [g[0] if len(g) == 1 else sum(g) / len(g) for g in groups]
    return played, {f: p for g, p in zip(groups, played) for f in g}


def synthesize_steps(settings: Settings, steps, assignment, seed=None, phases=None,
                     draws=None):
    """Waveform of every step (the sum of its active impacters' tones), by step key.

    ``assignment``: an :class:`~planner.assignment.assign.Assignment`, or a mapping Node -> tone
    [Hz] (a re-plan's tones).  Step ``i`` is seeded with ``seed + i`` (``seed``
    default ``settings.seed``).  ``phases`` (optional): step key -> {Node -> phase
    [rad]}; a step whose every impacter has one plays its tones at those phases
    instead of optimised ones (a re-plan keeps the phases its designs were verified
    under).  ``draws`` (optional): step key -> k, the k-th phase draw of that step
    (seeded :func:`planner.core.rng.try_seed` ``(seed + i, k)``; 0, the first, is
    ``seed + i``): the plan's loop draws a multi-tone step's phases anew when an idle
    impacter cannot be made silent under its summed drive.

    With ``drive.chain`` and an input limit (``max_input_v``, or ``max_output_v`` with
    ``amplifier_gain``) a multi-tone step plays the phases that hold down the amplifier
    input's peak relative to that limit (:func:`planner.synthesis.synthesize`'s
    ``transfer`` and ``input_limit``) where they leave its tones more amplitude at the
    die under every limit than the die's own phases do, which it plays otherwise (the
    input limit does not set its amplitude: ``max_acceleration_g`` or none does).  The
    waveforms are the die's.
    """
    from planner.core.errors import PlanningError
    from planner.core.rng import try_seed
    from planner.synthesis import synthesize
    from planner.synthesis.chain import ChainError

    seed = settings.seed if seed is None else seed
    # through a drive chain with a voltage limit the phases may be chosen for the
    # amplifier input's peak (the one the limit holds down), the die still feeling the
    # designed tones; without a chain, or a chain without an input limit, the die's
    # crest factor as before
    limit = None if settings.chain is None else settings.chain.input_limit
    through = ({} if limit is None else
               {"transfer": settings.chain.transfer, "input_limit": limit[0]})
    frequencies = getattr(assignment, "frequencies", assignment)
    out = {}
    for st in steps:
        nodes = sorted(Node(d, dr) for d, dr in st.active_nodes())
        freqs, tone_of = merged_tones(frequencies[n] for n in nodes)
        amps = tone_amplitudes(settings, freqs)
        # one tone: played within 0.01 %, inside the 10-80 Hz an impacter designed for
        # yield keeps driving its slider (0.1 % moved a 51 kHz tone by 50 Hz); a step of
        # several tones keeps the default (a longer loop only raises its crest factor,
        # and its designs are made under the drive as played)
        tol = ([SINGLE_TONE_TOLERANCE_REL * f for f in freqs] if len(freqs) == 1 else None)
        given = (phases or {}).get(st.key) or {}
        ph = None
        if nodes and all(n in given for n in nodes):
            first = {}
            for n in nodes:                     # a shared tone: its first impacter's phase
                first.setdefault(tone_of[frequencies[n]], given[n])
            ph = [first[f] for f in freqs]
        draw = int((draws or {}).get(st.key, 0))

        def synthesised(chain_kw, freqs=freqs, amps=amps, tol=tol, ph=ph, st=st, draw=draw):
            return synthesize(freqs, amps, settings.sample_rate_hz,
                              seed=try_seed(seed + st.index, draw),
                              peak_limit=settings.peak_limit_m, frequency_tolerance=tol,
                              phases=ph, **chain_kw)

        try:
            w = synthesised({})
            if through and ph is None and len(freqs) > 1:
                # the input's phases where they leave the die more of its tones under
                # every limit (the input's lowers the step less); the die's where the
                # input limit does not set the step's amplitude (phases held down at
                # the input alone peak higher in the die's acceleration)
                held = synthesised(through)
                if _die_share(settings, held) > _die_share(settings, w):
                    w = held
        except ChainError as exc:
            # a tone outside a measured transfer (as planner.planning.chain says it)
            raise PlanningError(f"drive.chain: {exc}") from None
        out[st.key] = w
    return out


def _die_share(settings: Settings, waveform) -> float:
    """The share of its tones' amplitudes [-] a step's loop keeps at the die under every
    limit: the peak limit's scale (``waveform.scale``) times the factor
    :func:`planner.planning.chain.limit_drives` will lower it by, for
    ``drive.max_acceleration_g`` at the die and the drive chain's input limit (all
    scale linearly with the amplitudes: the smallest ratio of limit to peak, or 1)."""
    from planner.synthesis.chain import compensate

    factor = 1.0
    if settings.max_acceleration_m_s2 is not None:
        factor = min(factor, settings.max_acceleration_m_s2 / drive_peaks(waveform)[1])
    chain = settings.chain
    if chain is not None and chain.input_limit is not None:
        factor = min(factor, chain.input_limit[0] / compensate(waveform, chain.transfer).peak)
    return waveform.scale * factor


def drive_of(waveform) -> Drive:
    """The model's drive of a waveform (its tones, amplitudes and phases, all at full
    amplitude: for a gated burst, its summed drive before any gate)."""
    return Drive(waveform.frequencies, waveform.amplitudes, waveform.phases)


def program_of(waveform, duration):
    """What a step plays, as (duration [s], Drive) stretches played in turn.

    A loop (:class:`planner.synthesis.Waveform`) plays its summed drive for
    ``duration`` [s]: one stretch.  A gated burst (:class:`planner.synthesis.gating.Burst`)
    plays its :meth:`~planner.synthesis.gating.Burst.program` (its own length; ``duration`` is
    not read).
    """
    from planner.synthesis.gating import Burst

    # a gated drive read back from plan.json (planner.planfile.reader.RecordedDrive)
    # plays its gates as the Burst it was
    if isinstance(waveform, Burst) or getattr(waveform, "gates_s", None) is not None:
        return waveform.program()
    return ((float(duration), drive_of(waveform)),)


def scaled(waveform, factor, why):
    """``waveform`` with every amplitude (and its samples, peak, rms and scale) times
    ``factor``; frequencies, phases and crest factor unchanged; ``why`` is added to its
    warnings.  A gated burst keeps its gates."""
    import dataclasses

    return dataclasses.replace(
        waveform, samples=waveform.samples * factor, amplitudes=waveform.amplitudes * factor,
        peak=waveform.peak * factor, rms=waveform.rms * factor, scale=waveform.scale * factor,
        warnings=waveform.warnings + (why,))


def reweighted(waveform, amplitudes, why):
    """``waveform`` with its tones at ``amplitudes`` [m], on the same loop, frequencies
    and phases: the samples, the continuous peak, rms and crest factor computed again
    (as :func:`planner.synthesis.chain.compensate` does for the amplifier input); ``why``
    is added to its warnings.  A loop only (a gated burst's gates are its tones')."""
    import dataclasses
    import math

    import numpy as np

    from planner.synthesis.kernels import _cosine_sum
    from planner.synthesis.peak import peak_of

    a = np.asarray(amplitudes, dtype=float)
    cycles = np.rint(waveform.frequencies * waveform.loop_length).astype(np.int64)
    n = waveform.loop_points
    loop = _cosine_sum(cycles, n, a, waveform.phases)
    n_loops = max(1, len(waveform.samples) // n)
    samples = np.tile(loop, n_loops) if n_loops > 1 else loop
    peak = max(peak_of(cycles, a, waveform.phases), float(np.max(np.abs(samples))))
    rms = math.sqrt(float(np.sum(a ** 2)) / 2.0)
    return dataclasses.replace(waveform, samples=samples, amplitudes=a, peak=peak, rms=rms,
                               crest_factor=peak / rms if rms > 0 else 0.0,
                               warnings=waveform.warnings + (why,))


def limit_acceleration(settings: Settings, waveforms):
    """Enforce ``drive.max_acceleration_g``: every step whose summed drive's peak base
    acceleration exceeds it has all its tone amplitudes lowered by one factor (limit /
    peak; phases and frequencies kept), and says so.

    Returns
    -------
    (waveforms, notes)
        ``notes``: step key -> {"peak_displacement_m", "peak_acceleration_m_s2"
        (after any lowering), "acceleration_scale" (1 if none)}.
    """
    out, notes = {}, {}
    limit = settings.max_acceleration_m_s2
    for key, w in waveforms.items():
        zp, ap = drive_peaks(w)
        scale = 1.0
        if limit is not None and ap > limit:
            # a hair under the limit, so that the refined peak of the lowered drive is
            # not above it by rounding
            scale = limit / ap * (1.0 - 1e-6)
            # the same loop scaled: frequencies, phases and crest factor unchanged
            w = scaled(w, scale, f"every amplitude lowered by x{scale:.4g} to meet "
                                 "drive.max_acceleration_g")
            zp, ap = drive_peaks(w)
        out[key] = w
        notes[key] = {"peak_displacement_m": zp, "peak_acceleration_m_s2": ap,
                      "acceleration_scale": scale}
    return out, notes


def drive_peaks(waveform):
    """(peak |zeta| [m], peak |zeta''| [m/s^2]) of a summed drive over its loop, or of
    a gated burst (:class:`planner.synthesis.gating.Burst`) over its length
    (:func:`planner.synthesis.gating.tone_peaks`)."""
    from planner.synthesis.gating import Burst, burst_peaks, tone_peaks

    if isinstance(waveform, Burst):
        return burst_peaks(waveform)
    return tone_peaks(waveform.frequencies, waveform.amplitudes, waveform.phases,
                      waveform.loop_length)

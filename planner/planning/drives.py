"""Stage 4, drives: the summed-tone drive of every step (tone amplitudes, synthesis)."""

from __future__ import annotations

from model import Drive
from planner.nodes import Node
from planner.planning.settings import Settings, tone_amplitudes


def synthesize_steps(settings: Settings, steps, assignment, seed=None):
    """Waveform of every step (the sum of its active impacters' tones), by step key.

    ``assignment``: an :class:`~planner.assign.Assignment`, or a mapping impacter id ->
    tone [Hz] (a re-plan's tones).  Step ``i`` is seeded with ``seed + i`` (``seed``
    default ``settings.seed``).
    """
    from planner.synthesis import synthesize

    seed = settings.seed if seed is None else seed
    frequencies = getattr(assignment, "frequencies", assignment)
    out = {}
    for st in steps:
        nodes = sorted(Node(d, dr).text for d, dr in st.active_nodes())
        freqs = sorted({frequencies[n] for n in nodes})
        amps = tone_amplitudes(settings, freqs)
        out[st.key] = synthesize(freqs, amps, settings.sample_rate_hz, seed=seed + st.index,
                                 peak_limit=settings.peak_limit_m)
    return out


def drive_of(waveform) -> Drive:
    """The model's drive of a waveform (its tones, amplitudes and phases)."""
    return Drive(waveform.frequencies, waveform.amplitudes, waveform.phases)


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
    import dataclasses

    from planner.planning.motion import drive_peaks

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
            w = dataclasses.replace(
                w, samples=w.samples * scale, amplitudes=w.amplitudes * scale,
                peak=w.peak * scale, rms=w.rms * scale, scale=w.scale * scale,
                warnings=w.warnings + (f"every amplitude lowered by x{scale:.4g} to meet "
                                       "drive.max_acceleration_g",))
            zp, ap = drive_peaks(w)
        out[key] = w
        notes[key] = {"peak_displacement_m": zp, "peak_acceleration_m_s2": ap,
                      "acceleration_scale": scale}
    return out, notes

"""Stage 4, drives: the summed-tone drive of every step (tone amplitudes, synthesis)."""

from __future__ import annotations

from model import Drive
from planner.nodes import Node
from planner.planning.settings import Settings, tone_amplitudes


def synthesize_steps(settings: Settings, steps, assignment, seed=None):
    """Waveform of every step (the sum of its active impacters' tones), by step key.

    Step ``i`` is seeded with ``seed + i`` (``seed`` default ``settings.seed``).
    """
    from planner.synthesis import synthesize

    seed = settings.seed if seed is None else seed
    out = {}
    for st in steps:
        nodes = sorted(Node(d, dr).text for d, dr in st.active_nodes())
        freqs = sorted({assignment.frequencies[n] for n in nodes})
        amps = tone_amplitudes(settings, freqs)
        out[st.key] = synthesize(freqs, amps, settings.sample_rate_hz, seed=seed + st.index,
                                 peak_limit=settings.peak_limit_m)
    return out


def drive_of(waveform) -> Drive:
    """The model's drive of a waveform (its tones, amplitudes and phases)."""
    return Drive(waveform.frequencies, waveform.amplitudes, waveform.phases)

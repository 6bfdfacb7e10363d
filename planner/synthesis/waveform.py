"""The drive-signal type: :class:`Waveform`, one step's sampled loop with its tone table."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planner.synthesis.kernels import _cosines_at


@dataclass(frozen=True)
class Waveform:
    """One step's drive: a sampled loop of summed tones, with its tone table.

    Attributes
    ----------
    samples : ndarray, shape (n_samples,)
        Substrate displacement [m] at ``t = n / sample_rate``; a whole number of loops.
        Read-only.
    sample_rate : float
        Sample rate [Hz].
    frequencies : ndarray, shape (n_tones,)
        Tone frequencies as synthesised [Hz]: each on the loop's grid ``1 / loop_length``.
        Same order as requested.
    amplitudes : ndarray, shape (n_tones,)
        Tone amplitudes in the samples [m], after ``scale``.
    phases : ndarray, shape (n_tones,)
        Tone phases at ``t = 0`` [rad], in ``(-pi, pi]``.
    crest_factor : float
        ``peak / rms`` [-], with the continuous-time peak.
    loop_length : float
        Length of one seamless loop [s]; every tone makes a whole number of cycles in it.
    peak : float
        Peak of ``|zeta(t)|`` over continuous time [m] (what the piezo sees after the
        generator's reconstruction filter); at least ``max(abs(samples))``.
    rms : float
        Root mean square of ``zeta`` [m], ``sqrt(sum(amplitudes**2) / 2)``.
    scale : float
        Factor applied to the requested amplitudes to meet ``peak_limit`` [-]; 1 if none.
    frequency_shift : ndarray, shape (n_tones,)
        ``frequencies`` minus the requested frequencies [Hz] (snapping to the loop grid).
    warnings : tuple of str
        Everything a user should know: scaling, large shifts.
    """

    samples: np.ndarray = field(repr=False)
    sample_rate: float
    frequencies: np.ndarray
    amplitudes: np.ndarray
    phases: np.ndarray
    crest_factor: float
    loop_length: float
    peak: float
    rms: float
    scale: float = 1.0
    frequency_shift: np.ndarray | None = None
    warnings: tuple[str, ...] = ()

    def __post_init__(self):
        n = len(self.frequencies)
        for name in ("amplitudes", "phases"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name}: {len(getattr(self, name))} values for {n} frequencies")
        if self.frequency_shift is None:
            object.__setattr__(self, "frequency_shift", np.zeros(n))
        for name in ("samples", "frequencies", "amplitudes", "phases", "frequency_shift"):
            arr = np.array(getattr(self, name), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "warnings", tuple(self.warnings))

    @property
    def loop_points(self) -> int:
        """Samples in one loop [-]."""
        return int(round(self.loop_length * self.sample_rate))

    @property
    def n_loops(self) -> int:
        """Whole loops in :attr:`samples` [-]."""
        return len(self.samples) // self.loop_points

    @property
    def duration(self) -> float:
        """Length of :attr:`samples` [s]."""
        return len(self.samples) / self.sample_rate

    @property
    def times(self) -> np.ndarray:
        """Sample times [s], shape (n_samples,)."""
        return np.arange(len(self.samples)) / self.sample_rate

    @property
    def requested_frequencies(self) -> np.ndarray:
        """The frequencies asked for, before snapping to the loop grid [Hz]."""
        return self.frequencies - self.frequency_shift

    def evaluate(self, t) -> np.ndarray:
        """The exact sum of cosines at arbitrary times.

        Parameters
        ----------
        t : array_like
            Times [s].

        Returns
        -------
        ndarray
            ``zeta(t)`` [m], the shape of ``t``.
        """
        t = np.asarray(t, dtype=float)
        cycles = np.rint(self.frequencies * self.loop_length)
        u = np.mod(t / self.loop_length, 1.0)
        flat = _cosines_at(cycles, self.amplitudes, self.phases, u.ravel())
        return flat.reshape(t.shape)


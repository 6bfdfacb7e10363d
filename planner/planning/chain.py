"""The drive chain's stage (issue 46): every step's drive compensated for the measured
chain, its voltage limits enforced, what plan.json records of it, and its figure.

The designs and the verification see the die's displacement, as without a chain; the
chain changes what is *played*: the amplifier input [V], each tone divided by the
chain's transfer at its frequency (:func:`planner.synthesis.chain.compensate`), so that
the die feels the designed tones, and with an input limit the phases it is played at
(:func:`planner.planning.drives.synthesize_steps`: the input's peak held down where
that leaves the die more of its tones).  The limits are checked where they apply: the
generator's and amplifier's volts at the input (here), ``drive.peak_limit_um`` and
``drive.max_acceleration_g`` at the die (:mod:`planner.planning.drives`, unchanged),
both by :func:`limit_drives`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from planner.core.errors import PlanningError
from planner.core.nodes import Node
from planner.planning.settings import Settings
from planner.synthesis.chain import ChainError, compensate, distort, input_tones
from planner.core.units import UM

#: Distortion products weaker than this fraction of a step's strongest tone are left
#: out of what the verification simulates [-]: a product of 0.1 % of a tone, on an idle
#: impacter's resonance (Q <= 100 in air), swings it by at most a tenth of what that
#: tone, which it was designed to sit out, already may; and a 25-tone step has
#: thousands of weaker 3rd-order products that would each cost the simulation a tone.
PRODUCT_FLOOR_REL = 1e-3

#: Products of a gated burst's stretch below this are left out, as DC is: a static
#: offset of the die over a stretch of ms (model.Drive refuses tones below 10 Hz) [Hz].
QUASI_STATIC_HZ = 10.0

#: A hair under the input limit when a step is lowered to it, so that the refined peak
#: of the lowered drive is not above it by rounding (as the acceleration limit does) [-].
LIMIT_MARGIN = 1e-6


def input_waveform(settings: Settings, waveform):
    """What the generator plays for the die's ``waveform``: the amplifier input [V]
    (a loop or a gated burst alike, its gates kept).

    Raises
    ------
    PlanningError
        A tone outside the chain's measured transfer, naming it.
    """
    return played_input(settings.chain, waveform)


def played_input(chain, waveform):
    """:func:`input_waveform` of a :class:`~planner.synthesis.chain.DriveChain` (a plan's
    as read back from plan.json: ``vibroplan drive``, a re-plan)."""
    from planner.synthesis.gating import Burst, burst_samples

    transfer = chain.transfer
    try:
        if isinstance(waveform, Burst):
            a, ph = input_tones(transfer, waveform.frequencies, waveform.amplitudes,
                                waveform.phases)
            samples = burst_samples(waveform.frequencies, a, ph, waveform.starts_s,
                                    waveform.gates_s, waveform.ramp_s, waveform.times)
            rms = float(np.sqrt(np.sum(a ** 2) / 2))
            peak = max(_burst_input_peak(waveform, a, ph), float(np.max(np.abs(samples))))
            return dataclasses.replace(
                waveform, samples=samples, amplitudes=a, phases=ph, peak=peak, rms=rms,
                crest_factor=peak / rms if rms > 0 else 0.0,
                warnings=waveform.warnings + ("the samples are the amplifier input [V]: "
                                              "every tone divided by the chain's transfer",))
        return compensate(waveform, transfer)
    except ChainError as exc:
        raise PlanningError(f"drive.chain: {exc}") from None


def _burst_input_peak(burst, amplitudes_v, phases):
    from planner.synthesis.gating import burst_peaks

    return burst_peaks(dataclasses.replace(burst, amplitudes=amplitudes_v,
                                           phases=phases))[0]


def _tone_names(steps, frequencies):
    """Tone [Hz] -> the impacters it drives, as text (for messages)."""
    names = {}
    for st in steps:
        for d, dr in st.active_nodes():
            n = Node(d, dr)
            names.setdefault(float(frequencies[n]), set()).add(n.text)
    return names


def limit_input(settings: Settings, waveforms, steps, frequencies):
    """Enforce the chain's voltage limits on every step's loop (``waveforms``: step key
    -> the die's :class:`~planner.synthesis.Waveform`, after the acceleration limit).

    A tone whose own input, at the amplitude its convention asks for, is above the
    limit cannot be delivered: an error naming it, the impacters it drives, the
    transfer there and the volts it needs.  A step whose summed input peaks above the
    limit has every tone lowered by one factor (as ``drive.max_acceleration_g`` does),
    which the designs and the verification then see.

    Returns
    -------
    (waveforms, notes)
        ``notes``: step key -> {"input_peak_v" (after any lowering), "input_scale"}.

    Raises
    ------
    PlanningError
        A tone the chain cannot deliver (outside a measured transfer, or beyond the
        limit by itself).
    """
    from planner.planning.drives import scaled

    chain = settings.chain
    limit = chain.input_limit
    names = _tone_names(steps, frequencies)
    out, notes = {}, {}
    for key, w in waveforms.items():
        v = input_waveform(settings, w)
        scale = 1.0
        if limit is not None:
            lim, field = limit
            # each tone at its convention's amplitude, before any lowering of the sum
            wanted = v.amplitudes / (w.scale if w.scale > 0 else 1.0)
            for f, need in zip(w.frequencies, wanted):
                if need > lim:
                    h = chain.response(float(f))
                    who = ", ".join(sorted(_near(names, f))) or "its impacter"
                    raise PlanningError(
                        f"drive.chain cannot deliver the tone {f:.1f} Hz ({who}, step "
                        f"{key}): the transfer there is {abs(h) / UM:.4g} um/V at "
                        f"{np.degrees(np.angle(h)):.1f} deg, so its "
                        f"{need * abs(h) / UM:.4g} um at the die need {need:.4g} V at the "
                        f"amplifier input, above {lim:.4g} V ({field}): a higher limit, "
                        "a lower drive.power_m2_s3 or amplitude_um, or a band that keeps "
                        "the tones off the chain's weak frequencies")
            if v.peak > lim:
                scale = lim / v.peak * (1.0 - LIMIT_MARGIN)
                w = scaled(w, scale, f"every amplitude lowered by x{scale:.4g} to meet "
                                     f"{field} at the amplifier input")
                v = input_waveform(settings, w)
        out[key] = w
        notes[key] = {"input_peak_v": float(v.peak), "input_scale": scale}
    return out, notes


def limit_drives(settings: Settings, waveforms, steps, frequencies):
    """Every limit on a step's loop, in turn: ``drive.max_acceleration_g`` at the die
    (:func:`planner.planning.drives.limit_acceleration`), then with ``drive.chain`` its
    voltage limits at the amplifier input (:func:`limit_input`: a tone it cannot
    deliver refused, a step over the limit lowered).  Every place that synthesises a
    step's loop anew (the plan's rounds, a re-plan's new phase draws) holds it to them
    here.

    Parameters
    ----------
    waveforms : dict
        Step key -> the die's :class:`~planner.synthesis.Waveform` (loops, not gated
        bursts).
    steps : sequence of Step
        The steps of ``waveforms`` (the input limit's messages name their impacters).
    frequencies : dict
        Node -> tone [Hz].

    Returns
    -------
    (waveforms, notes)
        As ``limit_acceleration``'s, with a chain each step's note also holding
        ``input_peak_v`` and ``input_scale``.
    """
    from planner.planning.drives import limit_acceleration

    out, notes = limit_acceleration(settings, waveforms)
    if settings.chain is not None:
        out, input_notes = limit_input(settings, out, steps, frequencies)
        notes = {k: {**v, **input_notes[k]} for k, v in notes.items()}
    return out, notes


def _near(names, f):
    """The impacters of the tone nearest ``f`` (a tone as snapped to its loop)."""
    if not names:
        return set()
    best = min(names, key=lambda t: abs(t - float(f)))
    return names[best]


def check_bursts(settings: Settings, played):
    """A gated burst (a ``targets_um`` step) plays its tones at their amplitudes as
    synthesised, one after the other: its input peak must be within the limit as it
    is (it is not lowered: its gates were found for these amplitudes).

    Raises
    ------
    PlanningError
        Naming the step, its input peak and the limit.
    """
    from planner.synthesis.gating import Burst

    limit = settings.chain.input_limit
    if limit is None:
        return
    lim, field = limit
    for key, w in played.items():
        if isinstance(w, Burst):
            v = input_waveform(settings, w)
            if v.peak > lim:
                loud = int(np.argmax(v.amplitudes))
                raise PlanningError(
                    f"drive.chain: the gated burst of step {key} peaks at {v.peak:.4g} V at "
                    f"the amplifier input, above {lim:.4g} V ({field}); its loudest tone "
                    f"is {w.frequencies[loud]:.1f} Hz ({v.amplitudes[loud]:.4g} V)")


def chain_record(settings: Settings, played, notes, steps=(), frequencies=None) -> dict:
    """plan.json's ``chain`` block: the transfer and nonlinearity as used, the input
    limit, per step the input's peak, every tone's transfer and input and how many
    distortion products the verification simulated, and the products that land on an
    idle impacter's band (:func:`products_near_idle`)."""
    chain = settings.chain
    tr = chain.transfer
    if hasattr(tr, "frequency_hz"):
        transfer = {"kind": "table", "file": tr.source, "band_hz": list(tr.band_hz),
                    "points": len(tr.frequency_hz)}
    else:
        transfer = {"kind": "model", "gain_m_per_v": tr.gain_m_per_v,
                    "resonances": [{"frequency_hz": f, "q": q} for f, q in tr.resonances],
                    "low_pass_hz": tr.low_pass_hz}
    lim = chain.input_limit
    steps_, steps = steps, {}
    for key, w in played.items():
        v = input_waveform(settings, w)
        h = chain.response(w.frequencies)
        steps[key] = {
            "input_peak_v": float(v.peak),
            "input_scale": float((notes.get(key) or {}).get("input_scale", 1.0)),
            "tones": [{"frequency_hz": float(f), "gain_m_per_v": float(abs(g)),
                       "phase_rad": float(np.angle(g)), "input_amplitude_v": float(a),
                       "input_phase_rad": float(p)}
                      for f, g, a, p in zip(w.frequencies, h, v.amplitudes, v.phases)]}
    nl = chain.nonlinearity
    drives = die_drives(settings, played)
    for key, d in drives.items():
        if isinstance(d, DieDrive):
            steps[key]["products_simulated"] = int(np.sum(d.is_product))
        elif isinstance(d, DieBurst):
            steps[key]["products_simulated"] = int(len(d.products_hz))
    near = (products_near_idle(settings, steps_, drives, frequencies)
            if frequencies is not None else [])
    return {"signal": "amplifier_input_v", "transfer": transfer,
            "nonlinearity": {"a2_per_m": nl.a2, "a3_per_m2": nl.a3,
                             "product_floor_rel": PRODUCT_FLOOR_REL},
            "input_limit_v": None if lim is None else lim[0], "steps": steps,
            "products_near_idle": near}


def chain_figure(settings: Settings, played, path, title="", near=None):
    """Save a PNG: the chain's gain and phase over the band with every tone of the plan
    on it, the compensated input of the step with the most tones against the ideal
    sum (the die's drive in volts of the chain's gain at the band's bottom), and, for a
    distorting chain, the distortion products that land near idle impacters.

    Parameters
    ----------
    settings : Settings
        With a chain.
    played : dict
        Step key -> the die's drive (Waveform or gated Burst).
    path : path
        The PNG.
    near : list of dict, optional
        :func:`products_near_idle`'s rows (plan.json's ``chain.products_near_idle``):
        each product's frequency and amplitude at the die, its idle impacter's tone
        marked beside it, the strongest named.  None or empty: the panel says none.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    chain = settings.chain
    lo, hi = settings.band_hz
    tr_band = getattr(chain.transfer, "band_hz", None)
    f_lo, f_hi = (max(lo / 1.5, tr_band[0]), min(hi * 1.5, tr_band[1])) if tr_band else (
        lo / 1.5, hi * 1.5)
    f = np.geomspace(f_lo, f_hi, 800)
    h = chain.response(f)
    tones = np.array(sorted({float(t) for w in played.values() for t in w.frequencies}))
    ht = chain.response(tones) if len(tones) else np.zeros(0, complex)

    nl = chain.nonlinearity
    distorting = bool(nl.a2 or nl.a3)
    fig = Figure(figsize=(9, 12 if distorting else 9), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(4 if distorting else 3, 1)
    ax_g, ax_p, ax_t = axes[:3]
    if distorting:
        _products_panel(axes[3], near or [], (lo, hi))
    ax_g.loglog(f, np.abs(h) / UM, color="C0", lw=1.2, label="|H| (chain)")
    ax_g.plot(tones, np.abs(ht) / UM, "o", ms=3, color="C3", label="the plan's tones")
    ax_g.axvspan(lo, hi, color="0.9", zorder=0, label="drive.band_hz")
    ax_g.set_ylabel("gain [um/V]")
    ax_g.legend(fontsize=8)
    ax_g.set_title(title or "drive chain: amplifier input to die displacement")
    ax_p.semilogx(f, np.degrees(np.unwrap(np.angle(h))), color="C0", lw=1.2)
    ax_p.plot(tones, np.degrees(np.angle(ht)), "o", ms=3, color="C3")
    ax_p.axvspan(lo, hi, color="0.9", zorder=0)
    ax_p.set_ylabel("phase [deg]")
    ax_p.set_xlabel("frequency [Hz]")
    if played:
        key = max(played, key=lambda k: (len(played[k].frequencies), k))
        w = played[key]
        v = input_waveform(settings, w)
        span = min(w.loop_length, 2e-3)
        t = np.linspace(0.0, span, 4000)
        g0 = abs(chain.response(lo))
        ax_t.plot(t * 1e3, w.evaluate(t) / g0, color="0.5", lw=0.8,
                  label=f"ideal sum (die drive / {g0 / UM:.3g} um/V)")
        ax_t.plot(t * 1e3, v.evaluate(t), color="C1", lw=0.8,
                  label=f"compensated input (peak {v.peak:.3g} V)")
        ax_t.set_xlabel("time [ms]")
        ax_t.set_ylabel("amplifier input [V]")
        ax_t.set_title(f"step {key}: {len(w.frequencies)} tones", fontsize=9)
        ax_t.legend(fontsize=8, loc="upper right")
    fig.savefig(path, dpi=110)


#: Products the figure names (the strongest, by amplitude at the die).
FIGURE_NAMED_PRODUCTS = 6


def _products_panel(ax, near, band):
    """The chain figure's panel of distortion products near idle impacters: each
    product's amplitude at the die [nm] at its frequency, the idle impacter's tone as a
    dotted line beside it, the strongest :data:`FIGURE_NAMED_PRODUCTS` named."""
    ax.set_xscale("log")
    ax.axvspan(*band, color="0.9", zorder=0)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("product at the die [nm]")
    if not near:
        ax.set_title("distortion products near idle impacters: none within "
                     "drive.guard.relative_bandwidth", fontsize=9)
        ax.set_xlim(band[0] / 1.5, band[1] * 1.5)
        return
    pf = np.array([r["product_hz"] for r in near])
    pa = np.array([r["amplitude_m"] for r in near]) * 1e9
    tones = sorted({r["impacter_hz"] for r in near})
    for t in tones:
        ax.axvline(t, color="C2", lw=0.6, ls=":", zorder=1)
    ax.vlines(pf, 0.0, pa, color="C3", lw=1.0, zorder=2)
    ax.plot(pf, pa, "v", ms=4, color="C3",
            label=f"{len(near)} products within the guard band of an idle impacter")
    ax.plot([], [], color="C2", lw=0.6, ls=":", label="that impacter's tone")
    for r in near[:FIGURE_NAMED_PRODUCTS]:
        ax.annotate(f"{r['impacter']} ({r['step']})", (r["product_hz"],
                                                       r["amplitude_m"] * 1e9),
                    textcoords="offset points", xytext=(3, 3), fontsize=7)
    ax.set_ylim(0.0, float(pa.max()) * 1.3)
    ax.set_title("distortion products near idle impacters (at the spec's distortion)",
                 fontsize=9)
    ax.legend(fontsize=8, loc="upper right")


def chain_section(block):
    """report.md's "Drive chain" section of plan.json's ``chain`` block."""
    from planner.core.markdown import Section, md_table

    tr = block["transfer"]
    if tr["kind"] == "table":
        what = (f"the measured table {tr['file'] or ''} ({tr['points']} points, "
                f"{tr['band_hz'][0]:g}-{tr['band_hz'][1]:g} Hz)")
    else:
        res = ", ".join(f"{r['frequency_hz']:g} Hz (Q {r['q']:g})" for r in tr["resonances"])
        what = (f"a flat {tr['gain_m_per_v'] / UM:g} um/V"
                + (f" with resonances at {res}" if res else "")
                + (f", low-pass {tr['low_pass_hz']:g} Hz" if tr["low_pass_hz"] else ""))
    lim = block["input_limit_v"]
    lines = [f"Every waveform file is the **amplifier input in volts** (sidecar "
             f"`signal: amplifier_input_v`): each tone divided by the chain's transfer, "
             f"{what}, so that the die feels the designed tones (figure: "
             f"[drive_chain.png](figures/drive_chain.png)). Input limit: "
             + (f"{lim:.4g} V: a step of several tones plays the phases that hold down "
                "the input's peak where that leaves the die more of its tones under every "
                "limit, else the phases optimised for the die." if lim is not None else
                "none given: the steps play the phases optimised for the die."), ""]
    rows = []
    for key, st in block["steps"].items():
        gains = [t["gain_m_per_v"] / UM for t in st["tones"]]
        rows.append([key, len(st["tones"]), f"{min(gains):.3g}-{max(gains):.3g}",
                     f"{st['input_peak_v']:.4g}", f"{st['input_scale']:.4g}"])
    lines += md_table(["step", "tones", "transfer at its tones [um/V]", "input peak [V]",
                       "lowered for the input limit"], rows)
    lines.append("")
    nl = block["nonlinearity"]
    if nl["a2_per_m"] or nl["a3_per_m2"]:
        n = sum(st.get("products_simulated", 0) for st in block["steps"].values())
        near = block.get("products_near_idle") or []
        lines.append(f"Every step was verified with the distortion simulated: its "
                     f"tones and their harmonic and intermodulation products at the die "
                     f"({n} products over all steps, those above "
                     f"{nl['product_floor_rel']:.1%} of the step's strongest tone; a gated "
                     f"burst's in each of its stretches, ramps included). {len(near)} "
                     "products land "
                     "within drive.guard.relative_bandwidth of an impacter idle in their "
                     "step" + (", the strongest:" if near else "."))
        if near:
            lines.append("")
            lines += md_table(["step", "idle impacter", "its tone [Hz]", "product [Hz]",
                               "at the die [nm]"],
                              [[r["step"], r["impacter"], f"{r['impacter_hz']:.1f}",
                                f"{r['product_hz']:.1f}", f"{r['amplitude_m'] * 1e9:.3g}"]
                               for r in near[:15]])
            lines.append("")
            lines.append("Whether one of them moves a slider is the verification's "
                         "verdict above (every idle slider checked under these drives).")
    else:
        lines.append("No distortion given (drive.chain.harmonics_db): the steps are "
                     "verified with the designed die drive.")
    return Section("Drive chain", lines)


@dataclass(frozen=True)
class DieDrive:
    """What the die feels of a looped step through the chain's distortion: the designed
    tones (with the cubic term's share) and their harmonic and intermodulation products
    (:func:`planner.synthesis.chain.distort`), all on the step's loop.  The
    verification reads its tones (:func:`planner.planning.drives.program_of`).

    Attributes
    ----------
    frequencies, amplitudes, phases : ndarray, shape (n,)
        [Hz], [m], [rad].
    loop_length : float or None
        [s] (None: a drive read back from plan.json, its tones off any grid).
    is_product : ndarray of bool, shape (n,)
        A product (True) or a designed tone.
    """

    frequencies: np.ndarray
    amplitudes: np.ndarray
    phases: np.ndarray
    loop_length: float
    is_product: np.ndarray


@dataclass(frozen=True)
class DieBurst:
    """What the die feels of a gated burst (a ``targets_um`` step) through the chain's
    distortion: each of the burst's stretches of constant tones
    (:meth:`planner.synthesis.gating.Burst.program`, its ramps included as the exact
    sum of constant tones they are) with its harmonic and intermodulation products
    (:func:`planner.synthesis.chain.distort_tones`), played in turn.  The
    verification and the scenes play :meth:`program`
    (:func:`planner.planning.drives.program_of` dispatches on ``gates_s``).

    Attributes
    ----------
    burst : Burst or RecordedDrive
        The burst as designed (its tones, starts and gates).
    stretches : tuple of (float, model.Drive)
        (duration [s], the die's drive) of every stretch, products included.
    products_hz, products_m : ndarray, shape (n,)
        Every product line of any stretch [Hz] and its largest amplitude [m].
    """

    burst: object
    stretches: tuple
    products_hz: np.ndarray
    products_m: np.ndarray

    @property
    def gates_s(self):
        return self.burst.gates_s

    @property
    def frequencies(self):
        return self.burst.frequencies

    @property
    def amplitudes(self):
        return self.burst.amplitudes

    @property
    def phases(self):
        return self.burst.phases

    def program(self):
        """The die's stretches, as :meth:`planner.synthesis.gating.Burst.program`'s."""
        return self.stretches


def _die_burst(burst, nl):
    """:class:`DieBurst` of ``burst`` under ``nl``: every stretch distorted, its products
    above :data:`PRODUCT_FLOOR_REL` of the burst's strongest tone."""
    import model
    from planner.synthesis.chain import distort_tones

    floor = PRODUCT_FLOOR_REL * float(np.max(burst.amplitudes))
    stretches, lines = [], {}
    for duration, drive in burst.program():
        f0 = np.asarray(drive.frequencies, dtype=float)
        a0 = np.asarray(drive.amplitudes, dtype=float)
        if not np.any(a0 > 0):
            stretches.append((duration, drive))         # the drive off between tones
            continue
        f, a, ph, prod = distort_tones(f0, a0, np.asarray(drive.phases, dtype=float), nl,
                                       floor)
        # a difference product of a ramp's sidebands a few Hz above DC is a static
        # offset of the die over the stretch, as DC is (left out)
        keep = ~prod | (f >= QUASI_STATIC_HZ)
        f, a, ph, prod = f[keep], a[keep], ph[keep], prod[keep]
        stretches.append((duration, model.Drive(f, a, np.mod(ph, 2.0 * np.pi))))
        for fp, ap in zip(f[prod], a[prod]):
            key = round(float(fp), 3)
            lines[key] = max(lines.get(key, 0.0), float(ap))
    keys = sorted(lines)
    return DieBurst(burst, tuple(stretches), np.array(keys, dtype=float),
                    np.array([lines[k] for k in keys], dtype=float))


def die_drive(settings: Settings, waveform):
    """The die's drive of a step through the chain's distortion: a loop's
    :class:`DieDrive`, a gated burst's :class:`DieBurst`; the drive as it is for a chain
    without harmonics."""
    nl = settings.chain.nonlinearity
    if not (nl.a2 or nl.a3) or not len(waveform.frequencies):
        return waveform
    if getattr(waveform, "gates_s", None) is not None:
        # a gated burst (or one read back from plan.json): its stretches distorted
        return _die_burst(waveform, nl)
    floor = PRODUCT_FLOOR_REL * float(np.max(waveform.amplitudes))
    loop = getattr(waveform, "loop_length", None)
    if loop is None:
        # a loop read back from plan.json (a chip's verification of the plan's drive):
        # its tones as they are, off any grid
        from planner.synthesis.chain import distort_tones

        f, a, ph, prod = distort_tones(waveform.frequencies, waveform.amplitudes,
                                       waveform.phases, nl, floor)
        return DieDrive(f, a, ph, None, prod)
    cycles = np.rint(np.asarray(waveform.frequencies) * loop)
    k, a, ph, prod = distort(cycles, waveform.amplitudes, waveform.phases, nl, floor)
    return DieDrive(k / loop, a, ph, loop, prod)


def die_drives(settings: Settings, played) -> dict:
    """:func:`die_drive` of every step (step key -> drive); ``played`` itself without a
    distorting chain."""
    if settings.chain is None or not (settings.chain.nonlinearity.a2
                                      or settings.chain.nonlinearity.a3):
        return played
    return {k: die_drive(settings, w) for k, w in played.items()}


def products_near_idle(settings: Settings, steps, drives, frequencies):
    """The guard rules' warnings as facts: every distortion product of a step that lands
    within ``drive.guard.relative_bandwidth`` of an impacter idle in that step.

    Returns
    -------
    list of dict
        ``step``, ``impacter``, ``impacter_hz``, ``product_hz``, ``amplitude_m`` (at the
        die, at the spec's distortion), strongest first.
    """
    rel = settings.tone_rules.relative_bandwidth
    out = []
    for st in steps:
        d = drives.get(st.key)
        if isinstance(d, DieDrive):
            pf, pa = d.frequencies[d.is_product], d.amplitudes[d.is_product]
        elif isinstance(d, DieBurst):
            pf, pa = d.products_hz, d.products_m
        else:
            continue
        active = {Node(dv, dr) for dv, dr in st.active_nodes()}
        for n, f in frequencies.items():
            if n in active:
                continue
            near = np.abs(pf - f) <= rel * f
            for fp, ap in zip(pf[near], pa[near]):
                out.append({"step": st.key, "impacter": n.text, "impacter_hz": float(f),
                            "product_hz": float(fp), "amplitude_m": float(ap)})
    out.sort(key=lambda r: (-r["amplitude_m"], r["step"], r["impacter"]))
    return out

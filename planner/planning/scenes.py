"""Stage 5b, scenes: each scene simulated in order with the state carried across steps."""

from __future__ import annotations

import numpy as np

import model
from model import Drive
from planner.nodes import Node
from planner.planning.drives import drive_of
from planner.planning.settings import SETTLE_S
from planner.planning.verify import kicks

#: Step name of the undriven tail in the scene rows (``"driven": false``).
SETTLE_NAME = "(drive off)"
#: |v| [m/s] above which an impacter counts as still ringing at the end of a step.
RINGING_V = 1e-6


def _scene_phase(impacters, sliders, drive, duration, states, sl_states, active,
                 idle_tolerance):
    """Advance every impacter and slider through one phase (a step, or the undriven
    tail) from the carried states; updates them in place and returns the scene row's
    fields.  ``idle_tolerance`` [m]: a slider none of whose impacters is driven and that
    moves more than this is listed in ``idle_moved_m``."""
    kick_lists = {d: ([], []) for d in sliders}
    idle_hits = {}
    for n, imp in impacters.items():
        x0, v0, stuck = states[n]
        res = model.simulate(imp, drive, x0, v0, duration, stuck=stuck or None,
                             max_events=1_000_000)
        states[n] = (min(res.x_end, imp.gap), res.v_end, res.stuck_end)
        node = Node.parse(n)
        t, dv = kicks(imp, sliders[node.device], res, node.sign)
        kick_lists[node.device][0].append(t)
        kick_lists[node.device][1].append(dv)
        hits = res.times.size + res.chatter_times.size
        if hits and n not in active:
            idle_hits[n] = int(hits)
    positions, moved = {}, {}
    driven_devices = {Node.parse(n).device for n in active}
    for dev, slider in sliders.items():
        z0, v0 = sl_states[dev]
        t = np.concatenate(kick_lists[dev][0]) if kick_lists[dev][0] else np.empty(0)
        dv = np.concatenate(kick_lists[dev][1]) if kick_lists[dev][1] else np.empty(0)
        _, _, z, v, _ = model.slider_motion(slider, drive, t, dv, duration, z0, v0)
        sl_states[dev] = (z, v)
        positions[dev] = float(z)
        if abs(z - z0) > idle_tolerance and dev not in driven_devices:
            moved[dev] = float(z - z0)
    ringing = sorted(n for n, (x, v, s) in states.items()
                     if abs(v) > RINGING_V and n not in active)
    return {"positions_m": positions, "ringing_impacters": ringing, "idle_hits": idle_hits,
            "idle_moved_m": moved}


def simulate_scenes(settings, steps, waveforms, impacters, sliders):
    """Each scene in order, carrying impacter and slider states across steps.

    Every scene starts from rest; each step starts from the state the previous one
    left, so an impacter that keeps ringing after its tone stops moves its slider in
    the next step.  After the last step the drive is switched off for
    ``settings.settle_s`` (:data:`planner.planning.settings.SETTLE_S`) so that the
    overshoot of that ringing is counted too.

    ``settings`` is a :class:`~planner.planning.settings.Settings` (a
    :class:`~planner.spec.LoadedSpec` is converted).

    Returns
    -------
    list of dict
        One row per step and one for the undriven tail of each scene (step
        :data:`SETTLE_NAME`, ``driven`` false): slider positions [m] at its end,
        the impacters still ringing then (idle ones moving faster than
        :data:`RINGING_V`), ``idle_hits``: impacter -> impacts of every impacter that
        hit its slider while its step did not drive it, and ``idle_moved_m``: device ->
        displacement [m] of every slider that moved more than the spec's idle tolerance
        in a phase that drove none of its impacters (in the undriven tail: the
        overshoot).  The per-step verification starts every impacter from rest or
        the x0 grid; this is where the state a previous step left shows.
    """
    from planner.planning.settings import Settings, resolve_settings

    if not isinstance(settings, Settings):
        settings = resolve_settings(settings)
    tol = settings.idle_tolerance_m
    settle = settings.settle_s
    rows = []
    rest = Drive([1.0], [0.0])      # the drive switched off
    for scene in settings.scenes:
        states = {n: (0.0, 0.0, False) for n in impacters}
        sl_states = {d: (0.0, 0.0) for d in sliders}
        for st in [s for s in steps if s.scene == scene]:
            active = {Node(d, r).text for d, r in st.active_nodes()}
            fields = _scene_phase(impacters, sliders, drive_of(waveforms[st.key]),
                                  st.duration_s, states, sl_states, active, tol)
            rows.append({"scene": scene, "step": st.name, "driven": True,
                         "duration_s": st.duration_s, **fields})
        fields = _scene_phase(impacters, sliders, rest, settle, states, sl_states, set(), tol)
        rows.append({"scene": scene, "step": SETTLE_NAME, "driven": False,
                     "duration_s": settle, **fields})
    return rows


def scene_overshoot(scene_rows):
    """Scene -> {device: overshoot [m]}: how far each slider moved once the drive was
    switched off after the scene's last step (the rows of :func:`simulate_scenes`)."""
    out = {}
    for scene in dict.fromkeys(r["scene"] for r in scene_rows):
        rows = [r for r in scene_rows if r["scene"] == scene]
        driven = [r for r in rows if r["driven"]]
        tail = [r for r in rows if not r["driven"]]
        if not tail:
            continue
        last = driven[-1]["positions_m"] if driven else {}
        out[scene] = {dev: z - last.get(dev, 0.0) for dev, z in tail[0]["positions_m"].items()}
    return out

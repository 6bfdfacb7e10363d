"""Why the tones of a targets step take turns: slider motion under k tones at once.

Reads a plan (the default one: ``vibroplan plan --out DIR``), takes the tones of its
multi-tone step, and for k = 1, 2, 3, 4, 6 and all of them played together (each at
its amplitude and phase in that step) simulates the sliders of those tones from rest
for 30 ms: their travel, speed, the largest travel in any 0.1 ms, and the peak of
the tones' summed base acceleration against the sliders' dynamic friction over their
mass.  Then, for the first device alone and with its first partner, the travel against
the tone's playing time in 50 us steps (the resolution a gate has).  Used for the
measurements in docs/targets.md.

    python docs/targets_probe.py DIR [--step position_all/position] [--devices B1,E5,...]
"""

import argparse
import json
from pathlib import Path

import numpy as np

from planner.fabrication.tolerances import design_from_plan, nominal_impacter
from planner.synthesis.gating import burst_peaks, gate
from planner.planning.motion import rest_state
from planner.planning.settings import G0, resolve_settings
from planner.planning.targets import RAMP_S, _Simulation
from planner.arrayspec import ArraySpec, LoadedSpec, resolve_steps
from planner.synthesis import synthesize

WINDOW_S = 0.03
CHUNK_S = 1e-4


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("plan", help="a plan folder (or its plan.json)")
    ap.add_argument("--step", default="position_all/position")
    ap.add_argument("--devices", default="B1,E5,C4,A1,D2,A3",
                    help="the tones' devices, in the order they are added")
    args = ap.parse_args()
    path = Path(args.plan)
    data = json.loads((path / "plan.json" if path.is_dir() else path).read_text())
    spec = ArraySpec.model_validate(data["spec"])
    settings = resolve_settings(LoadedSpec(spec, resolve_steps(spec), "plan.json"))
    chip = design_from_plan(data, spec)
    impacters = {n.id: nominal_impacter(spec, n) for n in chip.nodes}
    rec = next(s for s in data["steps"] if f"{s['scene']}/{s['name']}" == args.step)
    tones = rec["tones"]
    loop = synthesize([t["frequency_hz"] for t in tones], [t["amplitude_m"] for t in tones],
                      settings.sample_rate_hz, phases=[t["phase_rad"] for t in tones])
    direction = "forward" if rec["forward"] else "backward"
    freq = {n: r["frequency_hz"] for n, r in ((r["id"], r) for r in data["impacters"])}
    index = {d: int(np.argmin(np.abs(loop.frequencies - freq[f"{d}.{direction}"])))
             for d in rec["forward"] + rec["backward"]}
    states = {n: rest_state(i) for n, i in impacters.items()}
    slider = settings.sliders[rec["forward"][0] if rec["forward"] else rec["backward"][0]]
    friction = slider.dynamic_friction / slider.mass
    print(f"{args.step}: {len(tones)} tones; sliders' dynamic friction / mass "
          f"{friction / G0:.0f} g, static {slider.static_friction / slider.mass / G0:.0f} g")
    wanted = args.devices.split(",")
    sign = 1.0 if direction == "forward" else -1.0

    def run(devices, playing, window):
        movers = {d: (f"{d}.{direction}", index[d], sign) for d in devices}
        sim = _Simulation(settings, impacters, settings.sliders, movers, states, {})
        gates = np.zeros(len(loop.frequencies))
        for d in playing:
            gates[index[d]] = window
        burst = gate(loop, np.zeros_like(gates), gates, RAMP_S)
        return sim, burst

    print("k  peak [g]  device: travel in 30 ms [um], speed [mm/s], largest 0.1 ms step [um]")
    for k in (1, 2, 3, 4, 6, len(index)):
        playing = wanted[:k] if k <= len(wanted) else list(index)
        shown = playing[:6]
        sim, burst = run(shown, playing, WINDOW_S)
        _, ap_ = burst_peaks(burst)
        t, tr = sim.trajectory(burst.program(), CHUNK_S, shown)
        cells = []
        for d in shown:
            z = sign * tr[d] / 1e-6
            cells.append(f"{d} {z[-1]:.1f} {z[-1] / (WINDOW_S * 1e3):.2f} {np.diff(z).max():.2f}")
        print(f"{k:<2} {ap_ / G0:8.0f}  " + "; ".join(cells))
    for partners in ([], wanted[1:2]):
        d = wanted[0]
        sim, _ = run([d], [d] + partners, WINDOW_S)
        travel = []
        for played in np.arange(0.010, 0.012, 5e-5):
            gates = np.zeros(len(loop.frequencies))
            gates[index[d]] = played
            for p in partners:
                gates[index[p]] = WINDOW_S
            burst = gate(loop, np.zeros_like(gates), gates, RAMP_S)
            travel.append(sign * sim.travel(burst.program())[d] / 1e-6)
        steps = np.abs(np.diff(travel))
        print(f"{d} playing 10-12 ms" + (f" beside {partners[0]}" if partners else " alone")
              + f": travel {travel[0]:.2f}-{travel[-1]:.2f} um, per 50 us step median "
              f"{np.median(steps):.3f} um, largest {steps.max():.3f} um")


if __name__ == "__main__":
    main()

"""Slider speed under the two contact laws for Fig. 7's device (docs/contact.md).

Run from the repository root:  python docs/contact_table.py

The impacter is Fig. 7's (A = 1.5e4 um^2, w = 4 um, l = 1242 um, c = 3 um, nu_n = 5.2 kHz)
driven by one 6.2 kHz tone at Z0^2 w^3 = 50 m^2/s^3 from x0 = 0 for 3 ms.  Its mass is
then scaled to m/M = 0.5, 1, 2 and 5 with k scaled alike, so nu_n and the impacter's
trajectory (hence every impact time and v-) stay the same: only the contact law acts.
"""

from dataclasses import replace

import numpy as np

import model
from model import Drive, Impacter, Kicks, Slider

DURATION = 3e-3


def peak_slider_speed(slider, drive, kicks, contact):
    """Largest |V| just after a kick [m/s]: friction only slows the slider between kicks.

    Each kick is reached by its own run of the slider kernel ending just after it.
    """
    peak = 0.0
    for t in np.unique(kicks.times):
        _, _, _, v, _ = model.slider_motion(slider, drive, kicks, duration=t * (1 + 1e-12),
                                            contact=contact)
        peak = max(peak, abs(v))
    return peak


def rows():
    fig7 = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200)
    slider = Slider.from_geometry(8.0e-8)
    drive = Drive.tone(6200.0)
    impacts = model.simulate(fig7, drive, duration=DURATION)
    vmax = float(impacts.velocities.max())
    c = np.cos(fig7.impact_angle)
    for ratio in (fig7.mass / slider.mass, 0.5, 1.0, 2.0, 5.0):
        m = ratio * slider.mass
        imp = replace(fig7, mass=m, stiffness=fig7.stiffness * m / fig7.mass)
        kicks = Kicks.from_impacts(imp, slider, impacts)
        out = {"ratio": ratio}
        for contact in ("paper", "two_body"):
            res = model.simulate_slider(imp, slider, drive, duration=DURATION, contact=contact)
            assert res.impacts.n_impacts == impacts.n_impacts
            out[contact] = res.mean_velocity
            out[contact + "_peak"] = peak_slider_speed(slider, drive, kicks, contact)
        out["vmax"] = vmax
        out["bound"] = (1 + fig7.restitution) * vmax / c
        yield out


def energy_rows(e=0.5, theta=np.pi / 4):
    """Per-kick energy balance from rest, as fractions of the pair's incoming m v-^2."""
    for ratio in (0.01, 0.1, 1 / 3, 0.452, 0.5, 1.0, 2.0, 5.0, 10.0):
        q = 2 * ratio * np.cos(theta) ** 2
        yield (ratio, q, e * e + (1 + e) ** 2 * q, (e * e + q) / (1 + q),
               (1 + e) ** 2 * q / (1 + q) ** 2, (q - e) / (1 + q))


def main():
    print("Energy after / before one kick of a slider at rest (e = 0.5, theta = 45 deg):\n")
    print("| m/M | q = 2 (m/M) cos^2(theta) | paper: e^2 + (1+e)^2 q | two_body: (e^2 + q)/(1+q) "
          "| two_body, slider's share | two_body tip v+/v- = (q - e)/(1+q) |")
    print("|---|---|---|---|---|---|")
    for ratio, q, paper, two, share, rebound in energy_rows():
        print(f"| {ratio:.3g} | {q:.3g} | {paper:.3f} | {two:.3f} | {share:.3f} | {rebound:+.3f} |")
    print("\nFig. 7's device at 6.2 kHz, 3 ms, x0 = 0, impacter mass scaled:\n")
    print("| m/M | paper [mm/s] | two_body [mm/s] | two_body / paper | peak V paper [m/s] "
          "| peak V two_body [m/s] | tip max v- [m/s] | (1+e) max v- / cos(theta) [m/s] |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows():
        print(f"| {r['ratio']:.3g} | {r['paper'] * 1e3:.3f} | {r['two_body'] * 1e3:.3f} "
              f"| {r['two_body'] / r['paper']:.3f} | {r['paper_peak']:.3f} "
              f"| {r['two_body_peak']:.3f} | {r['vmax']:.3f} | {r['bound']:.3f} |")


if __name__ == "__main__":
    main()

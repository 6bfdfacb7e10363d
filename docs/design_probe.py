"""Design single impacters of an array spec over several designer seeds.

The planner designs each impacter once (plus retries); this shows how the fast budget's
result scatters with the seed, and what a summed drive does to it.  Used for the
measurements in docs/array_default.md.

    python docs/design_probe.py configs/array_5x5.yaml A4.backward,D3.backward --seeds 6
    python docs/design_probe.py configs/array_5x5.yaml D3.backward --without-drives

Each line: impacter, tone [Hz], then per designer seed the predicted slider speed
[mm/s] / m/M / seconds, an X in front of an infeasible design.
"""

import argparse
import time

from planner.assignment.assign import assign
from planner.designer import Ensemble, design_impacter
from planner.core.nodes import Node
from planner.planning.exposure import driven_ensembles, idle_ensembles, played_tones
from planner.planning.drives import drive_of, limit_acceleration, synthesize_steps
from planner.planning.settings import resolve_settings
from planner.arrayspec import load_spec


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec")
    ap.add_argument("impacters", help="comma-separated ids, e.g. A4.backward")
    ap.add_argument("--seeds", type=int, default=4, help="designer seeds 0..N-1")
    ap.add_argument("--plan-seed", type=int, default=0, help="the plan's --seed (phases)")
    ap.add_argument("--without-drives", action="store_true",
                    help="leave out the summed drives of the multi-tone steps")
    args = ap.parse_args()
    s = resolve_settings(load_spec(args.spec), args.plan_seed)
    a = assign(s, s.steps)
    wf, _ = limit_acceleration(s, synthesize_steps(s, s.steps, a))
    # the single tones as they play, as the planner gives them to the designer
    forb = played_tones(s.steps, a.frequencies, wf)
    idle = idle_ensembles(s.steps, a.frequencies)
    driven = driven_ensembles(s.steps, a.frequencies)
    for n in map(Node.parse, args.impacters.split(",")):
        out = []
        for seed in range(args.seeds):
            kw = {**s.design_kwargs(n), "seed": seed}
            t = time.perf_counter()
            d = design_impacter(
                frequency=a.frequencies[n], forbidden=forb[n],
                forbidden_drives=[] if args.without_drives else
                [Ensemble(drive_of(wf[k]), k) for k in idle[n]],
                target_drives=[] if args.without_drives else
                [Ensemble(drive_of(wf[k]), k) for k in driven[n]], **kw)
            out.append(f"{'' if d.feasible else 'X'}{d.predicted_slider_speed_m_s * 1e3:.3f}"
                       f"/{d.mass_ratio:.2f}/{time.perf_counter() - t:.1f}s")
        print(n, f"{a.frequencies[n]:g}", " ".join(out), flush=True)


if __name__ == "__main__":
    main()

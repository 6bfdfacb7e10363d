"""Summarise plan.json files of the default plan for docs/array_default.md.

Usage: python docs/array_default_table.py OUT_DIR [OUT_DIR ...]
(each OUT_DIR written by ``vibroplan plan --seed N --out OUT_DIR``).
"""

import json
import sys
from pathlib import Path


def summary(path):
    d = json.loads((Path(path) / "plan.json").read_text())
    ver = d["verification"]
    rows = [r for s in ver["steps"].values() for r in s.values()]
    out = {"seed": d["seed"], "passed": ver["passed"],
           "checks": f"{sum(r['passed'] for r in rows)}/{len(rows)}",
           "mass_ratio": (min(i["mass_ratio"] for i in d["impacters"]),
                          max(i["mass_ratio"] for i in d["impacters"])),
           "infeasible": [p["impacter"] for p in ver.get("design_problems", [])],
           "steps": {}}
    single = []
    for st in d["steps"]:
        movers = set(st["forward"]) | set(st["backward"])
        travel = {k: abs(v) for k, v in st["travel_m"].items() if k in movers}
        speeds = [v / st["duration_s"] for v in travel.values()]
        idle = [abs(v) for k, v in st["travel_m"].items() if k not in movers]
        rec = {"burst_ms": st["duration_s"] * 1e3, "dwell_ms": st["settle_s"] * 1e3,
               "peak_um": st["peak_displacement_m"] * 1e6, "peak_g": st["peak_acceleration_g"],
               "travel_um": (min(travel.values()) * 1e6, max(travel.values()) * 1e6),
               "speed_mm_s": (min(speeds) * 1e3, max(speeds) * 1e3),
               "idle_um": max(idle, default=0.0) * 1e6}
        if st["scene"] == "independent":
            single.append(rec)
        else:
            out["steps"][f"{st['scene']}/{st['name']}"] = rec
    if single:
        out["steps"]["independent (50 steps)"] = {
            "burst_ms": max(r["burst_ms"] for r in single),
            "dwell_ms": max(r["dwell_ms"] for r in single),
            "peak_um": max(r["peak_um"] for r in single),
            "peak_g": max(r["peak_g"] for r in single),
            "travel_um": (min(r["travel_um"][0] for r in single),
                          max(r["travel_um"][1] for r in single)),
            "speed_mm_s": (min(r["speed_mm_s"][0] for r in single),
                           max(r["speed_mm_s"][1] for r in single)),
            "idle_um": max(r["idle_um"] for r in single)}
    return out


def main(paths):
    print("| seed | passed | checks | m/M | step | burst [ms] | dwell [ms] | peak drive [um] | "
          "peak acceleration [g] | mover speed [mm/s] | mover travel [um] | largest idle "
          "travel [um] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for p in paths:
        s = summary(p)
        for k, r in s["steps"].items():
            print(f"| {s['seed']} | {'yes' if s['passed'] else 'no'} | {s['checks']} | "
                  f"{s['mass_ratio'][0]:.2f}-{s['mass_ratio'][1]:.2f} | {k} | "
                  f"{r['burst_ms']:.3g} | {r['dwell_ms']:.3g} | {r['peak_um']:.2f} | "
                  f"{r['peak_g']:.0f} | {r['speed_mm_s'][0]:.2f}-{r['speed_mm_s'][1]:.2f} | "
                  f"{r['travel_um'][0]:.3g}-{r['travel_um'][1]:.3g} | {r['idle_um']:.3g} |")
        if s["infeasible"]:
            print(f"| {s['seed']} | | | | infeasible designs: {', '.join(s['infeasible'])} |"
                  " | | | | | | |")


if __name__ == "__main__":
    main(sys.argv[1:])

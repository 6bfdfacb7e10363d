"""Yield of a plan under fabrication variation: the Monte Carlo behind ``vibroplan yield``.

Every chip is a sample of the spec's ``fabrication:`` tolerance model
(:mod:`planner.fabrication`) built from the plan's designs.  On each chip every step
of the plan is re-verified with the plan's own checks
(:func:`planner.pipeline.verify_step`, from the same initial-state grid, with the drive
rebuilt exactly from ``plan.json``'s tones) and every scene is simulated with the state
carried across steps (:func:`planner.pipeline.simulate_scenes`).  A chip passes when
every step passes the plan's own checks -- the criterion ``vibroplan plan`` calls
PASSED; the yield is the fraction of chips that pass, with a 95 % Wilson score
interval.  The carried-state check is counted in ``failures`` and gives a second,
stricter yield (``carried_state``: chips passing both), but is not part of the pass,
as in ``vibroplan plan`` (which reports it without failing): the default 5 x 5 plan's
nominal chip fails it.

Check kinds counted in ``failures`` (chips on which that check failed at least once):

- ``idle responds``: an impacter that must be idle hits its slider (r > 0, eq. (14));
- ``too slow``: a driven slider is slower than ``verification.min_speed_mm_s`` from
  some initial state;
- ``idle slider moves``: an idle slider moves more than ``verification.idle_tolerance_um``;
- ``idle slider moves (carried state)``: the same when each scene runs in order with
  the state the previous step left;
- ``unbuildable``: the sampled errors closed a gap or removed a beam (no simulation).

Chip ``i`` at sigma scale index ``j`` draws from
``numpy.random.SeedSequence([seed, j, i])``: the numbers depend on the seed only,
never on the number of workers or the order they finish in.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from planner.fabrication import ChipDesign, design_from_plan, sample_chip
from planner.spec import ArraySpec, FabricationSpec, LoadedSpec, Step

#: z of the two-sided 95 % normal quantile.
Z95 = 1.959963984540054
#: Check kinds, in the order reports list them.
KINDS = ("idle responds", "too slow", "idle slider moves",
         "idle slider moves (carried state)", "unbuildable")
#: The carried-state check: counted and reported, but, as in ``vibroplan plan``, not
#: part of a chip's pass (see the module docstring).
CARRIED = "idle slider moves (carried state)"
#: Scale index of the nominal chip's task (its draws are multiplied by 0).
NOMINAL_INDEX = 2**31 - 1


def wilson_interval(passed: int, n: int, z: float = Z95) -> list[float]:
    """Wilson score interval [low, high] of a binomial proportion ``passed / n``.

    >>> [round(x, 4) for x in wilson_interval(10, 10)]
    [0.7225, 1.0]
    """
    if n <= 0:
        return [0.0, 1.0]
    p = passed / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    # exact ends at 0 and n passes (the formula leaves round-off there)
    return [0.0 if passed == 0 else max(0.0, centre - half),
            1.0 if passed == n else min(1.0, centre + half)]


@dataclass(frozen=True)
class _Tones:
    """A step's drive as recorded in plan.json (what verify_step reads of a Waveform)."""

    frequencies: np.ndarray
    amplitudes: np.ndarray
    phases: np.ndarray


@dataclass(frozen=True)
class Payload:
    """Everything a worker needs to verify chips; sent to each worker once."""

    design: ChipDesign
    loaded: LoadedSpec
    waveforms: dict
    fabrication: FabricationSpec
    seed: int
    #: Numba threads per chip (None: numba's default); :func:`run_yield` sets 1.
    threads: int | None = None


def read_plan(path: str | Path) -> tuple[dict, Path]:
    """``plan.json`` of a plan folder (or the file itself): (its dict, its path).

    Raises
    ------
    FileNotFoundError
        No plan.json there.
    ValueError
        Not a JSON object with the plan's keys.
    """
    p = Path(path)
    if p.is_dir():
        p = p / "plan.json"
    if not p.is_file():
        raise FileNotFoundError(2, "no such file", str(p))
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except ValueError as exc:
        raise ValueError(f"{p}: not a plan.json ({exc})") from None
    missing = {"spec", "impacters", "steps"} - set(data if isinstance(data, dict) else ())
    if missing:
        raise ValueError(f"{p}: not a plan.json (missing {', '.join(sorted(missing))})")
    return data, p


def make_payload(data: dict, seed: int, fabrication: FabricationSpec | None = None) -> Payload:
    """The worker payload of a parsed plan.json; ``fabrication`` overrides the plan's."""
    spec = ArraySpec.model_validate(data["spec"])
    steps = tuple(Step(s["scene"], s["name"], int(s["index"]), float(s["duration_s"]),
                       tuple(s["forward"]), tuple(s["backward"])) for s in data["steps"])
    waveforms = {}
    for s, st in zip(data["steps"], steps):
        t = s["tones"]
        waveforms[st.key] = _Tones(np.array([x["frequency_hz"] for x in t], float),
                                   np.array([x["amplitude_m"] for x in t], float),
                                   np.array([x["phase_rad"] for x in t], float))
    loaded = LoadedSpec(spec, steps, "plan.json")
    fab = fabrication if fabrication is not None else spec.fabrication
    return Payload(design_from_plan(data, spec), loaded, waveforms, fab, int(seed))


def _kind(cause: str) -> str:
    if "responds" in cause:
        return "idle responds"
    if cause.startswith("too slow"):
        return "too slow"
    if cause.startswith("idle slider moves"):
        return "idle slider moves"
    return cause.split(":")[0].strip() or "other"


def verify_chip(payload: Payload, scale_index: int, chip_index: int, scale: float) -> dict:
    """Sample chip ``chip_index`` at sigma scale ``scale`` and run every check on it.

    Returns
    -------
    dict
        ``passed``, ``failures`` (kind -> failing rows), ``nodes`` (ids of the impacter
        pairs implicated in a failure), ``scale_index``, ``chip``.
    """
    from planner.assign import split_node
    from planner.pipeline import simulate_scenes, verify_step

    if payload.threads:
        import numba

        # per thread: every task sets it in the worker thread that runs it
        numba.set_num_threads(min(payload.threads, numba.config.NUMBA_NUM_THREADS))
    rng = np.random.default_rng(np.random.SeedSequence([payload.seed, scale_index,
                                                        chip_index]))
    chip = sample_chip(payload.design, payload.fabrication, rng, scale)
    failures, nodes = {}, set()
    if chip.unbuildable:
        failures["unbuildable"] = len(chip.unbuildable)
        for x in chip.unbuildable:
            nodes |= {n for n in payload.design.node_ids if n == x or split_node(n)[0] == x}
        return {"scale_index": scale_index, "chip": chip_index, "passed": False,
                "failures": failures, "nodes": sorted(nodes)}
    loaded = payload.loaded
    by_device = {}
    for n in chip.impacters:
        by_device.setdefault(split_node(n)[0], []).append(n)
    for st in loaded.steps:
        active = {f"{d}.{r}" for d, r in st.active_nodes()}
        for row in verify_step(loaded, st, payload.waveforms[st.key], chip.impacters,
                               chip.sliders):
            if row["passed"]:
                continue
            for cause in row["cause"].split("; "):
                kind = _kind(cause)
                failures[kind] = failures.get(kind, 0) + 1
                own = by_device.get(row["device"], [])
                named = [n for n in own if cause.startswith(n + " ")]
                if kind == "too slow":
                    named = [n for n in own if n in active]
                elif not named:  # an idle slider moved: its idle impacters did it
                    named = [n for n in own if n not in active]
                nodes |= set(named)
    passed = not failures
    carried = 0
    if loaded.spec.scenes:
        for r in simulate_scenes(loaded, loaded.steps, payload.waveforms, chip.impacters,
                                 chip.sliders):
            if r["driven"] and r["idle_moved_m"]:
                carried += len(r["idle_moved_m"])
    if carried:
        failures[CARRIED] = carried
    return {"scale_index": scale_index, "chip": chip_index, "passed": passed,
            "carried_passed": passed and not carried, "failures": failures,
            "nodes": sorted(nodes)}


def _summary(results, chips):
    passed = sum(r["passed"] for r in results)
    kinds = {}
    for r in results:
        for k in r["failures"]:
            kinds[k] = kinds.get(k, 0) + 1
    order = {k: i for i, k in enumerate(KINDS)}
    failures = dict(sorted(kinds.items(), key=lambda kv: (-kv[1], order.get(kv[0], 99))))
    both = sum(r.get("carried_passed", r["passed"]) for r in results)
    return {"chips": chips, "passed": passed, "yield": passed / chips,
            "ci95": wilson_interval(passed, chips), "failures": failures,
            "carried_state": {"passed": both, "yield": both / chips,
                              "ci95": wilson_interval(both, chips)}}


def parse_scales(text: str | None) -> list[float]:
    """``"0.5,1,2"`` -> [0.5, 1.0, 2.0]; None -> [1.0].

    Raises
    ------
    ValueError
        An entry is not a finite number >= 0, or an entry repeats.
    """
    if text is None or str(text).strip() == "":
        return [1.0]
    out = []
    for part in str(text).split(","):
        try:
            x = float(part)
        except ValueError:
            raise ValueError(f"--sigma-scale: {part.strip()!r} is not a number") from None
        if not (math.isfinite(x) and x >= 0):
            raise ValueError(f"--sigma-scale: {part.strip()} must be a finite number >= 0")
        if x in out:
            raise ValueError(f"--sigma-scale: {part.strip()} is given twice")
        out.append(x)
    return out


def run_yield(payload: Payload, chips: int, *, scales=(1.0,), jobs: int = 1,
              scheduler: str | None = None, progress=None) -> dict:
    """The Monte Carlo: ``chips`` chips at every sigma scale, plus the nominal chip.

    Returns
    -------
    dict
        The content of ``yield.json`` (see :func:`write_outputs` and docs/yield.md).
    """
    from planner.engine import run_tasks

    chips = int(chips)
    if chips < 1:
        raise ValueError(f"chips must be >= 1, {chips} was given")
    scales = [float(s) for s in scales]
    # the nominal chip (scale 0: every error 0) is task 0; it must reproduce the plan
    tasks = [(NOMINAL_INDEX, 0, 0.0)] + [(j, i, s) for j, s in enumerate(scales) for i in range(chips)]
    # one numba thread per chip everywhere: the chips are the parallelism, and the
    # kernels' own threads over a 5-9 point x0 grid cost more than they bring (on a
    # loaded 2-core machine a chip of the 5x5 plan took ~50 s threaded, ~5 s not)
    import numba

    before = numba.get_num_threads()
    payload = dataclasses.replace(payload, threads=1)
    try:
        results = run_tasks(verify_chip, payload, tasks, jobs=jobs, scheduler=scheduler,
                            progress=progress)
    finally:
        numba.set_num_threads(before)
    nominal, results = results[0], results[1:]
    main = scales.index(1.0) if 1.0 in scales else 0
    out_scale = {}
    for j, s in enumerate(scales):
        mine = [r for r in results if r["scale_index"] == j]
        out_scale[j] = (_summary(mine, chips), mine)
    summary, mine = out_scale[main]
    ids = payload.design.node_ids
    counts = dict.fromkeys(ids, 0)
    for r in mine:
        for n in r["nodes"]:
            counts[n] += 1
    data = {
        "chips": chips, "passed": summary["passed"], "yield": summary["yield"],
        "ci95": summary["ci95"], "ci95_method": "wilson", "seed": payload.seed,
        "sigma_scale": scales[main],
        "tolerance": json.loads(payload.fabrication.model_dump_json()),
        "failures": summary["failures"],
        "impacters": {n: counts[n] / chips for n in ids},
        "carried_state": summary["carried_state"],
        "nominal": {"passed": nominal["passed"], "failures": nominal["failures"],
                    "carried_passed": nominal["carried_passed"]},
        "failed_chips": [r["chip"] for r in mine if not r["passed"]],
    }
    if len(scales) > 1 or scales != [1.0]:
        data["by_sigma_scale"] = {
            f"{s:g}": {k: out_scale[j][0][k]
                       for k in ("yield", "ci95", "passed", "failures", "carried_state")}
            for j, s in enumerate(scales)}
    return data


# ----------------------------------------------------------------------------------
# outputs


def _grid(spec: ArraySpec, rates: dict, direction: str):
    rows, cols = spec.array.rows, spec.array.cols
    grid = np.full((rows, cols), np.nan)
    for n, rate in rates.items():
        dev, d = n.split(".")
        if d == direction:
            grid[ord(dev[0]) - ord("A"), int(dev[1:]) - 1] = rate
    return grid


def _figures(data: dict, spec: ArraySpec, folder: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)
    names = []
    # yield with its CI, against the sigma scale when there are several
    by = data.get("by_sigma_scale") or {f"{data['sigma_scale']:g}":
                                        {"yield": data["yield"], "ci95": data["ci95"]}}
    xs = [float(k) for k in by]
    ys = [v["yield"] for v in by.values()]
    lo = [v["yield"] - v["ci95"][0] for v in by.values()]
    hi = [v["ci95"][1] - v["yield"] for v in by.values()]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.errorbar(xs, ys, yerr=[lo, hi], fmt="o-", capsize=4)
    ax.set_xlabel("sigma scale [-]")
    ax.set_ylabel("yield (95 % Wilson CI)")
    ax.set_ylim(-0.03, 1.03)
    ax.set_title(f"{data['chips']} chips per point, seed {data['seed']}")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(folder / "yield.png", dpi=110)
    plt.close(fig)
    names.append("yield.png")
    # the checks that fail most
    if data["failures"]:
        kinds = list(data["failures"])
        fig, ax = plt.subplots(figsize=(5.5, 0.5 + 0.45 * len(kinds)))
        ax.barh(kinds[::-1], [data["failures"][k] / data["chips"] for k in kinds[::-1]])
        ax.set_xlabel("fraction of chips failing the check")
        ax.set_xlim(0, 1)
        fig.tight_layout()
        fig.savefig(folder / "failures.png", dpi=110)
        plt.close(fig)
        names.append("failures.png")
    # each impacter's failure rate over the array grid
    fig, axes = plt.subplots(1, 2, figsize=(2 + 1.4 * spec.array.cols, 0.8 + 0.9 * spec.array.rows),
                             squeeze=False)
    for ax, direction in zip(axes[0], ("forward", "backward")):
        g = _grid(spec, data["impacters"], direction)
        im = ax.imshow(g, vmin=0, vmax=1, cmap="Reds")
        ax.set_title(direction)
        ax.set_xticks(range(spec.array.cols), [str(c + 1) for c in range(spec.array.cols)])
        ax.set_yticks(range(spec.array.rows), [chr(ord("A") + r) for r in range(spec.array.rows)])
        for (r, c), v in np.ndenumerate(g):
            ax.text(c, r, "-" if np.isnan(v) else f"{v:.2f}", ha="center", va="center",
                    fontsize=8)
    fig.colorbar(im, ax=axes[0].tolist(), label="failure rate")
    fig.savefig(folder / "impacters.png", dpi=110)
    plt.close(fig)
    names.append("impacters.png")
    return names


def _report(data: dict, spec: ArraySpec, plan_path: str, figures: list[str]) -> str:
    lo, hi = data["ci95"]
    lines = [f"# Yield of {spec.name}", "",
             f"Plan: `{plan_path}`; {data['chips']} chips, seed {data['seed']}, "
             f"sigma scale {data['sigma_scale']:g}.", "",
             f"**Yield {data['yield']:.3f}** ({data['passed']} of {data['chips']} chips pass "
             f"every check); 95 % Wilson interval [{lo:.3f}, {hi:.3f}].", "",
             f"With the carried-state check too (each scene in order, the state carried "
             f"across steps): yield {data['carried_state']['yield']:.3f}, 95 % CI "
             f"[{data['carried_state']['ci95'][0]:.3f}, {data['carried_state']['ci95'][1]:.3f}]"
             + ("" if data["nominal"]["carried_passed"] else
                " (the nominal chip already fails it)") + ".", "",
             "The nominal chip (no fabrication error) "
             + ("passes every check." if data["nominal"]["passed"] else
                "FAILS: " + ", ".join(f"{k} ({v})" for k, v in data["nominal"]["failures"].items())
                + "; the plan itself does not verify."), "",
             "## Tolerance model", "",
             "| error | per die (sigma) | per device (sigma) |", "|---|---|---|"]
    for k, v in data["tolerance"].items():
        lines.append(f"| {k} | {v['die']:g} | {v['device']:g} |")
    lines += ["", "![yield](figures/yield.png)", ""]
    if "by_sigma_scale" in data:
        lines += ["## Yield against the tolerance scale", "",
                  "| sigma scale | yield | 95 % CI | chips passed |", "|---|---|---|---|"]
        for s, v in data["by_sigma_scale"].items():
            lines.append(f"| {s} | {v['yield']:.3f} | [{v['ci95'][0]:.3f}, {v['ci95'][1]:.3f}] "
                         f"| {v['passed']} / {data['chips']} |")
        lines.append("")
    lines += ["## Checks that fail", ""]
    if data["failures"]:
        lines += ["| check | chips failing it | fraction |", "|---|---|---|"]
        for k, v in data["failures"].items():
            lines.append(f"| {k} | {v} | {v / data['chips']:.3f} |")
        lines += ["", "![failures](figures/failures.png)", ""]
    else:
        lines += ["None: every chip passes every check.", ""]
    worst = sorted(data["impacters"].items(), key=lambda kv: -kv[1])[:10]
    lines += ["## Impacters", "",
              "Failure rate: the fraction of chips on which the impacter pair was implicated "
              "in a failed check (it responded while idle, its slider was too slow, or its "
              "idle slider moved).", "", "![impacters](figures/impacters.png)", "",
              "| impacter | failure rate |", "|---|---|"]
    lines += [f"| {n} | {r:.3f} |" for n, r in worst]
    lines.append("")
    return "\n".join(lines)


def write_outputs(data: dict, spec: ArraySpec, folder: Path, plan_path: str,
                  figures: bool = True) -> None:
    """``yield.json``, ``report.md`` and ``figures/`` into ``folder`` (a temporary one
    from :func:`planner._io.output_folder`)."""
    folder = Path(folder)
    (folder / "yield.json").write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    names = _figures(data, spec, folder / "figures") if figures else []
    (folder / "report.md").write_text(_report(data, spec, plan_path, names), encoding="utf-8")

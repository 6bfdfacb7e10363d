"""Benchmark of the bandwidth-colouring strategies (planner.coloring).

Runs every strategy on

- the public GEOM instances found in the GEOM directory (GEOM20, GEOM20a,
  GEOM20b: proven optima 21, 20, 13);
- the 5 x 5 array's conflict graph (50 impacters, complete graph, optimum 98 by
  the argument in tests/planner/test_coloring.py::test_array_5x5_proven_optimal);
- GEOM-style instances *generated here* (random points in a 10000 x 10000
  square as in Trick's generator, an edge when the squared distance is below the
  GEOM20 files' thresholds, 5e6 for plain and 1e7 for the a/b variants; random
  separations 1..9, and for "b" separations that grow as points get closer).
  They stand in for the larger public instances (GEOM30 ... GEOM120), which are
  not available here; they are NOT those instances and have no known optima.

and writes benchmarks/results/coloring.csv and coloring.md.

    python benchmarks/coloring.py [--geom-dir DIR] [--time-limit S] [--no-generated]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path

import networkx as nx
import numpy as np
import pandas as pd

from planner.coloring import read_band, solve_bandwidth, verify_coloring

HERE = Path(__file__).resolve().parent
DEFAULT_GEOM_DIR = Path(__file__).resolve().parents[1] / "tests" / "data" / "geom"
RESULTS = HERE / "results"

#: Proven optimal spans of the public instances (GEOM README; Trick's
#: COLOR02/03/04 bandwidth results).
KNOWN_OPTIMA = {"GEOM20": 21, "GEOM20a": 20, "GEOM20b": 13}

METHODS = ("dsatur", "milp", "auto")

#: Generated instance sizes and variants.
GENERATED_SIZES = (30, 60, 90, 120)
GENERATED_VARIANTS = ("", "a", "b")

#: Squared-distance thresholds of the GEOM20 / GEOM20a,b headers [grid units^2].
THRESHOLD_SQ = {"": 5e6, "a": 1e7, "b": 1e7}


def geom_style_instance(n: int, variant: str, seed: int) -> nx.Graph:
    """A generated GEOM-style bandwidth instance (not a public GEOM file).

    Parameters
    ----------
    n : int
        Number of vertices.
    variant : {"", "a", "b"}
        "" sparse (threshold 5e6), "a" denser (1e7), both with separations
        uniform in 1..9; "b" as dense, separation ceil(9 (1 - d / r)) +- 1
        clipped to 1..9 (closer points need more channels).
    seed : int
        Seed of the points and separations.

    Returns
    -------
    networkx.Graph
        Nodes 1..n, edge attribute "sep" [channels].
    """
    rng = np.random.default_rng(seed)
    pts = rng.uniform(0, 10000, (n, 2))
    r2 = THRESHOLD_SQ[variant]
    g = nx.Graph()
    g.add_nodes_from(range(1, n + 1))
    for i in range(n):
        for j in range(i + 1, n):
            d2 = float(((pts[i] - pts[j]) ** 2).sum())
            if d2 >= r2:
                continue
            if variant == "b":
                s = math.ceil(9 * (1 - math.sqrt(d2 / r2))) + int(rng.integers(-1, 2))
                s = int(min(9, max(1, s)))
            else:
                s = int(rng.integers(1, 10))
            g.add_edge(i + 1, j + 1, sep=s)
    return g


def array_graph(rows: int = 5, cols: int = 5) -> nx.Graph:
    """The array's conflict graph as in the tests (see there for the model)."""
    g = nx.Graph()
    imps = [((r, c, d), 1 + (r + 2 * c + k) % 3)
            for r in range(rows) for c in range(cols) for k, d in enumerate(("fwd", "bwd"))]
    for i, (u, wu) in enumerate(imps):
        for v, wv in imps[i + 1:]:
            g.add_edge(u, v, sep=math.ceil((wu + wv) / 2) + (u[:2] == v[:2]))
    return g


def instances(geom_dir: Path, generated: bool):
    """Yield (name, source, graph, known optimum or None)."""
    if geom_dir.is_dir():
        for path in sorted(geom_dir.glob("*.col")):
            yield path.stem, "public", read_band(path), KNOWN_OPTIMA.get(path.stem)
    else:
        print(f"warning: no GEOM directory at {geom_dir}", file=sys.stderr)
    yield "array5x5", "model", array_graph(), 98
    if generated:
        for n in GENERATED_SIZES:
            for variant in GENERATED_VARIANTS:
                seed = 1000 * n + ord(variant or "x")
                yield (f"gen-GEOM{n}{variant}", "generated",
                       geom_style_instance(n, variant, seed), None)


def run(geom_dir: Path, time_limit, generated: bool) -> pd.DataFrame:
    # load (or compile) the numba kernels before timing anything
    solve_bandwidth(nx.cycle_graph(5), method="dsatur", time_limit=1)
    rows = []
    for name, source, graph, optimum in instances(geom_dir, generated):
        edges = sum(1 for u, v in graph.edges if u != v)
        for method in METHODS:
            t0 = time.perf_counter()
            r = solve_bandwidth(graph, method=method, time_limit=time_limit)
            wall = time.perf_counter() - t0
            if verify_coloring(graph, r.coloring):
                raise RuntimeError(f"{name} {method}: invalid colouring")
            if optimum is not None and r.lower_bound > optimum:
                raise RuntimeError(f"{name} {method}: lower bound above the known optimum")
            rows.append({
                "instance": name,
                "source": source,
                "vertices": graph.number_of_nodes(),
                "edges": edges,
                "method": method,
                "used": r.method,
                "span": r.span,
                "known_optimum": optimum,
                "gap": None if optimum is None else r.span - optimum,
                "lower_bound": r.lower_bound,
                "proven_optimal": r.optimal,
                "seconds": round(wall, 3),
                "message": r.message,
            })
            print(f"{name:16s} {method:6s} span {r.span:3d} lb {r.lower_bound:3d} "
                  f"opt {str(r.optimal):5s} {wall:7.2f} s  {r.message}", flush=True)
    return pd.DataFrame(rows)


def markdown(df: pd.DataFrame, time_limit) -> str:
    cpu = os.cpu_count()
    lines = [
        "# Bandwidth colouring benchmark",
        "",
        f"`python benchmarks/coloring.py` on {platform.machine()} with {cpu} CPUs, "
        f"Python {platform.python_version()}; time limit: "
        f"{'method defaults (10 s exact, 5 s heuristic)' if time_limit is None else f'{time_limit} s'}. "
        "Times are wall-clock seconds per solve, numba kernels already loaded.",
        "",
        "- span: largest colour + 1; lower bound: proven; opt: span proven optimal.",
        "- known optimum: public GEOM instances (literature) and the 5x5 array "
        "(derived in the tests); `gen-` instances are **generated here** in the GEOM "
        "style and are not the public GEOM30..GEOM120 files (no known optimum).",
        "- `auto` runs the MILP up to 80 vertices and the heuristic above (column `used`).",
        "",
        "| instance | source | V | E | method | used | span | known opt | gap | lower bound "
        "| opt | time [s] |",
        "|---|---|---:|---:|---|---|---:|---:|---:|---:|:---:|---:|",
    ]
    for row in df.itertuples():
        opt = "—" if pd.isna(row.known_optimum) else int(row.known_optimum)
        gap = "—" if pd.isna(row.gap) else int(row.gap)
        lines.append(
            f"| {row.instance} | {row.source} | {row.vertices} | {row.edges} | {row.method} "
            f"| {row.used} | {row.span} | {opt} | {gap} | {row.lower_bound} "
            f"| {'yes' if row.proven_optimal else 'no'} | {row.seconds:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--geom-dir", type=Path, default=DEFAULT_GEOM_DIR,
                        help=f"directory of GEOM *.col files (default {DEFAULT_GEOM_DIR})")
    parser.add_argument("--time-limit", type=float, default=None,
                        help="time limit per solve [s] (default: each method's own)")
    parser.add_argument("--no-generated", action="store_true",
                        help="skip the generated GEOM-style instances")
    parser.add_argument("--out-dir", type=Path, default=RESULTS,
                        help="where to write coloring.csv and coloring.md")
    args = parser.parse_args(argv)
    df = run(args.geom_dir, args.time_limit, not args.no_generated)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out_dir / "coloring.csv", index=False)
    (args.out_dir / "coloring.md").write_text(markdown(df, args.time_limit))
    print(f"wrote {args.out_dir / 'coloring.csv'} and {args.out_dir / 'coloring.md'}")


if __name__ == "__main__":
    main()

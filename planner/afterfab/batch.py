"""A wafer in batch: every measured die re-planned (and trimmed where needed) on Dask,
each die's outputs kept as it finishes, a summary and a wafer map at the end
(``vibroplan replan PLAN --measured WAFER.csv``, issue 39).

Per die (:func:`replan_die`, a task of :func:`planner.runtime.engine.run_tasks`), the
after-fabrication loop a yield study runs on its chips
(:func:`planner.afterfab.loop.run_loop`), from the die's measurement only, with no
truth: the chip's as-built models from the measurement, the plan's own drive checked on
them (stopping at its first failing step; if it passes, the die works **as designed**);
else the drive re-planned for the die (as ``vibroplan replan``; if it verifies, the die
works **after re-plan**); else, with ``trim``, a die whose pairs cannot be told apart is
trimmed (:func:`planner.afterfab.trim.trim_chip`, as ``vibroplan trim``; if its re-plan
verifies on the trimmed models and the cuts' odds reach the target yield, it works
**after trim**); else the die is **scrapped**, with the causes
(:mod:`planner.afterfab.outcome`: the words of a yield study's, in one list).

A die whose file leaves an impacter out (a row missing, a tester's test skipped) has
that impacter taken at its design, as ``vibroplan replan`` takes it: the loop runs the
same, but what it finds holds only if the unmeasured impacters are as designed, so a
die that would work is counted **partly measured** (:data:`PARTLY_MEASURED`), its
causes naming the impacters and what the loop found (``works after re-plan if
A2.backward is at its design``), never *as designed*; a scrapped one stays scrapped, the
unmeasured impacters among its causes.

The re-plan is exactly the one a yield study makes of the same measurement (the same
loop, settings, phases and as-built models), so a wafer sampled by ``vibroplan yield``
and re-planned here gets the study's re-planned drive die by die; what this batch cannot
know is the chip's truth, which the study verifies the drive on.

**Resuming.**  Each die's result and files are written, as the die finishes, into a
work folder beside the output (``.OUT.dies/``, one ``die_<x>_<y>/`` per die, renamed
into place whole); an interrupted run leaves it, and the next run reads a finished die
back instead of redoing it only when that die's own key matches: the SHA-256 of the
plan.json's bytes, the options, the die's place, its measurement as read and, for a
folder of measured.csv files, its own file's bytes (:func:`die_key`).  A die whose file
was renamed, edited or swapped with another's is redone; a batch-wide key alone would
let a renamed file's die pass for another.  The work folder carries a marker
(:data:`WORK_MARKER`) from the moment it exists: a folder of that name without it (a
user's, or the ``--measured-dir`` itself) is refused, never emptied
(:func:`check_work_folder`).  The output folder itself is written at the end and
swapped in atomically (:func:`planner.files.output_folder`), and the work folder removed.
Every output depends on the inputs only: ``--jobs 1`` and ``--jobs 2`` (or a cluster)
write the same bytes.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

from planner.afterfab.loop import LoopJob, run_loop
from planner.afterfab.outcome import FLOOR_OUTCOMES, NOT_MEASURED, PARTLY_MEASURED
from planner.afterfab.wafer_file import die_name

#: A die's outcomes, best first (:data:`planner.afterfab.outcome.OUTCOMES` in the lab's
#: words: a yield study's ``fails`` is ``scrapped`` here, a die nothing rescued).
OUTCOMES = FLOOR_OUTCOMES
#: The summary's columns.
SUMMARY_COLUMNS = ("die_x", "die_y", "outcome", "causes", "trimmed", "checks_passed",
                   "checks", "folder", "repairs")
#: Version of the work folder's contents: a resume reads back only its own kind (3: a
#: die not measured whole is "partly measured"; each die keyed on its own input, issue 44).
WORK_FORMAT = 3
#: The file of a die's work folder written last: its presence says the die finished.
RESULT_FILE = "result.json"
#: The marker of a work folder vibroplan made (its format and the batch's key): a folder
#: at the work folder's place without it is not vibroplan's, and is refused.
WORK_MARKER = ".vibroplan-work"
#: In a finished die's work folder, the die's own key (:func:`die_key`); taken out
#: before the folder moves into the output.
KEY_FILE = ".die-key"


def make_job(record, *, trim: bool = False) -> LoopJob:
    """The loop's job for every die of a plan (:func:`planner.planfile.reader.
    read_plan`): re-plan, trim with ``trim``, keep the outputs; the as-built models
    assume the spec's ``fabrication.measurement_noise_pct``."""
    from planner.afterfab.checks import drive_of
    from planner.planning.settings import plan_settings

    steps, waveforms, dwells = drive_of(record)
    return LoopJob(record, plan_settings(record), steps, waveforms, dwells,
                   nodes=tuple(r.node for r in record.impacters), trim=bool(trim),
                   measure_noise_pct=record.spec.fabrication.measurement_noise_pct,
                   outputs=True)


def _files_of(folder: Path) -> dict:
    """Relative path -> bytes of every file under ``folder``, sorted."""
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def replan_die(job: LoopJob, die_x: int, die_y: int, measured: dict) -> dict:
    """One die: the after-fabrication loop on its measurement
    (:func:`planner.afterfab.loop.run_loop`, no truth), its outcome, causes and output
    files (the module docstring).

    Returns
    -------
    dict
        ``die_x``, ``die_y``, ``outcome`` (:data:`OUTCOMES`, or
        :data:`PARTLY_MEASURED`), ``causes`` (list of str), ``trimmed`` (impacter ids
        trim.csv moves), ``checks_passed`` and ``checks`` (of the drive the die is to be
        played with, on its as-built models; of the plan's drive, stopped at its first
        failing step, when it works as designed), ``inseparable`` (the pairs no drive
        tells apart, with their messages), ``files`` (path relative to the die's folder
        -> bytes) and, for a die not measured whole, ``not_measured``.
    """
    import numba

    # one numba thread per die, as a yield study's chips: the dies are the parallelism
    numba.set_num_threads(1)
    return _die_record(run_loop(job, measured=measured), die_x, die_y)


def _die_record(got, die_x: int, die_y: int) -> dict:
    """A die's result (:func:`replan_die`) from what the loop found
    (:class:`~planner.afterfab.outcome.LoopResult`), its files written as the lab gets
    them: the drive to play at the folder's top (after re-plan), ``trim.csv`` and the
    trimmed chip's drive in ``trimmed/`` (a trim), and a scrapped die's re-plan in
    ``replan/`` saying what fails."""
    from planner.afterfab.outcome import OUTCOMES as REACHED
    from planner.afterfab.replan import write_replan_outputs
    from planner.afterfab.trim import write_trim_csv

    # result.json's keys in the order they have always been written
    out = {"die_x": int(die_x), "die_y": int(die_y), "trimmed": [], "inseparable": [],
           "causes": []}
    result, trimmed = got.replanned, got.trimmed
    if result is None:
        # the plan's drive works on the die (its checks counted), or no re-plan could
        # be made: nothing to write
        nominal = got.nominal
        works = got.replan is None
        out.update(outcome=got.outcome, causes=list(got.causes),
                   checks=nominal.checks if works else 0,
                   checks_passed=nominal.checks_passed if works else 0)
        return _with_missing(_with_files(out, None), got)
    with tempfile.TemporaryDirectory(prefix="vibroplan-die-") as tmp:
        folder = Path(tmp)
        ver = result.verification
        out.update(checks=len(ver), checks_passed=int(ver["passed"].sum()),
                   inseparable=[c.message for c in result.replan.inseparable])
        # the repairs of the drive the die is to be played with (the trimmed chip's
        # where a trim was re-planned): kind -> count
        repairs = dict(result.replan.repairs)
        if trimmed is not None:
            write_trim_csv(trimmed.rows, folder / "trim.csv")
            out["trimmed"] = list(trimmed.trims.moved)
            if trimmed.plan is not None:
                write_replan_outputs(trimmed.plan, folder / "trimmed", figures=False,
                                     timings=False)
                tv = trimmed.plan.verification
                out.update(checks=len(tv), checks_passed=int(tv["passed"].sum()))
                repairs = dict(trimmed.plan.replan.repairs)
        if repairs:
            out["repairs"] = repairs
        reached = got.reached
        if reached == REACHED[1]:
            write_replan_outputs(result, folder, figures=False, timings=False)
        elif reached == REACHED[3]:
            # the re-plan as it stands says what fails (plan.json, report.md)
            write_replan_outputs(result, folder / "replan", figures=False, timings=False)
        out.update(outcome=got.outcome, causes=list(got.causes))
        return _with_missing(_with_files(out, folder), got)


def _with_files(out: dict, folder: Path | None) -> dict:
    out["files"] = _files_of(folder) if folder is not None else {}
    return out


def _with_missing(out: dict, got) -> dict:
    if got.not_measured:
        out["not_measured"] = list(got.not_measured)
    return out


# --------------------------------------------------------------------------- the batch

def inputs_digest(plan_path, measured_paths, options: dict) -> str:
    """SHA-256 of what a batch's results depend on: the plan.json's bytes, every
    measurement file's bytes (in order) and the options; a resume reads back only a
    work folder of the same digest."""
    from planner.files.version import version_string

    h = hashlib.sha256()
    h.update(f"format {WORK_FORMAT}\n{version_string()}\n".encode())
    for p in [plan_path, *measured_paths]:
        h.update(hashlib.sha256(Path(p).read_bytes()).hexdigest().encode() + b"\n")
    h.update(json.dumps(options, sort_keys=True).encode())
    return h.hexdigest()


def die_key(batch: str, die_x: int, die_y: int, measured: dict, source=None) -> str:
    """SHA-256 of what one die's result depends on: ``batch`` (:func:`inputs_digest`
    of the plan and options), the die's place, its measurement as read (every
    impacter's resonances, Q, gaps, in the file's order) and, when the die has a file
    of its own (``--measured-dir``), that file's bytes."""
    h = hashlib.sha256()
    h.update(f"{batch}\n{int(die_x)} {int(die_y)}\n".encode())
    for name, m in measured.items():
        h.update(json.dumps([name, list(m.halves_hz), list(m.quality), list(m.gap_m),
                             m.damping_ns_per_m, m.window_hz]).encode() + b"\n")
    if source is not None:
        h.update(hashlib.sha256(Path(source).read_bytes()).hexdigest().encode())
    return h.hexdigest()


def work_folder(out_dir) -> Path:
    """Where a batch keeps its finished dies until its output is written:
    ``.NAME.dies`` beside the output folder ``NAME``."""
    out = Path(out_dir).absolute()
    return out.parent / f".{out.name}.dies"


def _work_marker(work: Path) -> dict | None:
    """The marker of a work folder vibroplan made, or None (a work folder of format 1,
    before the marker, is known by its ``inputs.json`` stamp)."""
    for name, ours in ((WORK_MARKER, lambda d: d.get("written_by") == "vibroplan"),
                       ("inputs.json", lambda d: d.get("format") == 1 and "digest" in d)):
        try:
            data = json.loads((work / name).read_text())
        except (OSError, ValueError):
            continue
        if isinstance(data, dict) and ours(data):
            return data
    return None


def check_work_folder(work, inputs=()) -> None:
    """Refuse, before any work, a work folder vibroplan may not use: one that holds an
    input or lies inside an input folder (``--measured-dir .OUT.dies``), or one that
    exists without vibroplan's marker (a user's folder: it would be emptied).

    Raises
    ------
    planner.core.errors.OutputError
        Naming the folder and what to do instead.
    """
    from planner.core.errors import OutputError

    work = Path(work).absolute()
    for inp in inputs:
        if inp is None:
            continue
        p = Path(inp).absolute().resolve()
        if p.is_relative_to(work.resolve()) or work.resolve().is_relative_to(p):
            raise OutputError(f"{work}: the batch keeps its finished dies in this folder, "
                              f"which is (or holds) the input {inp}; choose another --out")
    if work.is_symlink() or (work.exists() and not work.is_dir()):
        raise OutputError(f"{work}: the batch keeps its finished dies here, and it is not "
                          "a folder vibroplan made; move it away or choose another --out")
    if work.is_dir() and _work_marker(work) is None:
        raise OutputError(f"{work}: the batch keeps its finished dies here, and this folder "
                          f"was not written by vibroplan (no {WORK_MARKER}); it is not "
                          "removed: move it away or choose another --out")


def _open_work(work: Path, digest: str) -> dict:
    """The finished dies of the work folder (name -> (key, result without files)),
    made with its marker if it does not exist (a folder without the marker is refused,
    :func:`check_work_folder`).  The dies are kept whatever ``digest``: each is matched
    on its own key (:func:`die_key`)."""
    check_work_folder(work)
    if not work.exists():
        # made whole with its marker: a run killed here leaves no unmarked folder
        tmp = Path(tempfile.mkdtemp(prefix=f".{work.name}.", dir=work.parent))
        (tmp / WORK_MARKER).write_text(json.dumps(
            {"written_by": "vibroplan", "format": WORK_FORMAT, "digest": digest}) + "\n")
        os.rename(tmp, work)
        return {}
    done = {}
    for d in sorted(work.iterdir()):
        if not d.is_dir() or d.is_symlink() or not d.name.startswith("die_"):
            continue
        res, key = d / RESULT_FILE, d / KEY_FILE
        try:
            done[d.name] = (key.read_text().strip(), json.loads(res.read_text()))
        except (OSError, ValueError):   # a die of an older format, or cut short: redone
            continue
    return done


def _keep(work: Path, result: dict, key: str) -> dict:
    """Write a finished die into the work folder atomically (a hidden folder renamed
    into place whole, its key inside); returns its result without its files."""
    name = die_name(result["die_x"], result["die_y"])
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=work))
    files = result.pop("files")
    for rel, data in files.items():
        p = tmp / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
    (tmp / RESULT_FILE).write_text(json.dumps(result, indent=2) + "\n")
    (tmp / KEY_FILE).write_text(key + "\n")
    final = work / name
    if final.exists():
        shutil.rmtree(final)
    os.rename(tmp, final)
    return result


def replan_wafer(record, dies, out_tmp, *, plan_path, measured_paths, trim=False,
                 jobs=1, scheduler=None, progress=None, work=None, sources=None) -> list:
    """Re-plan every die of a wafer and write the batch's outputs into ``out_tmp``.

    Parameters
    ----------
    record : PlanRecord
        The plan the wafer was made by.
    dies : list of (int, int, dict)
        ``(die_x, die_y, measured)`` (:func:`planner.afterfab.wafer_file.read_wafer`).
    out_tmp : path
        The output folder being written (:func:`planner.files.output_folder`'s temporary).
    plan_path, measured_paths :
        The inputs (the plan's bytes key the work folder, :func:`inputs_digest`;
        ``measured_paths`` is kept for callers, each die is keyed on its own input).
    sources : dict, optional
        ``(die_x, die_y) -> path`` of a die's own file (``--measured-dir``), whose bytes
        enter the die's key (:func:`die_key`).
    trim : bool
        Trim the dies whose pairs no drive tells apart.
    jobs, scheduler :
        As :func:`planner.runtime.engine.run_tasks`.
    progress : callable, optional
        ``progress(done, total, resumed)`` after each die and once at the start.
    work : path
        The work folder (:func:`work_folder` of the output).

    Returns
    -------
    list of dict
        Every die's result (without files), in ``dies``' order.
    """
    from planner.runtime.engine import run_tasks

    work = Path(work)
    # the batch's key holds the plan and the options; each die adds its own input
    batch = inputs_digest(plan_path, [], {"trim": bool(trim), "seed": record.seed})
    sources = sources or {}
    names = [die_name(x, y) for x, y, _ in dies]
    keys = {n: die_key(batch, x, y, m, sources.get((x, y)))
            for (x, y, m), n in zip(dies, names)}
    kept = _open_work(work, batch)
    done = {n: r for n, (k, r) in kept.items() if keys.get(n) == k}
    todo = [(x, y, m) for (x, y, m), n in zip(dies, names) if n not in done]
    total, resumed = len(dies), len(dies) - len(todo)
    tick = progress or (lambda done, total, resumed: None)
    tick(resumed, total, resumed)
    count = {"n": resumed}

    def keep(_index, result):
        name = die_name(result["die_x"], result["die_y"])
        done[name] = _keep(work, result, keys[name])
        count["n"] += 1
        tick(count["n"], total, resumed)

    if todo:
        import numba

        before = numba.get_num_threads()
        try:
            run_tasks(replan_die, make_job(record, trim=trim), todo, jobs=jobs,
                      scheduler=scheduler, on_result=keep)
        finally:
            numba.set_num_threads(before)
    results = [done[n] for n in names]
    write_batch_outputs(record, results, work, Path(out_tmp))
    return results


def write_batch_outputs(record, results, work: Path, out: Path) -> None:
    """The batch's output folder: every die's folder (``dies/die_<x>_<y>/``),
    ``summary.csv`` (:data:`SUMMARY_COLUMNS`), ``report.md`` and ``wafer_map.png``.

    The dies' folders are moved, not copied, from the work folder, last: a wafer's
    drive files are ~2 MB and 420 files a die on the default plan, which a copy (and
    the work folder's removal after it) would write and delete again; a run stopped
    after the first move has only those dies to redo."""
    lines = [",".join(SUMMARY_COLUMNS)]
    for r in results:
        name = die_name(r["die_x"], r["die_y"])
        row = {**r, "causes": "; ".join(r["causes"]), "trimmed": " ".join(r["trimmed"]),
               "folder": f"dies/{name}",
               # kind=count of the die's re-plan repairs (a die kept by an older batch
               # has none recorded)
               "repairs": " ".join(f"{k}={v}" for k, v in r.get("repairs", {}).items())}
        lines.append(",".join(_csv_cell(row[c]) for c in SUMMARY_COLUMNS))
    (out / "summary.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    from planner.fabrication.wafer import die_size

    spec = record.spec
    wafer = spec.fabrication.wafer
    size = (die_size(spec.array, wafer) if wafer is not None
            else (spec.array.cols * spec.array.pitch_um * 1e-6,
                  spec.array.rows * spec.array.pitch_um * 1e-6))
    size_mm = (size[0] * 1e3, size[1] * 1e3)
    from planner.figures.wafer_map import plot_wafer_map

    plot_wafer_map([{"die_x": r["die_x"], "die_y": r["die_y"], "outcome": r["outcome"],
                     "causes": r["causes"]} for r in results], size_mm,
                   out / "wafer_map.png",
                   diameter_mm=wafer.diameter_mm if wafer is not None else None,
                   edge_exclusion_mm=wafer.edge_exclusion_mm if wafer is not None else None,
                   title=f"{spec.name}: {len(results)} dies re-planned")
    (out / "report.md").write_text(_report(record, results), encoding="utf-8")
    dies_dir = out / "dies"
    dies_dir.mkdir(parents=True, exist_ok=True)
    for r in results:
        name = die_name(r["die_x"], r["die_y"])
        with contextlib.suppress(FileNotFoundError):
            os.unlink(work / name / KEY_FILE)
        os.rename(work / name, dies_dir / name)


def remove_work(work) -> None:
    """Remove a batch's work folder once its output is written (only a folder that
    carries vibroplan's marker)."""
    work = Path(work)
    if work.is_dir() and not work.is_symlink() and _work_marker(work) is not None:
        shutil.rmtree(work, ignore_errors=True)


def _csv_cell(v) -> str:
    text = str(v)
    return f'"{text}"' if ("," in text or '"' in text) else text


def counts(results) -> dict:
    """Outcome -> dies, every outcome of :data:`OUTCOMES` listed in order, then
    :data:`PARTLY_MEASURED` when a die is."""
    outcomes = [r["outcome"] for r in results]
    out = {o: outcomes.count(o) for o in OUTCOMES}
    if PARTLY_MEASURED in outcomes:
        out[PARTLY_MEASURED] = outcomes.count(PARTLY_MEASURED)
    return out


def repair_counts(results) -> dict:
    """Repair kind -> repairs the dies' re-plans made (:data:`planner.afterfab.replan.
    REPAIR_KINDS`' order; only the kinds that fired)."""
    from planner.afterfab.replan import REPAIR_KINDS

    made = dict.fromkeys(REPAIR_KINDS, 0)
    for r in results:
        for k, v in r.get("repairs", {}).items():
            made[k] = made.get(k, 0) + int(v)
    return {k: v for k, v in made.items() if v}


def scrapped_causes(results) -> dict:
    """Cause -> scrapped dies it is given for, in the order first met."""
    causes = {}
    for r in results:
        if r["outcome"] == OUTCOMES[3]:
            for k in r["causes"]:
                causes[k] = causes.get(k, 0) + 1
    return causes


def _report(record, results) -> str:
    n = len(results)
    c = counts(results)
    causes = scrapped_causes(results)
    lines = [f"# vibroplan replan: a wafer of {record.spec.name}", "",
             f"{n} dies re-planned from their measurement, each by the loop a lab runs on a "
             "chip: the plan's drive checked on the die's as-built models (as designed); "
             "else its drive re-planned and verified on them (after re-plan); else, with "
             "--trim, a die whose impacters no drive tells apart trimmed and its drive "
             "re-planned and verified on the trimmed models (after trim); else scrapped.  "
             "Each die's files are in dies/die_<x>_<y>/ (plan.json and waveforms/ of the "
             "drive to play, trim.csv of what to cut; a scrapped die's re-plan in replan/ "
             "saying what fails); one line per die in summary.csv.", "",
             "| outcome | dies | fraction |", "|---|---|---|"]
    lines += [f"| {o} | {v} | {v / n:.3f} |" for o, v in c.items()]
    made = repair_counts(results)
    if made:
        # only where a re-plan repaired its drive (a wafer that needed none: as before)
        lines += ["", "The re-plans' repairs (kind: repairs made, over the dies; "
                  "summary.csv's repairs column per die): "
                  + ", ".join(f"{k} {v}" for k, v in made.items()) + "."]
    lines += ["", "![wafer map](wafer_map.png)", ""]
    partial = [r for r in results if r.get("not_measured")]
    if partial:
        lines += ["## Dies not measured whole", "",
                  f"The measurement of {len(partial)} of the {n} dies leaves impacters "
                  "out: each is taken at its design, so what the loop found holds only "
                  f"if it is at its design; a die that would work is counted "
                  f"{PARTLY_MEASURED}, not as designed.  Measure them to know.", "",
                  "| die (x, y) | not measured | outcome | found |", "|---|---|---|---|"]
        for r in partial:
            found = r["causes"][1] if r["outcome"] == PARTLY_MEASURED else "; ".join(
                k for k in r["causes"] if not k.startswith(NOT_MEASURED))
            lines.append(f"| ({r['die_x']}, {r['die_y']}) | {' '.join(r['not_measured'])} "
                         f"| {r['outcome']} | {found} |")
        lines.append("")
    if causes:
        lines += ["## Why dies are scrapped", "", "| cause | dies |", "|---|---|"]
        lines += [f"| {k} | {v} |" for k, v in sorted(causes.items(), key=lambda kv: -kv[1])]
        lines.append("")
    lines += ["## Every die", "", "| die (x, y) | outcome | causes | trimmed | checks |",
              "|---|---|---|---|---|"]
    for r in results:
        lines.append(f"| ({r['die_x']}, {r['die_y']}) | {r['outcome']} | "
                     f"{'; '.join(r['causes']) or '-'} | {' '.join(r['trimmed']) or '-'} | "
                     f"{r['checks_passed']}/{r['checks']} |")
    return "\n".join(lines) + "\n"


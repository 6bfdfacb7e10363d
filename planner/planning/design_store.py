"""The on-disk design cache: a design is computed once per set of inputs and code.

A plan's designs take minutes; its other stages seconds.  Re-running a plan whose
designs did not change (new output folder, figures, a changed scene that leaves every
impacter's tone, forbidden tones and summed drives alone, another ``--jobs``) takes
every design from this cache.  An entry is keyed by a SHA-256 digest of

- every input of the design task (tone, forbidden tones, the summed drives' tones,
  amplitudes and phases, process, environment, bounds, slider, budget, seed ...),
- the retry policy (:data:`~planner.planning.designs.DESIGN_RETRIES` and the others),
- the source code that computes a design (``model/``, ``planner/designer/``,
  ``planner/planning/designs.py`` and the reach probes' ``planner/planning/reach.py``)
  and the versions of numpy, scipy and numba, so that a changed solver, designer or
  library never reads an old result,

and holds the pickled :class:`~planner.designer.DesignResult`.  A result from the
cache is the object the computation returned, so the plan is byte-identical either
way.  An unreadable entry is recomputed and rewritten; entries are written to a
temporary file and renamed into place, so concurrent plans sharing a cache never read
half an entry.  The cache is the user's own folder (``--cache-dir``, default
``$VIBROPLAN_CACHE_DIR`` or ``~/.cache/vibroplan``); delete it to free the space.

The same folder holds the results of two later stages that a re-run would otherwise
recompute from the same designs (issue 43: a re-run spent 1.4 s verifying and 3.1 s
predicting the yield of designs it read in 0.1 s): each verification step's rows and
failures (``verify/``) and the manufacturability block (``manufacturability/``).  Such
an entry is keyed by :func:`stage_digest`: every input of the stage (the settings, the
seed among them, the designs' models, the step and its drive, ...), the source of all
of ``model/`` and ``planner/`` (:func:`source_fingerprint`: a stage reads more code
than a design does) and the numerical libraries' versions.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import pickle
import tempfile
from pathlib import Path

import numpy as np

#: Bump to invalidate every entry written by earlier versions of the format.
FORMAT = 1


def default_cache_dir() -> Path:
    """``$VIBROPLAN_CACHE_DIR``, else ``$XDG_CACHE_HOME/vibroplan``, else
    ``~/.cache/vibroplan``."""
    env = os.environ.get("VIBROPLAN_CACHE_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "vibroplan"


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 of the source files a design depends on (sorted by path)."""
    import model
    import planner

    model_dir = Path(model.__file__).parent
    planner_dir = Path(planner.__file__).parent
    files = [(model_dir.parent, f) for f in sorted(model_dir.rglob("*.py"))]
    files += [(planner_dir.parent, f) for f in sorted((planner_dir / "designer").glob("*.py"))]
    files.append((planner_dir.parent, planner_dir / "planning" / "designs.py"))
    files.append((planner_dir.parent, planner_dir / "planning" / "reach.py"))
    h = hashlib.sha256()
    for root, f in files:
        # the path inside the installation (model/..., planner/...), then the text
        h.update(f.relative_to(root).as_posix().encode())
        h.update(b"\0")
        h.update(f.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def source_fingerprint() -> str:
    """SHA-256 of every source file of ``model/`` and ``planner/`` (sorted by path):
    the code version of a stage's cached result (:func:`stage_digest`)."""
    import model
    import planner

    h = hashlib.sha256()
    for pkg in (model, planner):
        top = Path(pkg.__file__).parent
        for f in sorted(top.rglob("*.py")):
            h.update(f.relative_to(top.parent).as_posix().encode())
            h.update(b"\0")
            h.update(f.read_bytes())
            h.update(b"\0")
    return h.hexdigest()


def _canon(obj, out):
    """Append a canonical, type-tagged text of ``obj`` to the list ``out``."""
    if obj is None or isinstance(obj, (bool, int, str)):
        out.append(f"{type(obj).__name__}:{obj!r}")
    elif isinstance(obj, float):
        out.append(f"float:{obj.hex()}")
    elif isinstance(obj, np.generic):
        _canon(obj.item(), out)
    elif isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        out.append(f"ndarray:{a.dtype.str}:{a.shape}:{hashlib.sha256(a.tobytes()).hexdigest()}")
    elif isinstance(obj, dict):
        out.append(f"dict:{len(obj)}")
        for k in sorted(obj, key=repr):
            _canon(k, out)
            _canon(obj[k], out)
    elif isinstance(obj, (list, tuple)):
        out.append(f"{type(obj).__name__}:{len(obj)}")
        for v in obj:
            _canon(v, out)
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out.append(f"dataclass:{type(obj).__module__}.{type(obj).__qualname__}")
        for f in dataclasses.fields(obj):
            out.append(f.name)
            _canon(getattr(obj, f.name), out)
    elif hasattr(obj, "model_dump") and hasattr(type(obj), "model_fields"):
        out.append(f"model:{type(obj).__module__}.{type(obj).__qualname__}")
        _canon(obj.model_dump(), out)
    elif hasattr(obj, "__dict__"):
        out.append(f"object:{type(obj).__module__}.{type(obj).__qualname__}")
        _canon(dict(vars(obj)), out)
    else:
        raise TypeError(f"no canonical form for {type(obj).__name__}")


def task_digest(kwargs: dict, *extra) -> str:
    """SHA-256 digest of a design task's keyword arguments, ``extra`` values (the
    retry policy), :func:`code_fingerprint` and the numerical libraries' versions."""
    import numba
    import scipy

    # the designer's last digits also depend on the numerical libraries (SLSQP, BLAS
    # calls, numba's code generation): a new version recomputes
    out = [f"format:{FORMAT}", code_fingerprint(), f"numpy:{np.__version__}",
           f"scipy:{scipy.__version__}", f"numba:{numba.__version__}"]
    _canon(kwargs, out)
    _canon(list(extra), out)
    return hashlib.sha256("\n".join(out).encode()).hexdigest()


def stage_digest(stage: str, *inputs) -> str | None:
    """SHA-256 digest of a stage's ``inputs`` (anything :func:`task_digest` takes: the
    settings, dicts of models, steps, waveforms, digests), the stage's name,
    :func:`source_fingerprint` and the numerical libraries' versions; None when an
    input has no canonical form (that result is then computed, not cached)."""
    import numba
    import scipy

    out = [f"format:{FORMAT}", f"stage:{stage}", source_fingerprint(),
           f"numpy:{np.__version__}", f"scipy:{scipy.__version__}",
           f"numba:{numba.__version__}"]
    try:
        _canon(list(inputs), out)
    except (TypeError, RecursionError):
        return None
    return hashlib.sha256("\n".join(out).encode()).hexdigest()


class DesignStore:
    """Designs on disk under ``path/designs/``, one pickle per task digest.

    Parameters
    ----------
    path : str or Path
        The cache folder; created (with its parents) on the first write.

    Attributes
    ----------
    hits, writes : int
        Designs read from and written to the cache so far.
    probes : dict
        {"read": n, "written": m}: the reach's probes (:mod:`planner.planning.reach`)
        read from and written to it so far (entries beside the designs, counted apart).
    stages : dict
        Stage name -> {"read": n, "written": m}: the later stages' results read from
        and written to the cache so far (:meth:`get_stage`, :meth:`put_stage`).
    """

    def __init__(self, path):
        self.path = Path(path)
        self.folder = self.path / "designs"
        self.hits = 0
        self.writes = 0
        self.probes = {"read": 0, "written": 0}
        self.stages = {}

    def _file(self, digest):
        return self.folder / f"{digest}.pkl"

    def get(self, digest, *, probe=False):
        """The stored result for ``digest``, or None (absent or unreadable); counted in
        :attr:`hits`, or with ``probe`` in :attr:`probes`."""
        res = _load(self._file(digest))
        if res is not None:
            if probe:
                self.probes["read"] += 1
            else:
                self.hits += 1
        return res

    def holds(self, digest) -> bool:
        """Whether a design is stored for ``digest`` (not read, not counted)."""
        return self._file(digest).is_file()

    def put(self, digest, result, *, probe=False):
        """Store ``result`` atomically; an unwritable cache is skipped, not an error
        (the plan does not depend on it).  Counted in :attr:`writes`, or with ``probe``
        in :attr:`probes`."""
        if _store(self.folder, digest, result):
            if probe:
                self.probes["written"] += 1
            else:
                self.writes += 1

    def _count(self, stage):
        return self.stages.setdefault(stage, {"read": 0, "written": 0})

    def get_stage(self, stage: str, digest):
        """A later stage's stored result for ``digest`` (:func:`stage_digest`), or None
        (no digest, absent or unreadable)."""
        if digest is None:
            return None
        self._count(stage)
        res = _load(self.path / stage / f"{digest}.pkl")
        if res is not None:
            self._count(stage)["read"] += 1
        return res

    def marked(self, stage: str, digest) -> bool:
        """Whether :meth:`mark` left ``digest`` under ``stage`` (not counted in
        :attr:`stages`: a mark is a hint, no result)."""
        return digest is not None and (self.path / stage / f"{digest}.pkl").is_file()

    def mark(self, stage: str, digest):
        """Leave a mark for ``digest`` under ``stage`` (see :meth:`marked`)."""
        if digest is not None:
            _store(self.path / stage, digest, True)

    def put_stage(self, stage: str, digest, result):
        """Store a later stage's ``result`` under ``digest`` as :meth:`put` does."""
        if digest is not None and _store(self.path / stage, digest, result):
            self._count(stage)["written"] += 1


def _load(path):
    """The pickled object in ``path``, or None (absent, truncated or foreign: the caller
    recomputes and overwrites it)."""
    try:
        with open(path, "rb") as fh:
            return pickle.load(fh)
    except Exception:
        return None


def _store(folder: Path, digest, result) -> bool:
    """Write ``result`` to ``folder/<digest>.pkl`` through a temporary file renamed into
    place; False (nothing written) when the folder cannot be written."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{digest[:16]}.", suffix=".tmp", dir=folder)
        try:
            with os.fdopen(fd, "wb") as fh:
                pickle.dump(result, fh, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, folder / f"{digest}.pkl")
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError:
        return False
    return True

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
    """

    def __init__(self, path):
        self.path = Path(path)
        self.folder = self.path / "designs"
        self.hits = 0
        self.writes = 0

    def _file(self, digest):
        return self.folder / f"{digest}.pkl"

    def get(self, digest):
        """The stored result for ``digest``, or None (absent or unreadable)."""
        try:
            with open(self._file(digest), "rb") as fh:
                res = pickle.load(fh)
        except Exception:   # absent, truncated or foreign: recompute (and overwrite)
            return None
        self.hits += 1
        return res

    def put(self, digest, result):
        """Store ``result`` atomically; an unwritable cache is skipped, not an error
        (the plan does not depend on it)."""
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{digest[:16]}.", suffix=".tmp",
                                       dir=self.folder)
            try:
                with os.fdopen(fd, "wb") as fh:
                    pickle.dump(result, fh, protocol=pickle.HIGHEST_PROTOCOL)
                os.replace(tmp, self._file(digest))
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
        except OSError:
            return
        self.writes += 1

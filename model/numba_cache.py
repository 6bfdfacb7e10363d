"""Where numba's ``cache=True`` files of vibroplan's kernels go.

numba writes a cached kernel beside its source, in ``__pycache__`` (``*.nbi``, ``*.nbc``).
In a source checkout that is what we want.  In an installed copy (a wheel or ``pip
install .``, in site-packages) those files are unknown to pip: ``pip uninstall`` -- also
the one ``pip install -e .`` runs over a regular install -- removes every file the wheel
listed and leaves ``model/kernels/__pycache__/*.nbi`` behind.  What remains,
``site-packages/model/`` without an ``__init__.py``, is an empty *namespace package*,
and Python's path finder returns it before any import hook of a later install gets
asked: ``import model`` then finds nothing (the editable checkout is shadowed).

So an installed copy caches in the user's cache folder instead, through numba's own
``NUMBA_CACHE_DIR``: ``$XDG_CACHE_HOME/vibroplan/numba`` (default
``~/.cache/vibroplan/numba``), one sub-folder per source folder.  A ``NUMBA_CACHE_DIR``
the user set is left alone.  The setting is made once, before any kernel is decorated
(``model/__init__.py`` and ``planner/coloring/kernels.py`` call
:func:`cache_outside_installed_copy` first), and child processes inherit it.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

#: The folder of the ``model`` package; a checkout has ``pyproject.toml`` beside it.
_PACKAGE = Path(__file__).resolve().parent


def installed() -> bool:
    """Whether this is an installed copy (not a source checkout).

    A checkout (the editable install's target, or a clone on ``sys.path``) holds
    ``pyproject.toml`` beside its packages; site-packages never does.
    """
    return not (_PACKAGE.parent / "pyproject.toml").is_file()


def user_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/vibroplan/numba``, by default ``~/.cache/vibroplan/numba``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "vibroplan" / "numba"


def cache_outside_installed_copy() -> None:
    """Point numba's cache at :func:`user_cache_dir` when this copy is installed.

    Idempotent; does nothing in a checkout or when ``NUMBA_CACHE_DIR`` is set.
    """
    if os.environ.get("NUMBA_CACHE_DIR") or not installed():
        return
    os.environ["NUMBA_CACHE_DIR"] = str(user_cache_dir())
    config = sys.modules.get("numba.core.config")
    if config is not None:
        # numba read its environment when it was imported (before us): read it again,
        # so that the kernels decorated from now on find their cache there
        config.reload_config()

"""The distribution: the wheel holds every package and its data, and an installed copy
leaves nothing of its own in site-packages (numba's cache goes to the user's cache).

Real builds (``pip wheel``), a real virtual environment, real imports; CI (.ci/run)
also installs the wheel with its dependencies into a fresh environment and plans the
tiny spec with it.
"""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

#: Slow (a wheel build, a venv: ~12 s of the default run's 5 minutes): `.ci/run` builds
#: the wheel, installs it into a fresh venv, plans with it and checks the same two
#: things (no numba cache inside site-packages, nothing left after uninstall) on every
#: submission; run these with `python -m pytest -m slow tests/test_packaging.py`.
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]


#: What a source distribution holds: the build reads nothing else.
SOURCES = ("pyproject.toml", "README.md", "model", "planner")


def _clean_env(**extra):
    """The environment without PYTHONPATH (which points the tests at the checkout)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(extra)
    return env


def _dependency_paths() -> list[str]:
    """The running interpreter's site-packages folders (where vibroplan's dependencies
    are, whether it runs in a virtual environment or system-wide)."""
    import site
    import sysconfig

    paths = [sysconfig.get_paths()[k] for k in ("purelib", "platlib")]
    paths += site.getsitepackages() + [site.getusersitepackages()]
    out = []
    for p in paths:
        if p and Path(p).is_dir() and p not in out:
            out.append(p)
    return out


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """The wheel, built from a copy of the sources (a build writes build/ and *.egg-info
    into its source folder: not into the checkout under test)."""
    src = tmp_path_factory.mktemp("src")
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name,
                            ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(ROOT / name, src / name)
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "-q",
                    "-w", str(out)], check=True, capture_output=True, text=True, timeout=600,
                   env=_clean_env())
    (path,) = out.glob("vibroplan-*.whl")
    return path


def test_wheel_holds_every_package_and_the_default_spec(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    packages = sorted(str(p.parent.relative_to(ROOT)) for top in ("model", "planner")
                      for p in (ROOT / top).rglob("__init__.py"))
    assert "planner/planning" in packages  # the package the hand-written list left out
    missing = [p for p in packages if f"{p}/__init__.py" not in names]
    assert missing == [], f"packages not in the wheel: {missing}"
    modules = [str(p.relative_to(ROOT)) for pkg in packages for p in (ROOT / pkg).glob("*.py")]
    assert [m for m in modules if m not in names] == []
    assert "planner/data/array_5x5.yaml" in names
    assert not any(n.startswith("tests/") or n.endswith((".nbi", ".nbc")) for n in names)


def test_installed_copy_caches_numba_outside_and_uninstalls_without_a_trace(wheel, tmp_path):
    """The README's old quirk: an installed copy wrote numba's cache into
    site-packages/model/kernels/__pycache__, which `pip uninstall` (also the one an
    editable install runs) left behind as an empty namespace package `model`."""
    venv = tmp_path / "venv"
    # a venv of its own, without --system-site-packages: the dependencies need not be
    # system-wide (the README's `pip install -e .[test]` may run in a virtual environment)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py = venv / "bin" / "python"
    # --ignore-installed: the running environment may hold an (editable) vibroplan of the
    # same version, which the paths below make visible to the venv's pip
    subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", "--ignore-installed",
                    str(wheel)], check=True, capture_output=True, timeout=300, env=_clean_env())
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()"
                                "['purelib'])"], capture_output=True, text=True,
                               check=True).stdout.strip())
    # the dependencies come from wherever the running interpreter has them (a venv or the
    # system), as path entries after the venv's own site-packages: the wheel's copy is the
    # one imported, and no editable install's finder of the running environment is
    # activated (a .pth line adds a path; the .pth files inside that path are not run)
    deps = site / "_vibroplan_test_dependencies.pth"
    deps.write_text("\n".join(_dependency_paths()) + "\n")
    cache = tmp_path / "xdg"
    env = _clean_env(HOME=str(tmp_path), XDG_CACHE_HOME=str(cache))
    env.pop("NUMBA_CACHE_DIR", None)
    code = ("import model, planner.coloring.kernels as k;"
            "from model.kernels.contact import two_body_impact;"
            "two_body_impact(0.0, 1.0, 1.0, 0.1, 0.7, 0.5);"
            "print(model.__file__)")
    run = subprocess.run([str(py), "-c", code], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().startswith(str(site))  # the installed copy, not the checkout
    assert list((site / "model").rglob("*.nb[ic]")) == []
    assert list((cache / "vibroplan" / "numba").rglob("*.nbi")), "no cache written at all"
    deps.unlink()     # the venv's pip then sees only the venv's vibroplan
    subprocess.run([str(py), "-m", "pip", "uninstall", "-y", "-q", "vibroplan"], check=True,
                   capture_output=True, timeout=300, env=_clean_env())
    left = [str(p.relative_to(site)) for top in ("model", "planner") for p in (site / top).rglob("*")]
    assert not (site / "model").exists() and not (site / "planner").exists(), left

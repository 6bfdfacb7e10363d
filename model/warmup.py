"""Compile (or load from numba's cache) the kernels a plan runs, on a problem that
takes no time to solve.

The exact solver's kernels compile in about 20 s on one core (numba re-optimises the
impacter kernel inside every entry point that calls it, so a plan has only two:
:func:`model.kernels.impacter.response_grid` for every response and sweep, and
:func:`model.kernels.impacter.run_impacter` for every simulation, which is the callee
of the first with the same argument types and so costs nothing more).  A planner that
starts :func:`compile_kernels` in a worker process while it does other work (the
assignment, whose own kernels compile in the main process) pays the compilation once,
overlapped, and every later worker loads the kernels from the cache in milliseconds.

With a warm cache the call only loads the kernels: about 0.3 s.
"""

from __future__ import annotations

import importlib
import time
import warnings

import numpy as np

#: The kernels a plan calls from Python (``module:name``); each compiles, and caches, the
#: kernels it calls with it.  The assigner's colouring kernels are left out: they have
#: compiled by the time the estimate is made.
PLAN_KERNELS = ("model.kernels.impacter:run_impacter", "model.kernels.impacter:response_grid",
                "model.kernels.slider:run_slider",
                "model.kernels.closed_form:tone_coefficients",
                "model.kernels.contact:two_body_impact", "model.kernels.contact:two_body_kick",
                "model.kernels.silence:linear_silence")


def compile_kernels() -> float:
    """Run every kernel of a plan's designs and checks once, on a tiny problem.

    Compiles the response kernel (through :func:`model.responses`, which also compiles
    the exact impacter kernel as its callee), the slider kernel and both contact laws
    (:func:`model.simulate_slider`) with the argument types a plan uses; numba's
    ``cache=True`` then keeps them for every later process.

    Returns
    -------
    float
        Seconds it took (compilation, or loading from the cache).
    """
    from model.bounds import silence_bound
    from model.devices import Impacter, Slider
    from model.drive import Drive
    from model.impacter import SolverWarning, responses
    from model.slider import CONTACTS, simulate_slider

    t0 = time.perf_counter()
    imp = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200.0)
    drive = Drive.tone(5200.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SolverWarning)
        responses(imp, drive, np.array([0.0, 1e-6]), duration=2e-4, check_input=False)
        slider = Slider.from_geometry(8.0e-8)
        for contact in sorted(CONTACTS):
            simulate_slider(imp, slider, drive, duration=2e-4, contact=contact)
        # the designer's proof of silence (model.bounds), with air's damping
        silence_bound(imp.with_natural_frequency(2 * 5200.0), drive)
    return time.perf_counter() - t0


def numba_cache_state(kernels=PLAN_KERNELS):
    """How many of ``kernels`` (``module:name`` of cached numba kernels) must compile.

    A kernel is warm when numba's own cache index for it (next to its source, or in
    ``NUMBA_CACHE_DIR``) exists, was written by this numba version for this source
    file, and holds at least one compiled signature.

    Returns
    -------
    (cold, total) : tuple of int
        Kernels without a usable cache entry, and all of them (0, 0 when numba's cache
        cannot be read).
    """
    cold = 0
    try:
        for entry in kernels:
            module, name = entry.split(":")
            cache_file = getattr(importlib.import_module(module), name)._cache._cache_file
            # numba's own reader: {} when missing, stale or of another numba version
            cold += not cache_file._load_index()
    except Exception:   # numba internals moved: say "not known" rather than fail
        return 0, 0
    return cold, len(kernels)

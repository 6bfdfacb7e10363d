"""Session set-up shared by every test."""


def pytest_configure(config):
    """Compile numba's kernels once, in the process that starts the session, before the
    test workers (``-n 2``) and the CLI subprocesses start: on a fresh clone each of
    them would otherwise compile the same kernels at the same time (tens of seconds
    each); afterwards every process loads them from numba's cache."""
    if hasattr(config, "workerinput"):       # an xdist worker: the controller did it
        return
    from model.warmup import compile_kernels

    compile_kernels()

"""Where the work runs: the Dask engine, worker processes, CPU cores and memory limits."""

"""What the commands do, below the command line: replay (one log: the reference chosen and named,
the runner, scoring) and its report, evaluate (many logs in a process pool or on Dask) and its
report, tune, bench, info. The command line (``cli``) and the Python API call these."""

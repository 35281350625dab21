"""The estimation core: the runner (estimators over a clock segment's samples as they arrive, the
one path replay, live, evaluate, tune and the API share), a run's parameters (params) and the
kernels compiled before they are needed (warmup)."""

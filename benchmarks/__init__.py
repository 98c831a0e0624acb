"""The benchmarks of torchrl-dual, run from the repository root as modules
(``python -m benchmarks.learning``, ``python -m benchmarks.speed.latency``, ...); see
``benchmarks/README.md``. Not part of the installed package (the wheel ships
``torchrl_dual`` only)."""

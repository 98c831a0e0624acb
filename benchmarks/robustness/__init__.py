"""How the code holds up: a run killed and resumed, mutation testing of the core
(``python -m benchmarks.robustness.<name>``)."""

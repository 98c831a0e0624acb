"""Studies of the method's signals and of finished runs: epistemic uncertainty, the
dynamics shifts and DUAL's shift signal, the critics' calibration, the online reward
found, scores over seeds (``python -m benchmarks.studies.<name>``)."""

"""Change detection: pure detectors over numpy arrays, their aggregation and offline evaluation.

Import from the modules themselves (`redline.detect.methods`, `.aggregate`, `.changepoint`, ...):
this package imports nothing, so that `redline --help`, which imports the `evaluate` and `compare`
commands' modules here, does not load scipy. The detectors import scipy.stats inside the function
that calls it, for the same reason: the API server imports their constants and registry, and
scipy.stats took 2.2 of the 5 s the API's import took on a CI machine (2026-11-28).
"""

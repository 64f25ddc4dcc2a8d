"""Change detection: pure detectors over numpy arrays, their aggregation and offline evaluation.

Import from the modules themselves (`redline.detect.methods`, `.aggregate`, `.changepoint`, ...):
this package imports nothing, so that `redline --help`, which imports the `evaluate` and `compare`
commands' modules here, does not load scipy.
"""

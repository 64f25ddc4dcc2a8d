"""The server distribution's commands: the service's processes (`redline server`, `worker`,
`migrate`, `token`, `retention`), the whole service on one machine (`up`, `demo`, with the
embedded Postgres and Redis they start) and the offline tools (`compare`, `evaluate`).

It sits above every layer: it may import the server, the worker and the detectors; nothing
imports it but the `redline` command line (`redline.cli.main`) and the tests.
"""

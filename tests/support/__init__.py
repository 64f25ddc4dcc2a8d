"""Helpers the tests share that are not fixtures: builders of recordings, histories and API
clients, and the test servers' databases. Fixtures live in the `conftest.py` of the folder whose
tests use them; no test module imports another."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

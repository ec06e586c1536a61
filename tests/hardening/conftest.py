"""Hardening tests: faults, hostile input and crash safety on the host (see docs/reliability.md)."""

from __future__ import annotations

import sys
from pathlib import Path

# the seeded truth loop of the estimator tests
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "estimation"))

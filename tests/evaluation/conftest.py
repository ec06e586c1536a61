"""Evaluation tests: scoring against simulated truth."""

from __future__ import annotations

import sys
from pathlib import Path

# the synthetic field and passes of the map tests
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "mapping"))

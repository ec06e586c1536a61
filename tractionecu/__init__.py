"""tractionecu: online traction parameter identification and ground-condition mapping.

Implements Kobelski, Osinenko & Streif, "A method of online traction parameter
identification and mapping" (IFAC-PapersOnLine 2020, doi:10.1016/j.ifacol.2020.12.909)
as an on-board service. All physical quantities are SI unless a name says otherwise.

The public Python API (imported on first use, so ``import tractionecu`` stays light)::

    from tractionecu import Estimator, VehicleParams, read_recording, replay

- :class:`Estimator` — the AUKF-FS estimator; ``step(t, inputs, measurements)`` returns an :class:`Estimate`;
- :class:`VehicleParams`, :class:`SensorSpec`, :class:`EstimatorConfig` — the machine, its sensors, the tuning;
- :func:`read_recording` — a capture (directory, or one CAN file in any common format) as a :class:`Recording`;
- :func:`replay` — the estimator stepped over a recording (a :class:`ReplayResult`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

_API = {
    "Estimator": "tractionecu.estimation.estimator",
    "Estimate": "tractionecu.estimation.estimator",
    "EstimatorConfig": "tractionecu.estimation.config",
    "VehicleParams": "tractionecu.config",
    "SensorSpec": "tractionecu.config",
    "read_recording": "tractionecu.recording.reader",
    "Recording": "tractionecu.recording.containers",
    "replay": "tractionecu.pipeline.replay",
    "ReplayResult": "tractionecu.pipeline.replay",
}

__all__ = ["__version__", *_API]

if TYPE_CHECKING:  # pragma: no cover
    from .config import SensorSpec, VehicleParams
    from .estimation.config import EstimatorConfig
    from .estimation.estimator import Estimate, Estimator
    from .pipeline.replay import ReplayResult, replay
    from .recording.containers import Recording
    from .recording.reader import read_recording


def __getattr__(name: str) -> Any:
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'tractionecu' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_API})

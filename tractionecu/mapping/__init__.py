"""Ground-condition mapping (paper section 4).

Modules: :mod:`.projection` (WGS84 → UTM field frame), :mod:`.grid`
(per-cell running statistics), :mod:`.fill` (the paper's band fill),
:mod:`.tiles` (on-disk format), :mod:`.store` (:class:`MapStore`, the API
called at 10 Hz), :mod:`.soil` (classification by ``a``), :mod:`.sampler`
(window means at the GNSS epochs), :mod:`.from_replay` (a replay's map),
:mod:`.export` (GeoTIFF, ISO-XML, PNG, GeoJSON).  The map scorecard against
a simulated field is :mod:`tractionecu.evaluation.map_score`.

The names below are imported lazily so that ``import tractionecu.mapping``
stays cheap in the cab.
"""

from __future__ import annotations

from typing import Any

_LAZY = {
    "MapStore": "store",
    "LayerGrid": "store",
    "open_store": "store",
    "paper_fill": "fill",
    "FieldFrame": "projection",
    "LAYERS": "grid",
}


def __getattr__(name: str) -> Any:
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'tractionecu.mapping' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f"{__name__}.{mod}"), name)


__all__ = sorted(_LAZY)

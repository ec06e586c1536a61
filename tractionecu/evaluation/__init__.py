"""Scoring against simulated truth; the on-board core never imports it.

Modules: :mod:`.scoring` (the estimator scorecard against ``truth.csv``),
:mod:`.map_score` (the map scorecard against a known field),
:mod:`.map_truth` (the simulated field rebuilt from ``truth.toml``, and a
replay's map scored against it), :mod:`.plots` (the paper's Fig. 5 and 6 of
a replay), :mod:`.replay` (everything a replay of a simulated recording is
scored with, in one call) and :mod:`.suite` (the diagnosis suite: recordings
with one concealed effect, and their scoring).

The core (``bus``, ``gnss``, ``recording``, ``estimation``, ``mapping``,
``service``, ``pipeline``) runs on the tractor and has no truth to score
against; ``tests/test_core_imports.py`` keeps it from importing this package
or the simulator.
"""

"""Score a finished replay of a simulated recording: what ``tractionecu replay`` adds with truth.

:func:`score_replay` takes the outputs of a replay (its directory, the
recording, the per-step result arrays and the summary so far) and writes,
next to ``estimates.csv``:

* ``scorecard.json`` — the estimator scorecard (:mod:`.scoring`) against
  ``truth.csv``, with the replay's ``realtime_factor``;
* ``map_scorecard.json`` — when the replay wrote a map, that map against the
  field of ``truth.toml`` (:mod:`.map_truth`);
* with ``plot``: ``fig6_mu_rho.png``, ``fig5_mu_curves.png``,
  ``fig_efficiency.png`` (η and s*) and ``report.html`` (map, curves,
  efficiency over the track, advice) (:mod:`.plots`), also for a recording
  without truth (estimates only).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from ..jsonsafe import json_safe
from .map_truth import score_replay_map
from .plots import plot_efficiency, plot_run
from .machine_score import is_machine_level, machine_scorecard
from .scoring import read_truth, scorecard


def read_scorecard(path: Path | str) -> dict[str, Any]:
    """A ``scorecard.json`` as :func:`score_replay` returned it: its ``null`` figures (not measured: strict
    JSON has no NaN) read back as NaN."""
    def nan(x: Any) -> Any:
        if x is None:
            return math.nan
        if isinstance(x, dict):
            return {k: nan(v) for k, v in x.items()}
        if isinstance(x, list):
            return [nan(v) for v in x]
        return x

    return nan(json.loads(Path(path).read_text(encoding="utf-8")))


def score_replay(out_dir: Path, rec: Any, arrays: dict[str, Any], *, plot: bool,
                 summary: dict[str, Any]) -> dict[str, Any]:
    """Score a replay against the recording's truth; return the additions to its summary.

    ``rec`` is the :class:`~tractionecu.recording.reader.Recording` replayed,
    ``arrays`` the replay's per-step results (keys t, mu, slip, omega,
    P_diag, nis_dof, status, valid, soil_class, rho_s, a, v, nis, adapt).
    ``summary`` is the replay's summary so far and is not changed: its
    ``realtime_factor`` goes into ``scorecard.json``, and the map is scored
    only when it says a map was written (``map_epochs``, from
    :func:`~tractionecu.mapping.from_replay.write_replay_map`).

    Returns a dict with, as they apply, ``scorecard`` and ``scorecard_json``
    (recording with ``truth.csv``), ``map_scorecard`` (map written and
    ``truth.toml`` with a field) and ``plots`` (``plot``).
    """
    out = Path(out_dir)
    add: dict[str, Any] = {}
    def skipped(path: Any, e: Exception) -> None:
        # a truth file of another tool (a user's own simulator, another format): the replay's outputs
        # stand, the scoring is said to be left out (it raised after every estimate had been written)
        add.setdefault("truth_skipped", []).append(f"{Path(path).name}: not scored: {e}")

    if "map_epochs" in summary:
        try:
            card = score_replay_map(out, rec, Path(summary.get("map_dir", out / "map")))
        except (ValueError, KeyError, TypeError, OSError) as e:      # tomllib.TOMLDecodeError is a ValueError
            skipped(rec.truth_toml_path, e)
            card = None
        if card is not None:
            add["map_scorecard"] = card
    truth = sc = None
    if rec.truth_csv_path is not None:
        try:
            truth = read_truth(rec.truth_csv_path, rec.truth_toml_path)
            if is_machine_level(arrays):                 # one μ for the machine: scored against ΣF_h/ΣF_z
                from ..pipeline.replay import machine_of

                sc = machine_scorecard(arrays, truth, rec.truth_csv_path, machine_of(rec)[0].mass_kg)
            else:
                sc = scorecard(arrays, truth)
            add["scorecard"] = sc
        except (ValueError, KeyError, TypeError, OSError) as e:
            skipped(rec.truth_csv_path, e)
            truth = sc = None
    if plot:
        add["plots"] = plot_run(out, arrays, truth, sc)
        eff_paths, _ = plot_efficiency(out, rec, arrays, truth)     # η and s*, and report.html
        add["plots"] += eff_paths
    if sc is not None:
        sc_out = dict(sc)
        if "realtime_factor" in summary:
            sc_out["realtime_factor"] = summary["realtime_factor"]
        path = out / "scorecard.json"
        # strict JSON: a figure not measured (NaN) is null
        path.write_text(json.dumps(json_safe(sc_out), indent=2, sort_keys=True, allow_nan=False) + "\n",
                        encoding="utf-8")
        add["scorecard_json"] = str(path)
    return add

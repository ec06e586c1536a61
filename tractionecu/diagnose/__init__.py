"""Simulation versus recording: locate the mismatch, name the missing physics, fit it.

Entry points: :func:`diagnose_path` (what ``tractionecu diagnose`` runs) and
:func:`tractionecu.diagnose.engine.diagnose` (the analysis of one recording).
Diagnosis reads only what a real logger records: never ``truth.csv`` or
``truth.toml``.
"""

from __future__ import annotations

from pathlib import Path


def diagnose_path(recording: str | Path, out: str | Path, *, vehicle: str | Path | None = None,
                  csv_mapping: str | None = None, reference_torque_nm: float | None = None,
                  time_offset_s: float = 0.0, estimator: bool = True) -> dict:
    """Diagnose a recording directory (or a decoded CSV export) and write the report into ``out``.

    A CSV export (``csv_mapping`` a :class:`~tractionecu.recording.csv_import.CsvMapping` or the
    name of one, ``"contract"``, ``"j1939"`` or ``"auto"``, or a path ending in ``.csv``) goes
    through :func:`tractionecu.recording.csv_import.import_csv` (percent engine torque over
    ``reference_torque_nm``, else the vehicle file's ``[drivetrain] engine_reference_torque_nm``; on a bus
    recording ``reference_torque_nm`` stands in for that key, used where the bus sends no EC1);
    engine-level exports without per-wheel data get the reduced analysis of :mod:`.reduced`, and so does a
    bus recording that leaves the full analysis no channel but carries the engine-level signals (a
    mechanical tractor without draft sensing).  Returns the ``report.json`` dict.
    """
    from . import data as _data
    from . import report as _report

    p = Path(recording)
    out = Path(out)
    is_csv = csv_mapping is not None or (p.is_file() and p.suffix.lower() == ".csv" and not _is_can_capture(p))
    if is_csv:
        from ..recording.csv_import import CsvMapping, import_csv, mapping_named

        mapping = csv_mapping if isinstance(csv_mapping, CsvMapping) else mapping_named(csv_mapping or "j1939")
        if reference_torque_nm is None and vehicle is not None:
            # an export carries no EC1: the engine's reference torque (SPN 544) as the vehicle file declares it
            from ..config import load_vehicle

            declared = float(load_vehicle(vehicle).drivetrain.engine_reference_torque_nm)
            reference_torque_nm = declared if declared > 0 else None
        rec = import_csv(p, mapping, time_offset_s=time_offset_s, reference_torque_nm=reference_torque_nm,
                         vehicle_toml=vehicle)
        fr = _data.load(rec, vehicle)
        if not fr.has("omega", "md"):
            return _write_reduced(fr, out)
        source = fr
    else:
        # the reference torque given stands in for EC1's on the bus too (it was read for an export only)
        source = _data.load(p, vehicle, reference_torque_nm=reference_torque_nm)
    from .engine import diagnose
    from .reduced import ENGINE_LEVEL

    d = diagnose(source)
    if not d.problem.channels and not source.has("omega", "md") and source.has(*ENGINE_LEVEL):
        # A bus recording of a mechanical tractor without draft or axle-load sensing: no channel of the
        # full analysis, but the engine-level one of an export works on the same signals.
        return _write_reduced(source, out, note=(
            "engine-level analysis: the recording has no per-wheel drive torques, no front-axle load and no "
            "draft, which the full analysis needs; it has engine torque (EEC1 × EC1), engine speed, a "
            "wheel-based speed and the GNSS speed"))
    from .channels import release_memos

    release_memos(d.problem.channels.values())   # the fits are done: memos only spare recomputation
    est = None
    if estimator and not is_csv and p.is_dir():
        from ..pipeline.replay import MissingSignals
        from .innovations import estimator_view

        try:
            est = estimator_view(p, d.features)
        except MissingSignals as exc:
            # The second view needs what replay needs (a hub drive: the draft and the front-axle load); the
            # fits above do not, and their report is not dropped for it.
            why = f"not run: replay needs {', '.join(exc.missing)}, which this recording lacks"
            est = {"skipped": why}
            d.notes.append(f"estimator view {why}")
    return _report.write(d, out, est)


def _is_can_capture(p: Path) -> bool:
    """A ``.csv`` file that is a CAN capture (python-can's CSV, a PolyCAN export), judged by content as
    ``replay`` and ``inspect`` judge it, not a decoded export."""
    from ..errors import RecordingError
    from ..recording.formats import detect

    try:
        return detect(p) in ("csv", "polycan")
    except RecordingError:
        return False


def _write_reduced(fr, out: Path, note: str | None = None) -> dict:
    """The engine-level analysis of ``fr`` (:func:`.reduced.diagnose_reduced`) written into ``out``."""
    import json

    from . import report as _report
    from .reduced import diagnose_reduced

    if note:
        fr.notes.append(note)
    rep = _report._num(diagnose_reduced(fr))
    with _report.staged(out) as st:
        (st / "report.json").write_text(json.dumps(rep, indent=2, ensure_ascii=False), encoding="utf-8")
        (st / "report.md").write_text(_report.to_markdown(rep), encoding="utf-8")
        _report.plot_reduced(rep, fr, st)
    return rep


__all__ = ["diagnose_path"]

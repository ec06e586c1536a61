"""``tractionecu inspect REC [--dbc FILE ...]``: what a recording holds, and what was wrong with it.

The recording is read block by block and only its speed signals are kept whole (the
others as stubs that tell whether they are present), so memory hardly grows with its
length; the last line reports the reading's throughput.

The report (:func:`tractionecu.recording.summary.summarize`): duration,
frames, rates and gaps per message, unknown PGNs, decode errors, address
claims, GNSS epochs, rejected lines; the capture format, the CAN-to-GNSS clock
offset when one was estimated (or why none was found: inspect reports it where
replay refuses), warnings about implausible durations, an unset logger clock
and time jumps; then for each estimation profile the
contract signals found (with the message they came from) and missing, and
whether the speed signals show motion.

``--dbc FILE`` (repeatable) adds the owner's DBC files to the built-in one;
a ``[signals]`` table in the recording's ``vehicle.toml`` maps their
signals onto contract names (:func:`tractionecu.config.signal_map`).
"""

from __future__ import annotations

import argparse
import math
import time
from typing import Any

from ..bus.dbc import Codec, extra_dbcs
from ..pipeline.signals import (GNSS_TRACK_SPEED, PROFILE_KINDS, best_profile, estimator_profile, motion,
                                profile_role, profile_status, required_missing, signal_state, source_of)
from ..pipeline.survey import inspect_keep
from ..recording.containers import TIME_JUMP_S
from ..recording.reader import read_recording
from ..recording.summary import summarize


def add_dbc_option(p: argparse.ArgumentParser) -> None:
    """``--dbc FILE``, repeatable: the owner's DBC files, loaded beside the built-in one."""
    p.add_argument("--dbc", action="append", default=[], metavar="FILE",
                   help="the owner's DBC file, added to the built-in one (repeatable); map its signals onto the "
                        "contract names with a [signals] table in the recording's vehicle.toml")


def dbc_lines(codec: Codec) -> list[str]:
    """The owner's DBC files of ``codec``: messages added, messages skipped and why."""
    out = []
    for path in codec.extra_paths:
        names = [m.name for m in codec.messages.values() if m.source == path.name]
        out.append(f"  owner DBC {path.name}: {len(names)} messages ({', '.join(names)})")
        ids: dict[tuple[str, str], int] = {}      # a DBC may define one name on several identifiers
        for f, msg, why in codec.skipped:
            if f == path.name:
                ids[(msg, why)] = ids.get((msg, why), 0) + 1
        out += [f"    skipped {msg}{f' ({n} identifiers)' if n > 1 else ''}: {why}" for (msg, why), n in ids.items()]
    return out


def vehicle_of(rec: Any) -> tuple[Any, str]:
    """The recording's vehicle (:func:`tractionecu.pipeline.replay.machine_of`) and a line saying where it came
    from; a ``vehicle.toml`` that does not load is reported, and the defaults (hub) stand in."""
    from ..config import VehicleParams
    from ..errors import ConfigError
    from ..pipeline.replay import machine_of

    if rec.vehicle_toml_path is None:
        return VehicleParams(), "no vehicle.toml: the default [drivetrain] kind = \"hub\""
    try:
        veh = machine_of(rec)[0]
    except ConfigError as e:
        why = str(e).removeprefix(f"{rec.vehicle_toml_path}: ")      # the line names the file already
        return VehicleParams(), f"vehicle.toml does not load ({why}): the default [drivetrain] kind = \"hub\""
    return veh, f"vehicle.toml: [drivetrain] kind = \"{veh.drivetrain.kind}\""


def profile_lines(rec: Any) -> list[str]:
    """The estimation profiles (:data:`tractionecu.pipeline.signals.PROFILES`): the one replay runs (from the
    recording's ``vehicle.toml``), and for each profile each need with the signal found and its message, or
    what is missing; the profile the signals fit best when it is another; then the motion the speed signals
    show."""
    veh, origin = vehicle_of(rec)
    run_as = estimator_profile(veh)
    status = profile_status(rec, veh)
    out = [f"  estimation profiles (contract signals found, from which message); replay runs {run_as} ({origin}):"]
    for name, needs in status.items():
        found = sum(1 for _, sig in needs if sig is not None)
        out.append(f"    {name} ({profile_role(name, run_as)}): {found} of {len(needs)} found")
        width = max(len(need.what) for need, _ in needs)
        for need, sig in needs:
            if sig is not None:
                src = source_of(rec, sig)
                label = "speed over ground" if sig == GNSS_TRACK_SPEED else sig
                out.append(f"      {need.what:<{width}}  {label}" + (f" from {src}" if src and src != sig else ""))
                continue
            sent = [s for s in need.signals if signal_state(rec, s) == "not available"]
            names = " or ".join("GNSS speed" if s == GNSS_TRACK_SPEED else s for s in need.signals)
            note = (f" ({', '.join(source_of(rec, x) or x for x in sent)} sent, every value not available)"
                    if sent else "")
            note += "".join(f" (mapped: {source_of(rec, x)})" for x in need.signals
                            if x != GNSS_TRACK_SPEED and signal_state(rec, x) == "absent" and source_of(rec, x))
            out.append(f"      {need.what:<{width}}  missing: {names}{note}")
    best = best_profile(status)
    if best != run_as and origin.startswith("vehicle.toml does not load"):
        out.append(f"  the signals fit profile {best} best: once vehicle.toml loads (above), it runs the profile "
                   "its [drivetrain] declares")
    elif best != run_as:
        out.append(f"  the signals fit profile {best} best: declare [drivetrain] {PROFILE_KINDS[best]} in "
                   "vehicle.toml to run it")
    missing = required_missing(rec, veh)
    out.append(f"  replay of profile {run_as}: " + (f"does not run, missing {', '.join(missing)}" if missing
                                                    else "runs (the signals it cannot run without are there)"))
    out.append(f"  motion: {motion(rec).describe()}")
    return out


PLAUSIBLE_DURATION_S = 7 * 86400.0
"""A recording longer than this (a week) is reported as implausible: a clock jump, not a drive."""
EARLIEST_PLAUSIBLE_T = 946684800.0
"""2000-01-01 UTC: a CAN time before it comes from a logger whose clock was never set."""


def time_lines(rec: Any) -> list[str]:
    """The capture format, how CAN and GNSS clocks were reconciled, and warnings about implausible
    durations, unset clocks and time jumps."""
    st = rec.stats
    out = [f"  CAN capture format: {st.can_format or 'candump'}"]
    if st.clock_note:
        out.append(f"  clock: {st.clock_note}")
    dur = rec.duration
    if math.isfinite(dur) and dur > PLAUSIBLE_DURATION_S:
        out.append(f"  WARNING: implausible duration {dur:.3g} s ({dur / 86400:.0f} days): the times jump "
                   "(a logger clock set while logging, or CAN and GNSS on different clocks)")
    first = st.can_t_first if math.isfinite(st.can_t_first) else math.nan
    if math.isfinite(first) and first - st.clock_offset_s < EARLIEST_PLAUSIBLE_T:
        raw = first - st.clock_offset_s
        out.append(f"  WARNING: the CAN capture's own clock starts at {raw:.3f} s ("
                   f"{time.strftime('%Y-%m-%d', time.gmtime(max(raw, 0.0)))}): a logger without a set clock"
                   + ("; placed on GNSS time (see clock)" if st.clock_offset_s else ""))
    if st.n_time_jumps:
        shown = ", ".join(f"{dt:.3g} s at {_when(t)}" for t, dt in st.time_jumps)
        more = ", ..." if st.n_time_jumps > len(st.time_jumps) else ""
        out.append(f"  WARNING: {st.n_time_jumps} time jump(s) between consecutive CAN frames over "
                   f"{TIME_JUMP_S:.0f} s: {shown}{more}")
    return out


def _when(t: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(t)) if 0 <= t < 4e9 else f"{t:.3f} s"


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inspect", help="print duration, frame counts, rates, gaps, rejected lines and the signals "
                                       "each estimation profile finds or misses")
    p.add_argument("recording", help="recording directory, or one CAN capture file (candump, ASC, BLF, TRC, "
                                     "python-can CSV/SQLite, MF4) with its NMEA log beside it")
    add_dbc_option(p)
    p.set_defaults(func=run)


def throughput_line(rec: Any, seconds: float) -> str:
    """How fast the recording was read: frames and bytes per second, and recorded time per second."""
    frames = sum(getattr(f, "frames", 0) for f in rec.stats.files.values())
    size = 0
    for name in rec.stats.files:
        q = rec.path / name if rec.path.is_dir() else rec.path.parent / name
        size += q.stat().st_size if q.is_file() else 0
    dur = rec.duration if math.isfinite(rec.duration) else 0.0
    sec = max(seconds, 1e-9)
    return (f"  read in {seconds:.2f} s: {frames / sec:,.0f} frames/s, {size / sec / 1e6:.1f} MB/s, "
            f"{dur / sec:,.0f}x real time")


def run(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    with extra_dbcs(args.dbc) as codec:
        rec = read_recording(args.recording, clock="report", keep=inspect_keep)
    read_s = time.perf_counter() - t0
    print("\n".join([summarize(rec), *time_lines(rec), *profile_lines(rec), *dbc_lines(codec),
                     throughput_line(rec, read_s)]))
    return 0

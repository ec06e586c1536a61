"""``tractionecu inspect``: a recording's duration, frames and rates per message,
gaps, unknown PGNs, decode errors, address claims, GNSS epochs and rejected lines.
The estimation profiles that follow in the command's output are the pipeline's
(:func:`tractionecu.cli.inspect.profile_lines`)."""

from __future__ import annotations

import math
from collections import Counter
from datetime import datetime, timezone

from ..bus.transport import PGN_TP_CM, PGN_TP_DT
from .containers import Recording, RecordingStats

_PGN_NOTES = {PGN_TP_CM: "  (transport protocol: connection management)",
              PGN_TP_DT: "  (transport protocol: data)"}

MAX_UNKNOWN_PGNS = 40
"""Unknown PGNs listed one a line, the most frequent; the rest are summed in one line (a bus flood of random
identifiers has tens of thousands)."""


def _fmt_t(t: float) -> str:
    if not math.isfinite(t):
        return "-"
    try:
        return datetime.fromtimestamp(t, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + "Z"
    except (OverflowError, ValueError, OSError):  # beyond years 1..9999 or the platform's time_t
        return f"{t:.6f} s"


def summarize(recording: Recording) -> str:
    """Human-readable report for ``tractionecu inspect``: duration, frames and
    rates per message, gaps, unknown PGNs, decode errors, address claims,
    GPS epochs and rejected lines."""
    r = recording
    st = r.stats
    out: list[str] = [f"Recording {r.path}"]
    out.append(
        f"  duration {r.duration:.3f} s  ({_fmt_t(r.t_start)} .. {_fmt_t(r.t_end)})"
        if math.isfinite(r.duration)
        else "  duration: no samples"
    )
    for fname, fst in st.files.items():
        lines = getattr(fst, "lines", 0)
        acc = getattr(fst, "frames", getattr(fst, "accepted", 0))
        rej = getattr(fst, "total_rejected", 0)
        out.append(f"  {fname}: {lines} lines, {acc} accepted, {rej} rejected")
    if st.messages:
        out.append("  messages:")
        out.append(f"    {'name':<22}{'PGN':>7}{'frames':>8}{'rate Hz':>9}{'nominal':>9}{'gaps':>6}{'max dt s':>10}  sources")
        for ms in sorted(st.messages.values(), key=lambda m: (m.pgn is None, m.pgn or 0, m.name)):
            nom = f"{1.0 / ms.nominal_period_s:.1f}" if ms.nominal_period_s else "-"
            rate = f"{ms.rate_hz:.2f}" if math.isfinite(ms.rate_hz) else "-"
            srcs = ",".join(f"0x{sa:02X}" for sa in sorted(ms.sources) if sa >= 0) or "-"
            pgn = str(ms.pgn) if ms.pgn is not None else f"{ms.std_id:#05x}" if ms.std_id is not None else "-"
            out.append(
                f"    {ms.name:<22}{pgn:>7}{ms.count:>8}{rate:>9}{nom:>9}{ms.n_gaps:>6}{ms.max_interval_s:>10.3f}  {srcs}"
            )
            for t0, dt in ms.gaps:
                out.append(f"      gap {dt:.3f} s at {_fmt_t(t0)}")
    if st.unknown_pgns:
        out.append(
            f"  unknown PGNs skipped: {st.unknown_frames} frames, {len(st.unknown_pgns)} PGNs"
        )
        shown = sorted(st.unknown_pgns.items(), key=lambda kv: (-kv[1], kv[0]))[:MAX_UNKNOWN_PGNS]
        for pgn, n in sorted(shown):
            kept = st.unknown_pgn_sources.get(pgn)
            srcs = ",".join(f"0x{sa:02X}" for sa in sorted(kept)) if kept is not None else "(sources not kept)"
            out.append(f"    PGN {pgn:>6} (0x{pgn:05X}) {n:>7} frames  from {srcs}{_PGN_NOTES.get(pgn, '')}")
        if len(st.unknown_pgns) > len(shown):
            rest = st.unknown_frames - sum(n for _, n in shown)
            out.append(f"    ... {len(st.unknown_pgns) - len(shown)} more PGNs, {rest} frames (the "
                       f"{len(shown)} most frequent are listed)")
    if st.non_extended_frames:
        out.append(f"  11-bit frames skipped: {st.non_extended_frames}")
    if st.decode_errors:
        out.append("  decode errors (wrong DLC):")
        for name, n in sorted(st.decode_errors.items()):
            lines = ", ".join(map(str, st.decode_error_lines.get(name, [])))
            out.append(f"    {name}: {n} (line {lines})")
    out += [f"  WARNING: {line}" for line in other_source_lines(st)]
    if st.address_claims:
        out.append("  address claims (PGN 60928):")
        for c in st.address_claims:
            out.append(f"    SA 0x{c.sa:02X} ({c.sa:3d}) x{c.count}: {c.name.describe()}")
    if len(r.gps):
        q = Counter(int(v) for v in r.gps.fix_quality)
        span = r.gps.t[-1] - r.gps.t[0]
        rate = (len(r.gps) - 1) / span if span > 0 else math.nan
        out.append(
            f"  GPS: {len(r.gps)} epochs, {rate:.2f} Hz, fix quality "
            + ", ".join(f"{k}:{v}" for k, v in sorted(q.items()))
        )
    if st.gps_alignment:
        out.append(f"  GPS alignment: {st.gps_alignment}")
    rej = [(f, s) for f, s in st.files.items() if getattr(s, "total_rejected", 0)]
    if rej:
        out.append("  rejected lines:")
        for _fname, s in rej:
            for line in s.describe():  # type: ignore[attr-defined]
                out.append(f"    {line}")
    for s in st.files.values():
        out += [f"  {line}" for line in getattr(s, "notes", list)()]
    ign = [(f, s) for f, s in st.files.items() if getattr(s, "ignored", None)]
    for fname, s in ign:
        out.append(
            f"  {fname} ignored: " + ", ".join(f"{k} x{v}" for k, v in sorted(s.ignored.items()))  # type: ignore[attr-defined]
        )
    return "\n".join(out)


def other_source_lines(stats: RecordingStats) -> list[str]:
    """One line per message sent by more than one source address: whose frames give its signals, and what of
    the others was left out (:func:`.fastdecode.one_source`)."""
    out = []
    for name, other in stats.other_sources.items():
        used = stats.source_used.get(name)
        srcs = ", ".join(f"0x{sa:02X} ({n} frames)" for sa, n in sorted(other.items()))
        out.append(f"{name} is sent by more than one source: its signals are those of 0x{used:02X}, the first "
                   f"seen; not used: {srcs} (another ECU sending the same message, or a second bus logged "
                   "through a gateway)")
    return out


def wrong_length_line(stats: RecordingStats) -> str:
    """The frames of a known message skipped for their wrong length, one line (``""`` when there are none):
    what ``replay`` and ``diagnose`` say they left out beside the skipped lines."""
    if not stats.decode_errors:
        return ""
    return ("skipped frames of a known message with the wrong length: "
            + ", ".join(f"{name} {n}" for name, n in sorted(stats.decode_errors.items())))

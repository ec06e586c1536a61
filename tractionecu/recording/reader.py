"""Read a recording directory into time-aligned signal series.

A recording is a directory (see ``docs/architecture.md``)::

    can.log      candump -L lines                     (required)
    gps.nmea     raw NMEA 0183 lines                  (optional)
    vehicle.toml nominal VehicleParams                (path kept, not parsed here)
    truth.csv    simulated truth                      (path kept)
    truth.toml   scenario, seed, effects              (path kept)

``read_recording`` also accepts a single capture file, with the GNSS log
beside it (``<name>.nmea``, else ``gps.nmea``) when there is one.  The CAN
file may be in any format of :mod:`.formats` (candump ``-L`` and screen
output, Vector ASC/BLF, PEAK TRC, python-can CSV/SQLite, MF4), recognised by
its content; a directory without ``can.log`` may hold one ``can.<ext>``.

Clocks
------
When the CAN capture's clock cannot be trusted (:data:`.formats.TRUSTED_CLOCK`)
or its frames overlap the GNSS epochs badly, the offset between the two clocks
is estimated from the speeds both see (:mod:`.clock`) and added to every CAN
time; ``RecordingStats.clock_note`` reports it with its uncertainty.  A trusted
clock that overlaps well is checked the same way, and an offset beyond
:data:`.clock.CHECK_MIN_S` (a logger's clock seconds off) is applied and reported.  When the
frames and the epochs do not overlap and no offset is found, ``clock="auto"``
raises :class:`~tractionecu.errors.RecordingError` saying why;
``clock="report"`` (``inspect``) keeps the times and reports the problem;
``clock="keep"`` never estimates.

CAN decoding
------------
Frames are decoded in bulk (:mod:`.fastdecode`), block by block
(:mod:`.chunks`: a candump ``-L`` file is never held whole), with the same
results as frame by frame (:func:`read_can_per_frame`).  ``keep`` makes a
survey that keeps only some signals whole; :func:`stream_signals` reads the
capture again block by block for a streamed replay.  Every 29-bit frame is decoded by its PGN through :class:`~tractionecu.bus.dbc.Codec`,
whatever its source (and, for PDU1, destination) address.  Frames whose
PGN the DBC lacks are skipped and counted per PGN (with the source
addresses seen); frames of a known PGN with the wrong DLC are skipped and
counted per message; 11-bit frames are decoded by identifier when an owner's
DBC defines it (no source address: ``Series.sa`` -1), else counted and skipped.  Address
Claimed frames (PGN 60928) are listed with source address and decoded
NAME.  Lines the candump reader rejects (garbage, truncated, bad hex,
DLC > 8, time going backwards, ...) are counted by reason with the first
line numbers.

The owner's own messages
------------------------
``dbc`` adds the owner's DBC files to the built-in one (their signals are
named ``Message.Signal``, :class:`~tractionecu.bus.dbc.Codec`).  A
``[signals]`` table (the ``signals`` argument, else the recording's
``vehicle.toml``) maps them onto contract names: the contract signal is the
source series times the scale, in the contract unit, and replaces a contract
signal decoded directly.  ``Recording.signal_sources`` says where each
signal came from (for a mapped source without frames: that it is not in the
recording).  Unknown contract names, messages or signals are
:class:`~tractionecu.errors.ConfigError` naming the key, raised before the
CAN log is read.

GNSS epochs are placed on the CAN time axis by :mod:`.gps`; the containers are
in :mod:`.containers`, the per-frame reference decoder in :mod:`.reference`
and the ``tractionecu inspect`` report in :mod:`.summary`.

All series times are epoch seconds [s]; values are in the DBC's SI units.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np

from ..bus.candump import ReadStats
from ..bus.dbc import Codec, default_codec
from ..config import load_signal_map
from ..counting import MAX_EXAMPLES
from ..errors import ConfigError, RecordingError
from .containers import (CAN_FILE, GAP_FACTOR, GPS_FILE, TRUTH_CSV, TRUTH_TOML, VEHICLE_FILE,
                         GpsTrack, MessageStats, Recording, RecordingStats, Series, Table)
from .gps import read_gps

__all__ = ["GpsTrack", "HeldBlocks", "MessageStats", "Recording", "RecordingStats", "Series", "Table", "held_signals",
           "read_recording", "stream_signals"]


def read_recording(path: str | Path, codec: Codec | None = None, *, dbc: Sequence[str | Path] = (),
                   signals: Mapping[str, tuple[str, float]] | None = None, gps: str | Path | None = None,
                   clock: str = "auto", keep: Callable[[str, set[str]], bool] | None = None,
                   reference: bool = False, hold: "HeldBlocks | None" = None) -> Recording:
    """Read a recording directory (or a lone candump file) into a :class:`Recording`.

    ``dbc``: the owner's DBC files, added to ``codec``'s (default: the
    built-in DBC).  ``signals``: a ``[signals]`` mapping, contract name ->
    (``Message.Signal``, scale) (:func:`tractionecu.config.signal_map`);
    None takes the recording's ``vehicle.toml`` ``[signals]`` table, if any.
    ``gps``: the NMEA file (default: the directory's ``gps.nmea``, or for a
    single capture file ``<name>.nmea`` or ``gps.nmea`` beside it).
    ``clock``: ``auto``, ``report`` or ``keep`` (module doc, "Clocks").
    ``keep(name, names seen)``: False keeps only a stub of that signal (its first and last time and
    first number): a survey of a long recording that the replay then streams (:mod:`.chunks`).  Once False
    for a name, ``keep`` must stay False for it (as the survey's do): a stub whose first number is known is not
    asked again, and its values are no longer computed (only its message's times).
    ``reference``: read the GNSS log sentence by sentence (:func:`.gps.read_gps_reference`) instead of
    through the NMEA fast path; the same recording (``tests/recording/test_reader_fast.py``), for the
    equality tests and ``benchmarks/decode.py``.
    ``hold``: keep the decoded blocks of ``hold.names`` beside the survey, up to ``hold.max_bytes``, so that
    one later pass over them (:func:`held_signals`) replaces :func:`stream_signals`' second reading of the
    capture (:class:`HeldBlocks`).

    Raises :class:`~tractionecu.errors.RecordingError` naming the file (and
    line) when the path is missing, ``can.log`` is missing, unreadable,
    empty or holds no valid frame, or ``gps.nmea`` is present but empty or
    unreadable; :class:`~tractionecu.errors.ConfigError` for a DBC that cannot
    be loaded or a mapping naming an unknown signal.  Bad lines and frames
    are counted in ``Recording.stats``.
    """
    if clock not in CLOCK_MODES:
        raise ConfigError(f"clock: one of {', '.join(CLOCK_MODES)}, got {clock!r}")
    p = Path(path)
    if not p.exists():
        raise RecordingError(f"{p}: no such recording")
    root, can_path, codec, mapping = _resolve(p, codec, dbc, signals)
    stats = RecordingStats()
    if hold is not None:
        hold.mapping = list(mapping)
    decoded = _read_can(can_path, codec, stats, _keep_mapped(keep, mapping), hold)
    sources = {name: codec.signals[name].message for name in decoded}
    for target, src, scale in mapping:
        s = decoded.get(src)
        how = src if scale == 1.0 else f"{src} x {scale:g}"
        if s is None:
            if target not in decoded:
                sources[target] = f"{how}, not in the recording"
            continue
        decoded[target] = Series(s.t, s.value * scale, s.sa, codec.signals[target].unit)
        sources[target] = how
    can_t0 = stats.can_t_first

    track = GpsTrack.empty()
    gps_path = Path(gps) if gps is not None else _gps_beside(p)
    if gps_path is not None and (gps is not None or gps_path.exists()):
        if not gps_path.is_file():
            raise RecordingError(f"{gps_path}: no such GNSS file")
        track = read_gps(gps_path, can_t0, stats, fast=not reference)
    else:
        stats.gps_alignment = f"no {GPS_FILE}"
    _reconcile_clocks(can_path, decoded, track, stats, clock)

    def opt(name: str) -> Path | None:
        q = root / name
        return q if p.is_dir() and q.is_file() else None

    units = {name: s.unit for name, s in decoded.items()}
    return Recording(
        path=p,
        signals=decoded,
        gps=track,
        stats=stats,
        vehicle_toml_path=opt(VEHICLE_FILE),
        truth_csv_path=opt(TRUTH_CSV),
        truth_toml_path=opt(TRUTH_TOML),
        units=units,
        signal_sources=sources,
    )


def stream_signals(rec: Recording, codec: Codec | None = None, *, dbc: Sequence[str | Path] = (),
                   signals: Mapping[str, tuple[str, float]] | None = None, names: Sequence[str] | None = None,
                   reference: bool = False) -> Iterator[tuple[dict[str, tuple[np.ndarray, np.ndarray]], float]]:
    """The CAN signals of ``rec`` read again block by block: ``(block, before)`` pairs, ``block`` mapping
    each signal (of ``names``, default all) to ``(t, value)`` with the clock offset ``rec`` found applied
    and owner mappings resolved as :func:`read_recording` does, ``before`` the block's last frame time
    (later blocks hold nothing earlier).  ``codec``, ``dbc`` and ``signals`` must be those ``rec`` was read
    with.  Memory is that of one block (:mod:`.chunks`).

    The survey (``rec``) already holds the capture's statistics, so the blocks are decoded without them
    (:func:`.fastdecode.decode_table` alone, the values of the wanted signals and their mapping sources
    only); ``reference`` decodes them as the survey does (:class:`.chunks.ChunkDecoder`, every signal), the
    same blocks (``tests/recording/test_reader_fast.py``)."""
    from ..bus.transport import Reassembler
    from .chunks import ChunkDecoder, open_tables
    from .fastdecode import decode_table

    root, can_path, codec, mapping = _resolve(rec.path, codec, dbc, signals)
    rs = ReadStats(source=can_path.name)
    _fmt, blocks = open_tables(can_path, rs)
    scratch = RecordingStats()
    dec = ChunkDecoder(codec, scratch)
    tp, claims = Reassembler(), {}
    off = rec.stats.clock_offset_s
    want = None if names is None else set(names)
    decode_want = None if want is None else want | {src for target, src, _ in mapping if target in want}
    for table in blocks:
        if not len(table):
            continue
        if reference:
            got = dec.decode(table)
        else:
            got = {name: (t, v, sa) for name, (_lines, t, v, sa) in decode_table(
                table, codec, scratch, MAX_EXAMPLES, tp=tp, claims=claims, want=decode_want)[1].items()}
        for target, src, scale in mapping:
            if src in got:
                t, v, sa = got[src]
                got[target] = (t, v * scale, sa)
        yield ({name: (t + off, v) for name, (t, v, _sa) in got.items() if want is None or name in want},
               float(table.t[-1]) + off)


HOLD_MAX_BYTES = 256 << 20
"""Default bound [bytes] of the decoded blocks a survey holds for one later pass (:class:`HeldBlocks`): about
7 h of ``paper-three-soils``' estimator signals (4.0 MiB per 415 s, 35 MiB per hour).  A capture whose held blocks would pass it is read again
block by block (:func:`stream_signals`), so memory stays bounded whatever the recording's length."""


class HeldBlocks:
    """The decoded CAN blocks of some signals, kept by a survey (``read_recording(..., hold=)``) for one later
    pass in place of :func:`stream_signals`' second reading and decoding of the capture.

    ``names``: the signals to hold (the owner-mapped sources of those among them are held too).
    ``max_bytes``: the bound on the held arrays' bytes; the first block that would pass it drops every held
    block (``blocks`` becomes None, ``over`` True), and the caller streams instead.  Each held block is the
    block of frames :func:`stream_signals` would decode (:mod:`.chunks`): the values of
    :meth:`.chunks.ChunkDecoder.decode`, which equal :func:`.fastdecode.decode_table`'s for the wanted
    signals (``tests/recording/test_reader_fast.py``), and the block's last frame time.
    """

    def __init__(self, names: Iterable[str], max_bytes: int = HOLD_MAX_BYTES) -> None:
        self.names = frozenset(names)
        self.max_bytes = int(max_bytes)
        self.blocks: list | None = []
        """(name -> (t, value), last frame time [s]) per block, CAN clock (no offset), before any mapping."""
        self.nbytes = 0
        self.over = False
        self.mapping: list = []
        """The resolved ``[signals]`` mapping the survey used (:func:`read_recording`)."""

    def add(self, got: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]], t_last: float,
            names: frozenset[str]) -> None:
        """One decoded block (``ChunkDecoder.decode``'s dict); ``names``: the signals held, mapped sources too."""
        if self.blocks is None:
            return
        block = {name: (t, v) for name, (t, v, _sa) in got.items() if name in names}
        seen: set[int] = set()                 # the signals of one message share their time array
        for t, v in block.values():
            self.nbytes += v.nbytes + (0 if id(t) in seen else t.nbytes)
            seen.add(id(t))
        if self.nbytes > self.max_bytes:
            self.blocks, self.over = None, True
            return
        self.blocks.append((block, t_last))


def held_signals(rec: Recording, hold: HeldBlocks, names: Sequence[str] | None = None
                 ) -> Iterator[tuple[dict[str, tuple[np.ndarray, np.ndarray]], float]]:
    """:func:`stream_signals` of ``rec`` from the blocks its survey held (``hold``, filled by
    ``read_recording(..., hold=hold)``), without reading the capture again: the same ``(block, before)`` pairs,
    array for array (``tests/recording/test_reader_fast.py``).  ``names`` (default: those held) must be
    held.  Each block is let go once handed out, so one pass is possible."""
    if hold.blocks is None:
        raise ValueError("the survey's held blocks were dropped (over their bound): stream the capture instead")
    want = set(hold.names if names is None else names)
    if not want <= hold.names:
        raise ValueError(f"not held: {', '.join(sorted(want - hold.names))}")
    decode_want = want | {src for target, src, _ in hold.mapping if target in want}
    off = rec.stats.clock_offset_s
    blocks = hold.blocks
    for i in range(len(blocks)):
        block, t_last = blocks[i]
        blocks[i] = None
        got = {name: tv for name, tv in block.items() if name in decode_want}
        for target, src, scale in hold.mapping:
            if src in got:
                t, v = got[src]
                got[target] = (t, v * scale)
        yield {name: (t + off, v) for name, (t, v) in got.items() if name in want}, t_last + off
    hold.blocks = None


def _resolve(p: Path, codec: Codec | None, dbc: Sequence[str | Path],
             signals: Mapping[str, tuple[str, float]] | None) -> tuple[Path, Path, Codec, list]:
    """(root directory, CAN capture, codec with the owner's DBCs, resolved ``[signals]`` mapping) of a
    recording path (:func:`read_recording`'s rules)."""
    if p.is_dir():
        root = p
        can_path = p / CAN_FILE
        if not can_path.exists():
            others = sorted(q for q in p.glob("can.*") if q.is_file())
            if len(others) != 1:
                raise RecordingError(f"{can_path}: missing (a recording needs {CAN_FILE}, or one can.<ext> "
                                     "capture in any format read)")
            can_path = others[0]
    else:
        root = p.parent
        can_path = p
    if dbc:
        codec = Codec(codec.path if codec is not None else None,
                      extra=[*(codec.extra_paths if codec is not None else ()), *dbc])
    codec = codec if codec is not None else default_codec()
    vehicle_toml = root / VEHICLE_FILE if p.is_dir() else None
    if signals is None and vehicle_toml is not None and vehicle_toml.is_file():
        try:
            mapping = codec.resolve_mapping(load_signal_map(vehicle_toml))
        except ConfigError as e:          # named once: load_toml's own errors already start with the path
            raise ConfigError(str(e) if str(e).startswith(str(vehicle_toml)) else f"{vehicle_toml}: {e}") from None
    else:
        mapping = codec.resolve_mapping(signals or {})
    return root, can_path, codec, mapping


def _gps_beside(p: Path) -> Path | None:
    if p.is_dir():
        return p / GPS_FILE
    own = p.with_suffix(".nmea")
    return own if own.is_file() else p.parent / GPS_FILE


# --------------------------------------------------------------------------- clocks
CLOCK_MODES = ("auto", "report", "keep")


def _reconcile_clocks(can_path: Path, decoded: dict[str, Series], track: GpsTrack, stats: RecordingStats,
                      mode: str) -> None:
    """Estimate and apply the CAN-to-GNSS clock offset when needed (module doc, "Clocks")."""
    from .clock import GOOD_OVERLAP, check_offset, estimate_offset, overlap_fraction, shift_can
    from .formats import TRUSTED_CLOCK

    if mode == "keep" or len(track) < 2 or not math.isfinite(stats.can_t_first):
        return
    c0, c1, g0, g1 = stats.can_t_first, stats.can_t_last, float(track.t[0]), float(track.t[-1])
    frac = max(overlap_fraction(c0, c1, g0, g1), overlap_fraction(g0, g1, c0, c1))   # of the shorter span
    trusted = stats.can_format in TRUSTED_CLOCK
    if trusted and frac >= GOOD_OVERLAP:
        # The spans agree, the clocks may still not: a logger's clock seconds off overlaps almost wholly.
        off = check_offset(decoded, track.t, track.speed, (c0, c1))
        if off.found:
            shift_can(decoded, stats, off.offset_s)
            stats.clock_offset_s, stats.clock_sigma_s = off.offset_s, off.sigma_s
            stats.clock_note = (f"the {stats.can_format} capture's clock and GNSS time disagree although their "
                                f"spans overlap over {frac:.0%}: {off.describe()}, applied")
        elif off.contradicted:
            stats.clock_note = f"CAN times kept: {off.reason}"
        return
    why = (f"the CAN frames ({_span(c0, c1)}) and the GNSS epochs ({_span(g0, g1)}) overlap over {frac:.0%} "
           "of the shorter"
           if frac < GOOD_OVERLAP else f"the {stats.can_format} capture has no absolute clock of its own")
    off = estimate_offset(decoded, track.t, track.speed)
    if off.found:
        shift_can(decoded, stats, off.offset_s)
        stats.clock_offset_s, stats.clock_sigma_s = off.offset_s, off.sigma_s
        stats.clock_note = f"{why}: {off.describe()}, applied"
        return
    stats.clock_note = f"{why}; {off.describe()}; CAN times kept"
    if mode == "auto" and frac <= 0.0:
        raise RecordingError(
            f"{can_path}: CAN and GNSS clocks disagree: {why}, and the offset between them could not be "
            f"found: {off.reason}. Check the logger's clock, or pass the GNSS log that belongs to this capture")


def _span(a: float, b: float) -> str:
    return f"{_when(a)} .. {_when(b)}"


def _when(t: float) -> str:
    import time
    if 0 <= t < 4e9:
        return time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(t))
    return f"{t:.3f} s"


def _keep_mapped(keep: Callable[[str, set[str]], bool] | None, mapping: Sequence[tuple[str, str, float]]
                 ) -> Callable[[str, set[str]], bool] | None:
    """``keep`` that also keeps whole the owner's signals a ``[signals]`` table maps onto a kept name: the
    mapping is applied after decoding, so a ground speed mapped from an owner's message was otherwise a stub
    (inspect's motion report read one sample of it, the clock offset none)."""
    if keep is None or not mapping:
        return keep
    targets: dict[str, list[str]] = {}
    for target, src, _ in mapping:
        targets.setdefault(src, []).append(target)

    def kept(name: str, seen: set[str]) -> bool:
        return keep(name, seen) or any(keep(t, seen) for t in targets.get(name, ()))
    return kept


# --------------------------------------------------------------------------- CAN
def _read_can(path: Path, codec: Codec, stats: RecordingStats,
              keep: Callable[[str, set[str]], bool] | None = None, hold: HeldBlocks | None = None
              ) -> dict[str, Series]:
    """Read and decode the CAN capture block by block (:mod:`.chunks`, :mod:`.fastdecode`), whatever its
    format (:mod:`.formats`).

    For candump ``-L``: the same signals, statistics and counters as :func:`read_can_per_frame`.
    ``keep(name, names seen so far)`` False makes a signal a stub (:func:`_stub`): its first and last time
    and its first number, enough to tell it present, for a survey that must not hold a long recording.
    ``hold``: the blocks to keep beside (:class:`HeldBlocks`).
    """
    from .chunks import ChunkDecoder, open_tables

    rs = ReadStats(source=path.name)
    stats.files[path.name] = rs
    stats.can_format, blocks = open_tables(path, rs)
    dec = ChunkDecoder(codec, stats, rs)
    parts: dict[str, list] = {}
    stubs: dict[str, list] = {}
    held = None if hold is None else hold.names | {src for target, src, _ in hold.mapping if target in hold.names}
    # a stub whose first number is known needs only its message's times: its values are not computed
    # (``keep`` once False for a name stays False: the survey's keeps only grow what they see)
    done: list[str] = []
    want = None
    for table in blocks:
        got = dec.decode(table, want)
        if held is not None and len(table):
            hold.add(got, float(table.t[-1]), held)
        for name in done:
            msg = dec.messages.get(codec.signals[name].message)
            if msg is not None:
                _stub_add(stubs[name], msg[1], None)
        for name, (t, v, sa) in got.items():
            if keep is not None and not keep(name, parts.keys() | stubs.keys()):
                st = stubs.get(name)
                if st is None:
                    st = stubs[name] = _stub_of(parts.get(name, []))
                    parts[name] = []             # keeps the order of first appearance
                _stub_add(st, t, v)
                if not math.isnan(st[2]) and (held is None or name not in held):
                    done.append(name)
                continue
            parts.setdefault(name, []).append((t, v, sa))
        if done and (want is None or len(done) != len(codec.signals) - len(want)):
            want = frozenset(codec.signals).difference(done)
    dec.finish()
    check_frames(path, rs, stats.can_format)
    out = {}
    for name, ps in parts.items():
        if name in stubs:
            t0, t1, v0 = stubs[name]
            out[name] = Series(np.array([t0, t1]), np.array([v0, math.nan]), np.full(2, -1, dtype=np.int16),
                               codec.signals[name].unit)
            continue
        out[name] = Series(np.concatenate([p[0] for p in ps]).astype(float, copy=False),
                           np.concatenate([p[1] for p in ps]).astype(float, copy=False),
                           np.concatenate([p[2] for p in ps]).astype(np.int16), codec.signals[name].unit)
    return out


def _stub_of(parts: list) -> list:
    st = [math.nan, math.nan, math.nan]
    for t, v, _ in parts:
        _stub_add(st, t, v)
    return st


def _stub_add(st: list, t: np.ndarray, v: np.ndarray | None) -> None:
    """A stub's first and last time and first number, with one block's samples (``v`` None: the first number
    is known already)."""
    if not t.size:
        return
    if math.isnan(st[0]):
        st[0] = float(t[0])
    st[1] = float(t[-1])
    if math.isnan(st[2]) and v is not None:
        ok = np.flatnonzero(np.isfinite(v))
        if ok.size:
            st[2] = float(v[ok[0]])


def check_frames(path: Path, rs: ReadStats, fmt: str = "candump") -> None:
    if rs.frames == 0 and rs.total_rejected == 0:
        raise RecordingError(f"{path}: empty file (no candump line)" if fmt == "candump"
                             else f"{path}: no CAN frame in this {fmt} capture")
    if rs.frames == 0 and fmt != "candump":
        raise RecordingError(f"{path}: no valid CAN frame in this {fmt} capture of {rs.lines} frames")
    if rs.frames == 0:
        first = min(
            ((lines[0], reason) for reason, lines in rs.examples.items() if lines),
            default=(None, None),
        )
        where = f", line {first[0]}: {first[1]}" if first[0] is not None else ""
        raise RecordingError(f"{path}: no valid candump frame in {rs.lines} lines{where}")


def message_times(ms: MessageStats, arr: np.ndarray) -> None:
    ms.t_first, ms.t_last = float(arr[0]), float(arr[-1])
    if arr.size >= 2:
        dt = np.diff(arr)
        ms.max_interval_s = float(dt.max())
        if ms.nominal_period_s:
            big = np.nonzero(dt > GAP_FACTOR * ms.nominal_period_s)[0]
            ms.n_gaps = int(big.size)
            ms.gaps = [(float(arr[i]), float(dt[i])) for i in big[:MAX_EXAMPLES]]

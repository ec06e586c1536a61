"""Vectorised reading and decoding of a candump ``-L`` file (what :func:`.reader.read_recording` uses).

The per-frame path — :func:`tractionecu.bus.candump.iter_candump` for the
lines and :meth:`tractionecu.bus.dbc.Codec.decode` for each frame — costs
≈ 10 µs a frame in Python; a 415 s recording has 133 000 frames.  Here the
same results come from numpy arrays:

Lines
    Lines in the canonical candump layout, ``(ssssssssss.uuuuuu) IFACE
    IIIIIIII#DDDDDDDDDDDDDDDD`` (10 + 6 timestamp digits, an 8-digit
    29-bit identifier, 8 data bytes), are checked character by character
    and converted as a block.  Every other line (blank, garbage, another
    data length, direction flags, an identifier with the error flag, ...)
    goes through the per-line classifier of :mod:`tractionecu.bus.candump`,
    so rejects are counted with the same reasons and line numbers.  The
    timestamp N·10⁻⁶ s with N the 16-digit integer is computed as N / 10⁶,
    which is the correctly rounded value of the decimal, like ``float()``.
    ``time_backwards`` is judged against the running maximum of the frames
    before, which equals the last accepted time.  A block whose lines all
    have one width (a capture of one interface holding canonical frames
    only) is not split into strings: its bytes are the rows of one matrix
    (:class:`_Uniform`), and a line is cut out of the text only when the
    per-line classifier must see it.  The check and conversion of the
    canonical lines is compiled with numba (:func:`_canonical_rows`, line by
    line, the same checks and arithmetic; 5x faster than the numpy form,
    :func:`_canonical_np`, which stays the reference, and the path taken
    until numba is loaded in the process: :func:`use_compiled`).

Frames
    Frames of a DBC message whose signals are all little-endian integers
    (every message of ``dbc/tractionecu.dbc``) and whose data length matches
    are decoded per message with the DBC's own signal definitions, read
    from the cantools database: raw = (data as little-endian uint64 >> start)
    & (2^length − 1), two's complement when signed, NaN outside the raw
    range, else raw·scale + offset (:meth:`Codec.decode`'s rule; the raw
    range is the codec's, so a J1939 parameter's error and not-available
    codes, 0xFB.. to 0xFF.., are NaN here as there).  Unknown PGNs are
    counted per PGN and source address as arrays.  Address claims, wrong
    data lengths and messages of any other layout go through
    :meth:`Codec.decode` frame by frame.

Multi-packet messages
    TP.CM / TP.DT frames (J1939-21 transport protocol) stay counted as
    unknown PGNs; the messages they carry are reassembled
    (:mod:`tractionecu.bus.transport`) and, when the DBC has their PGN,
    decoded with :meth:`Codec.decode` as one frame at the line and time of
    their last packet, from the sender's address.

The result — signals, statistics, counters and the insertion order of every
dict — equals the per-frame reader's (:func:`.reference.read_can_per_frame`);
``tests/recording`` checks that on recordings with bad lines.
"""

from __future__ import annotations

import dataclasses
import sys
import weakref
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..bus import j1939
from ..bus.candump import TIME_SPIKE_S, ReadStats, TimeRule, _classify, classify_unterminated
from ..bus.dbc import NETWORK_MANAGEMENT_PGNS, Codec
from ..bus.transport import TRANSPORT_PGNS, Reassembler, message_id
from ..errors import DecodeError, UnknownFrame
from .containers import STD_SA

CHUNK_CHARS = 1 << 20
"""Characters read at a time (whole lines are processed per chunk)."""

_HEXVAL = np.full(256, -1, dtype=np.int16)
for _i, _c in enumerate(b"0123456789"):
    _HEXVAL[_c] = _i
for _i, _c in enumerate(b"abcdef"):
    _HEXVAL[_c] = 10 + _i
    _HEXVAL[_c - 32] = 10 + _i
_POW10 = 10 ** np.arange(9, -1, -1, dtype=np.int64)
_POW10_6 = 10 ** np.arange(5, -1, -1, dtype=np.int64)
_POW16 = 16 ** np.arange(7, -1, -1, dtype=np.int64)
_MAX_EXACT = 1 << 53


@dataclass
class FrameTable:
    """Accepted frames in file order: line number, time [s], identifier, 29-bit?, data length and the
    data bytes as a little-endian integer (zero-padded to 8 bytes)."""

    lineno: np.ndarray
    t: np.ndarray
    can_id: np.ndarray
    ext: np.ndarray
    dlc: np.ndarray
    payload: np.ndarray

    def __len__(self) -> int:
        return int(self.t.size)

    def data(self, i: int) -> bytes:
        """The data bytes of frame i."""
        return int(self.payload[i]).to_bytes(8, "little")[: int(self.dlc[i])]


class _Uniform:
    """A block of lines that all have one width ``w``, kept as its text (each line followed by LF) and that
    text's ASCII bytes: ``lines[i]`` without splitting the block into strings, and the lines as the rows of
    one byte matrix without joining them again (:func:`_canonical`).  What a capture that holds only
    canonical frames of one interface is, block after block."""

    def __init__(self, text: str, raw: bytes, w: int) -> None:
        self.text, self.raw, self.w = text, raw, w
        self.n = len(text) // (w + 1)

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> str:
        a = i * (self.w + 1)
        return self.text[a:a + self.w]

    @staticmethod
    def of(body: str) -> "_Uniform | None":
        """The block ``body`` (whole lines, each ended by LF) as a :class:`_Uniform`, if its lines have one
        width and it is ASCII; else None."""
        w = body.find("\n")
        if w < 0 or len(body) % (w + 1) or not body.isascii():
            return None
        raw = body.encode("ascii")
        if not (np.frombuffer(raw, dtype=np.uint8)[w::w + 1] == 0x0A).all():
            return None
        return _Uniform(body, raw, w)


def _line_matrix(lines: list[str] | _Uniform, idx: np.ndarray, width: int) -> np.ndarray:
    """The lines ``lines[idx]`` (all of length ``width``) as the rows of a C-contiguous byte matrix of at
    least ``width`` columns (a :class:`_Uniform` block's rows keep their LF); a non-ASCII line is a row of
    NUL bytes (no canonical line)."""
    if isinstance(lines, _Uniform):                   # every line has this width: the rows of the block
        return np.frombuffer(lines.raw, dtype=np.uint8).reshape(-1, width + 1)
    cand = lines if idx.size == len(lines) else [lines[i] for i in idx]   # all lines: idx is 0..n-1
    raw = "".join(cand).encode("utf-8")
    if len(raw) != width * len(cand):                 # a non-ASCII character somewhere
        ascii_ok = np.fromiter((s.isascii() for s in cand), dtype=bool, count=len(cand))
        raw = "".join(s if a else "\x00" * width for s, a in zip(cand, ascii_ok)).encode("ascii")
    return np.frombuffer(raw, dtype=np.uint8).reshape(-1, width)


def _canonical(lines: list[str] | _Uniform, idx: np.ndarray, width: int):
    """Parse the lines ``lines[idx]`` (all of length ``width``) as canonical candump lines.

    Returns (ok mask, t, can_id, payload) for the rows, values valid where ok.  Compiled
    (:func:`_compiled_rows`) once numba is loaded, else :func:`_canonical_np`; the two take the same lines
    and give the same values bit for bit (``tests/recording/test_fastdecode_uniform.py``).
    """
    A = _line_matrix(lines, idx, width)
    rows = _compiled_rows()
    if rows is not None:
        return rows(A, width, _HEXVAL)
    return _canonical_np(A, width)


def _canonical_rows_py(A: np.ndarray, width: int, hexval: np.ndarray):
    """:func:`_canonical_np` line by line (compiled with numba as :func:`_canonical_rows`): the same checks
    (brackets, dot, blanks, hash, digits, a printable interface name, hex digits, N < 2^53, a 29-bit
    identifier) and the same arithmetic (N as an integer, t = N / 10^6, the data bytes little-endian)."""
    n = A.shape[0]
    ch = width - 46                                   # interface name length
    ok = np.zeros(n, dtype=np.bool_)
    t = np.zeros(n, dtype=np.float64)
    cid = np.zeros(n, dtype=np.int64)
    pl = np.zeros(n, dtype=np.uint64)
    for i in range(n):
        r = A[i]
        if not (r[0] == 0x28 and r[11] == 0x2E and r[18] == 0x29 and r[19] == 0x20 and r[20 + ch] == 0x20
                and r[29 + ch] == 0x23):
            continue
        good = True
        sec = 0
        for k in range(1, 11):
            d = np.int64(r[k]) - 0x30
            if d < 0 or d > 9:
                good = False
                break
            sec = sec * 10 + d
        if not good:
            continue
        usec = 0
        for k in range(12, 18):
            d = np.int64(r[k]) - 0x30
            if d < 0 or d > 9:
                good = False
                break
            usec = usec * 10 + d
        if not good:
            continue
        for k in range(20, 20 + ch):
            if r[k] < 0x21 or r[k] > 0x7E:
                good = False
                break
        if not good:
            continue
        c_id = 0
        for k in range(21 + ch, 29 + ch):
            h = np.int64(hexval[r[k]])
            if h < 0:
                good = False
                break
            c_id = c_id * 16 + h
        if not good:
            continue
        p = np.uint64(0)
        for j in range(8):
            hi = np.int64(hexval[r[30 + ch + 2 * j]])
            lo = np.int64(hexval[r[31 + ch + 2 * j]])
            if hi < 0 or lo < 0:
                good = False
                break
            p |= np.uint64(hi * 16 + lo) << np.uint64(8 * j)
        n_us = sec * 1_000_000 + usec
        if not good or n_us >= _MAX_EXACT or c_id > 0x1FFFFFFF:   # also excludes the error flag 0x20000000
            continue
        ok[i] = True
        t[i] = np.float64(n_us) / 1e6
        cid[i] = c_id
        pl[i] = p
    return ok, t, cid, pl


_canonical_rows = None
""":func:`_canonical_rows_py` compiled (numba, cached on disk), once :func:`_compiled_rows` has loaded it."""


def _compiled_rows():
    """The compiled line check, loaded on first use once numba is imported in this process (by the
    estimator's kernels, or :func:`use_compiled`); None before, so reading a recording alone does not pay
    numba's start-up (about 0.6 s; loading this kernel from the cache once numba is up: about 0.03 s)."""
    global _canonical_rows
    if _canonical_rows is None and "numba" in sys.modules:
        import numba

        _canonical_rows = numba.njit(cache=True, nogil=True)(_canonical_rows_py)
    return _canonical_rows


def use_compiled() -> bool:
    """Import numba (if installed) so that the lines are checked by the compiled kernel from now on
    (batch replay, which loads numba for its loop anyway); whether it is."""
    try:
        import numba  # noqa: F401
    except ImportError:                               # pragma: no cover - numba is a dependency
        return False
    return _compiled_rows() is not None


def _canonical_np(A: np.ndarray, width: int):
    """:func:`_canonical` over the rows of the byte matrix ``A`` in numpy (without numba; the reference of
    the compiled one)."""
    A = A[:, :width]
    ch = width - 46                                   # interface name length
    A = np.ascontiguousarray(A.T)                     # one row per character position: the checks below
    ok = ((A[0] == 0x28) & (A[11] == 0x2E) & (A[18] == 0x29) & (A[19] == 0x20)   # run along contiguous rows
          & (A[20 + ch] == 0x20) & (A[29 + ch] == 0x23))
    sec = A[1:11] - np.uint8(0x30)                    # digits map to 0..9, anything else above 9
    usec = A[12:18] - np.uint8(0x30)
    ok &= (sec.max(axis=0) <= 9) & (usec.max(axis=0) <= 9)
    name = A[20:20 + ch] - np.uint8(0x21)             # printable, no white space: 0x21..0x7E
    ok &= name.max(axis=0) <= 0x7E - 0x21
    hid = _HEXVAL[A[21 + ch:29 + ch]]
    hpl = _HEXVAL[A[30 + ch:46 + ch]]
    ok &= (hid.min(axis=0) >= 0) & (hpl.min(axis=0) >= 0)
    n_us = (_POW10 @ sec.astype(np.int64)) * 1_000_000 + _POW10_6 @ usec.astype(np.int64)
    ok &= n_us < _MAX_EXACT
    can_id = _POW16 @ hid.astype(np.int64)
    ok &= can_id <= 0x1FFFFFFF                         # also excludes the error flag 0x20000000
    byts = ((hpl[0::2] << 4) | hpl[1::2]).astype(np.uint8)          # row j: data byte j of every frame
    payload = np.ascontiguousarray(byts.T).view("<u8").reshape(-1).astype(np.uint64)
    return ok, n_us.astype(np.float64) / 1e6, can_id, payload


def _scan_lines(lines: list[str] | _Uniform, lineno0: int, state: dict, rs: ReadStats, parts: list,
                unterminated: bool = False) -> None:
    """Classify one chunk of lines (numbered from lineno0 + 1) into frames and rejects; ``unterminated``:
    the chunk is the file's last line, without a line break after it (:func:`.candump.classify_unterminated`)."""
    n = len(lines)
    rs.lines += n
    if isinstance(lines, _Uniform):                   # one width: all lines or none are candidates
        lens = None
        widths = [lines.w] if 47 <= lines.w <= 78 else []
    else:
        lens = np.fromiter(map(len, lines), dtype=np.int64, count=n)
        widths = np.unique(lens[(lens >= 47) & (lens <= 78)]).tolist()
    fast = np.zeros(n, dtype=bool)
    f_idx, f_t, f_id, f_pl = [], [], [], []
    for width in widths:
        idx = np.arange(n) if lens is None else np.flatnonzero(lens == width)
        ok, t, cid, pl = _canonical(lines, idx, width)
        if ok.any():
            idx = idx[ok]
            fast[idx] = True
            f_idx.append(idx)
            f_t.append(t[ok])
            f_id.append(cid[ok])
            f_pl.append(pl[ok])
    rejects: list[tuple[int, str]] = []
    s_idx, s_t, s_id, s_ext, s_dlc, s_pl = [], [], [], [], [], []
    for i in np.flatnonzero(~fast).tolist():
        line = lines[i]
        if not line.strip():
            continue
        reason, frame = classify_unterminated(line) if unterminated else _classify(line)
        if reason is not None:
            rejects.append((i, reason))
            continue
        assert frame is not None
        s_idx.append(i)
        s_t.append(frame.t)
        s_id.append(frame.can_id)
        s_ext.append(frame.is_extended)
        s_dlc.append(len(frame.data))
        s_pl.append(int.from_bytes(frame.data, "little"))
    if len(f_idx) == 1 and not s_idx:                 # one width, no other frame: already in line order
        idx, t, cid, pl = f_idx[0], f_t[0], f_id[0], f_pl[0]
        ext = np.ones(idx.size, dtype=bool)
        dlc = np.full(idx.size, 8, dtype=np.int64)
    else:
        idx = np.concatenate(f_idx + [np.asarray(s_idx, dtype=np.int64)])
        t = np.concatenate(f_t + [np.asarray(s_t, dtype=np.float64)])
        cid = np.concatenate(f_id + [np.asarray(s_id, dtype=np.int64)])
        ext = np.concatenate([np.ones(sum(a.size for a in f_idx), dtype=bool), np.asarray(s_ext, dtype=bool)])
        dlc = np.concatenate([np.full(sum(a.size for a in f_idx), 8, dtype=np.int64),
                              np.asarray(s_dlc, dtype=np.int64)])
        pl = np.concatenate(f_pl + [np.asarray(s_pl, dtype=np.uint64)])
        order = np.argsort(idx, kind="stable")
        idx, t, cid, ext, dlc, pl = idx[order], t[order], cid[order], ext[order], dlc[order], pl[order]
    # time going backwards: earlier than the last accepted frame = the running maximum before it
    rule: TimeRule = state["rule"]
    if (rule.held is None and rule.t_max == -np.inf and t.size >= 2 and np.isfinite(t[0])
            and not t[0] - t[1] > TIME_SPIKE_S):
        # the capture's first frame: the rule holds it (it is "ahead" of no time at all) and the next frame
        # accepts it, as here, so the block does not go frame by frame for it
        rule.t_max = float(t[0])
    prev = np.maximum.accumulate(np.concatenate([[rule.t_max], t]))[:-1]
    if rule.held is not None or (t - prev > TIME_SPIKE_S).any():
        # a frame stamped far ahead is held until the next one (candump.TimeRule): frame by frame
        keep, back, ahead, held_in = _time_order(t, state)
        idx_abs = idx + (lineno0 + 1)
        if ahead is not None:                          # the frame held from the block before, out of line
            rs.reject("time_ahead", ahead[0], ahead[1])
        rejects += [(i, "time_backwards") for i in idx[back].tolist()]
        rejects += [(int(idx[j]), "time_ahead") for j in held_in]
        if rule.held is not None and not isinstance(rule.held[0], tuple):    # held at this block's last frame
            j, th = rule.held
            rule.held = ((int(idx_abs[j]), lines[int(idx[j])], (float(t[j]), int(cid[j]), bool(ext[j]),
                                                                int(dlc[j]), int(pl[j]))), th)
        cols = [a[keep] for a in (idx_abs, t, cid, ext, dlc, pl)]
        front = state.pop("front", None)               # the frame held from the block before, accepted
        if front is not None:
            cols = [np.concatenate([np.asarray([v], dtype=c.dtype), c]) for v, c in zip(front, cols)]
        for i, reason in sorted(rejects):
            rs.reject(reason, lineno0 + i + 1, lines[i])
        rs.frames += int(cols[1].size)
        parts.append(tuple(cols))
        return
    if t.size:
        back = t < prev
        rule.t_max = max(rule.t_max, float(t.max()))
        if back.any():
            rejects += [(i, "time_backwards") for i in idx[back].tolist()]
            keep = ~back
            idx, t, cid, ext, dlc, pl = idx[keep], t[keep], cid[keep], ext[keep], dlc[keep], pl[keep]
    for i, reason in sorted(rejects):
        rs.reject(reason, lineno0 + i + 1, lines[i])
    rs.frames += int(t.size)
    parts.append((idx + (lineno0 + 1), t, cid, ext, dlc, pl))


def _time_order(t: np.ndarray, state: dict):
    """The capture's :class:`~.candump.TimeRule` (``state["rule"]``) over one block's frames ``t`` (in line
    order): (kept mask, time_backwards mask, the frame held from the block before when it was out of line (its
    line number and text), the block's positions found out of line).  The rule's keys are a frame's position in
    the block, or ``(line number, text, (t, id, ext, dlc, payload))`` for one held from the block before; such a
    frame accepted is left in ``state["front"]``."""
    keep = np.zeros(t.size, dtype=bool)
    back = np.zeros(t.size, dtype=bool)
    ahead = None
    held_in: list[int] = []
    rule: TimeRule = state["rule"]
    for j, tj in enumerate(t.tolist()):
        for key, why in rule.push(j, tj):
            if isinstance(key, tuple):                  # the frame held from the block before
                if why is None:
                    state["front"] = (key[0], *key[2])
                else:
                    ahead = (key[0], key[1])
            elif why is None:
                keep[key] = True
            elif why == "time_backwards":
                back[key] = True
            else:
                held_in.append(key)
    return keep, back, ahead, held_in


def _held_table(state: dict, rs: ReadStats) -> "FrameTable | None":
    """The frame still held at the end of the file (accepted: no frame came after it), as a table."""
    for (lineno, _text, (t, cid, ext, dlc, pl)), _why in state["rule"].end():
        rs.frames += 1
        return FrameTable(np.asarray([lineno], dtype=np.int64), np.asarray([t]), np.asarray([cid], dtype=np.int64),
                          np.asarray([ext]), np.asarray([dlc], dtype=np.int64), np.asarray([pl], dtype=np.uint64))
    return None


def empty_table() -> FrameTable:
    """A :class:`FrameTable` without frames."""
    e = np.empty(0, dtype=np.int64)
    return FrameTable(e, np.empty(0), e.copy(), np.empty(0, dtype=bool), e.copy(), np.empty(0, dtype=np.uint64))


def iter_candump_tables(path: str | Path, rs: ReadStats, chunk_chars: int = CHUNK_CHARS) -> Iterator[FrameTable]:
    """The accepted frames of a candump file, one :class:`FrameTable` per block of about ``chunk_chars``
    characters (whole lines), in file order; counted in ``rs`` as by :func:`scan_candump`.  Memory is that
    of one block, whatever the file's length.  OSError propagates."""
    state: dict = {"rule": TimeRule()}
    lineno0 = 0
    carry: list[str] = []                  # the text after the last line break, in pieces (a long line
    parts: list = []                       # is joined once, not once per block)
    with open(path, "r", encoding="utf-8-sig", errors="replace", newline=None) as fh:
        while True:
            block = fh.read(chunk_chars)
            if not block:
                break
            cut = block.rfind("\n") + 1
            if cut:
                body = "".join(carry) + block[:cut]
                carry = [block[cut:]] if cut < len(block) else []
            else:
                body = ""
                carry.append(block)
            lines = _Uniform.of(body) or (body[:-1].split("\n") if body else [])
            _scan_lines(lines, lineno0, state, rs, parts)
            lineno0 += len(lines)
            yield FrameTable(*parts.pop())
    if carry:
        _scan_lines(["".join(carry)], lineno0, state, rs, parts, unterminated=True)
        yield FrameTable(*parts.pop())
    last = _held_table(state, rs)
    if last is not None:
        yield last


def scan_candump(path: str | Path, rs: ReadStats) -> FrameTable:
    """All accepted frames of a candump file; lines, frames and rejects counted in ``rs`` exactly as
    :func:`~tractionecu.bus.candump.read_candump` counts them.  OSError propagates."""
    parts = list(iter_candump_tables(path, rs))
    if not parts:
        return empty_table()
    return FrameTable(*[np.concatenate(c) for c in zip(*(dataclasses.astuple(p) for p in parts))])


# --------------------------------------------------------------------------- decoding
_LAYOUTS: "weakref.WeakKeyDictionary[Codec, dict[str, Any]]" = weakref.WeakKeyDictionary()
""":func:`_vector_layout` per codec and message, found once (a codec's messages do not change)."""


def _vector_layout(codec: Codec, name: str) -> list[tuple[str, int, int, bool]] | None:
    """[(signal, start bit, length, signed)] in the order Codec.decode returns them, if every signal of
    the message is a little-endian integer (and the message is not multiplexed); else None."""
    known = _LAYOUTS.get(codec)
    if known is None:
        known = _LAYOUTS[codec] = {}
    if name not in known:
        known[name] = _find_layout(codec, name)
    return known[name]


def _find_layout(codec: Codec, name: str) -> list[tuple[str, int, int, bool]] | None:
    msg = codec._cmsg[name]  # type: ignore[attr-defined]
    if msg.length > 8 or msg.is_multiplexed():
        return None
    sigs = {s.name: s for s in msg.signals}
    if any(s.byte_order != "little_endian" or s.is_float or s.length > 64 for s in sigs.values()):
        return None
    info = codec.messages[name]
    _, values = (codec.decode(info.pgn << 8, bytes(msg.length), True) if info.std_id is None
                 else codec.decode(info.std_id, bytes(msg.length), False))
    dbc = {k: sigs[codec.signals[k].dbc_name] for k in values}
    return [(k, dbc[k].start, dbc[k].length, dbc[k].is_signed) for k in values]


def _signal_values(payload: np.ndarray, start: int, length: int, signed: bool, info) -> np.ndarray:
    raw = payload >> np.uint64(start)
    if length < 64:
        raw = raw & np.uint64((1 << length) - 1)
    r = raw.astype(np.int64) if length < 64 or signed else raw
    if signed and length < 64:
        r = np.where(r >= (1 << (length - 1)), r - (1 << length), r)
    bad = (r < info.raw_min) | (r > info.raw_max)
    with np.errstate(invalid="ignore"):
        v = r.astype(np.float64) * info.scale + info.offset
    v[bad] = np.nan
    return v


def decode_table(table: FrameTable, codec: Codec, stats, max_examples: int, *, tp: Reassembler | None = None,
                 claims: dict | None = None, want: set[str] | frozenset[str] | None = None) -> tuple[dict, dict, dict]:
    """Decode the frames of ``table`` as the per-frame reader does; fills ``stats``.

    Returns (messages, signals, claims): ``messages[name] = (lineno, t, sa)`` of
    the decoded frames of each message, ``signals[name] = (lineno, t, value,
    sa)``, ``claims[(sa, NAME)] = [first t, count, first line, Name]``.

    A table read in blocks is decoded block after block with the same ``tp``
    (multi-packet messages that span two blocks) and ``claims`` (added to);
    ``stats.can_t_first``/``can_t_last`` are those of this table.  ``want``: compute the values of these
    signals only (the others are left out of ``signals``; messages, statistics and claims are unchanged).
    """
    n = len(table)
    if n:
        stats.can_t_first = float(table.t[0])
        stats.can_t_last = float(table.t[-1])
    ext = table.ext
    cid = table.can_id
    pgn = j1939.pgn_of(cid)
    sa = np.where(ext, cid & 0xFF, STD_SA)                  # an 11-bit frame has no source address
    known = {p: codec.message_for_pgn(p) for p in np.unique(pgn[ext]).tolist()}
    std = np.flatnonzero(~ext)
    std_known = {}                                         # the owner's messages on 11-bit identifiers
    if std.size and codec.has_std_ids:
        std_known = {i: info for i in np.unique(cid[std]).tolist()
                     if (info := codec.message_for_std_id(i)) is not None}
    n_std = int(std.size) - (int(np.isin(cid[std], list(std_known)).sum()) if std_known else 0)
    stats.non_extended_frames += n_std
    msg_parts: dict[str, list] = {}                    # name -> [(rows, values dict | None)]
    sig_out: dict[str, list] = {}
    unknown_first: dict[int, int] = {}
    claims = {} if claims is None else claims
    per_frame: list[int] = []
    # address claims (listed whatever their decode gives)
    for i in np.flatnonzero(ext & (pgn == j1939.PGN_ADDRESS_CLAIMED) & (table.dlc == 8)).tolist():
        name = j1939.Name.from_bytes(table.data(i))
        key = (int(sa[i]), name.to_int())
        if key in claims:
            claims[key][1] += 1
        else:
            claims[key] = [float(table.t[i]), 1, int(table.lineno[i]), name]
    groups = [(p, info, None) for p, info in known.items()] + [(None, info, i) for i, info in std_known.items()]
    for p, info, std_id in groups:
        rows = np.flatnonzero(ext & (pgn == p)) if std_id is None else std[cid[std] == std_id]
        if info is None:
            unknown_first[p] = int(rows[0])
            stats.unknown_pgns[p] += int(rows.size)
            continue
        layout = _vector_layout(codec, info.name)
        good = table.dlc[rows] == info.length
        if layout is None:
            per_frame += rows.tolist()
            continue
        per_frame += rows[~good].tolist()
        rows = rows[good]
        if rows.size == 0:
            continue
        vals = None
        if p not in NETWORK_MANAGEMENT_PGNS:
            pl = table.payload[rows]
            vals = {s: _signal_values(pl, st, ln, sg, codec.signals[s]) for s, st, ln, sg in layout
                    if want is None or s in want}
        msg_parts.setdefault(info.name, []).append((rows, vals))
    # unknown PGNs and their sources, in order of first appearance
    for p in sorted(unknown_first, key=unknown_first.__getitem__):
        rows = np.flatnonzero(ext & (pgn == p))
        stats.add_unknown_sources(p, np.unique(sa[rows]).tolist())
    counts = stats.unknown_pgns
    stats.unknown_pgns = Counter({p: counts[p] for p in sorted(counts, key=lambda q: unknown_first.get(q, -1))})
    # frames that need Codec.decode: wrong length (counted) or a layout not handled above, and the
    # multi-packet messages of known PGNs, each after its last TP.DT frame
    items = [(i, 0, int(cid[i]), table.data(i)) for i in per_frame]
    tp = Reassembler() if tp is None else tp
    for i in np.flatnonzero(ext & np.isin(pgn, list(TRANSPORT_PGNS)) & (table.dlc == 8)).tolist():
        done = tp.feed(int(cid[i]), table.data(i))
        if done is not None and codec.message_for_pgn(done[0]) is not None:
            items.append((i, 1, message_id(done[0], done[1]), done[2]))
    for i, _, can_id, data in sorted(items, key=lambda x: x[:2]):
        is_ext = bool(ext[i])
        p = j1939.pgn_of(can_id) if is_ext else None
        try:
            msg, values = codec.decode(can_id, data, is_ext)
        except UnknownFrame:                            # pragma: no cover - PGN known above
            stats.unknown_pgns[p] += 1
            stats.add_unknown_sources(p, (int(sa[i]),))
            continue
        except DecodeError:
            info = codec.message_for_pgn(p) if is_ext else codec.message_for_std_id(can_id)
            key_name = info.name if info is not None else f"PGN {p}"
            stats.decode_errors[key_name] += 1
            ex = stats.decode_error_lines.setdefault(key_name, [])
            if len(ex) < max_examples:
                ex.append(int(table.lineno[i]))
            continue
        rows = np.array([i])
        vals = None if p in NETWORK_MANAGEMENT_PGNS else {k: np.array([v], dtype=float) for k, v in values.items()
                                                          if want is None or k in want}
        msg_parts.setdefault(msg, []).append((rows, vals))
    # per message: rows in file order; messages in order of their first frame
    messages: dict[str, tuple] = {}
    signals: dict[str, tuple] = {}
    firsts = {name: min(int(r[0]) for r, _ in parts) for name, parts in msg_parts.items()}
    for name in sorted(msg_parts, key=firsts.__getitem__):
        parts = msg_parts[name]
        if len(parts) == 1:                             # one part: its rows are in file order already
            rows, order = parts[0][0], None
        else:
            rows = np.concatenate([r for r, _ in parts])
            order = np.argsort(rows, kind="stable")
            rows = rows[order]
        lines_r, t_r, sa_r = messages[name] = (table.lineno[rows], table.t[rows], sa[rows])
        if parts[0][1] is None:
            continue
        keep = one_source(stats, name, sa_r)
        if keep is not None:
            lines_r, t_r, sa_r = lines_r[keep], t_r[keep], sa_r[keep]
        for sig in parts[0][1]:                         # a message's signals share its line, time, source
            v = parts[0][1][sig] if order is None else np.concatenate([vals[sig] for _, vals in parts])[order]
            signals[sig] = (lines_r, t_r, v if keep is None else v[keep], sa_r)
    return messages, signals, claims


def one_source(stats: Any, message: str, sa: np.ndarray) -> np.ndarray | None:
    """The frames of ``message`` (source addresses ``sa``, in file order) whose signals are used: those of
    ``stats.source_used[message]``, the first source seen (set here); the others are counted in
    ``stats.other_sources``.  None when every frame is of that source (the common case)."""
    if not sa.size:
        return None
    used = stats.source_used.setdefault(message, int(sa[0]))
    keep = sa == used
    if keep.all():
        return None
    other = stats.other_sources.setdefault(message, Counter())
    vals, counts = np.unique(sa[~keep], return_counts=True)
    for a, c in zip(vals.tolist(), counts.tolist()):
        other[int(a)] += int(c)
    return keep

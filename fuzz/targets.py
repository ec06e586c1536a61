"""Fuzz targets: one class per input path.

Each target draws *cases* from its seeds with :meth:`Target.generate`, runs
one through the project code with :meth:`Target.run` (returning how many
inputs the case held) and counts outcomes in :attr:`Target.counts`:

- ``ok...`` / ``accepted...``: the input was used;
- ``reject:<reason>``: the input was refused the documented way (a
  ``tractionecu.errors`` exception, or skipped and counted by the reader
  under ``<reason>``).

Anything else raised escapes :meth:`run` and is an *unhandled exception*
for the runner.  A broken output contract that is not an exception (a
decoded value outside its DBC range, a ConfigError that does not name the
key, a config value of the wrong type accepted) raises
:class:`ContractViolation`, reported beside the unhandled exceptions.

Cases serialise to JSON (:meth:`Target.dump` / :meth:`Target.load`) so a
failing one can be stored under ``tests/data/fuzz`` and replayed.

The targets stay in one module (over 500 lines): they share the case
format, the outcome counting and the contract checks of :class:`Target`,
and :data:`TARGETS` is the one registry the runner, the minimiser, the
atheris harness and the CI short form read.
"""

from __future__ import annotations

import base64
import csv
import fnmatch
import io
import math
import random
import re
import tomllib
import warnings
from collections import Counter
from dataclasses import fields
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from .corpus import Seeds
from .mutate import INTERESTING_INTS, Mutator, ubx_frame


class ContractViolation(Exception):
    """The code returned normally (or raised a project error) but broke its documented contract."""


_PRINTABLE = frozenset(range(0x20, 0x7F)) | {0x09, 0x0A, 0x0D}


def _b64(b: bytes) -> str:
    """Bytes as JSON text: the text itself if it is printable ASCII, else ``b64:`` + base64."""
    if all(c in _PRINTABLE for c in b) and not b.startswith(b"b64:"):
        return b.decode("ascii")
    return "b64:" + base64.b64encode(b).decode("ascii")


def _unb64(s: str) -> bytes:
    if s.startswith("b64:"):
        return base64.b64decode(s[4:].encode("ascii"))
    return s.encode("ascii")


class Target:
    """Base class: ``generate`` a case, ``run`` it, ``dump``/``load`` it."""

    name = "?"
    unit = "inputs"

    def __init__(self, seeds: Seeds, rng: random.Random, workdir: Path) -> None:
        self.seeds = seeds
        self.rng = rng
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.counts: Counter[str] = Counter()
        self.extra: Counter[str] = Counter()
        """Secondary counters (e.g. the service's own statistics), printed apart from the rejects."""

    def generate(self) -> dict[str, Any]:
        raise NotImplementedError

    def run(self, case: dict[str, Any]) -> int:
        raise NotImplementedError

    def size(self, case: dict[str, Any]) -> int:
        """Number of inputs in a case (used when run() raised)."""
        return 1

    def dump(self, case: dict[str, Any]) -> dict[str, Any]:
        return case

    def load(self, data: dict[str, Any]) -> dict[str, Any]:
        return data


# =========================================================================== CAN
class CanTarget(Target):
    """CAN frames: ``Codec.decode`` on every frame, then the service's own
    frame handler (``FrameDispatcher.on_frame``: filters, address claim, decode,
    step assembler) and estimator steps on the 100 Hz grid."""

    name = "can"
    unit = "frames"

    def __init__(self, seeds: Seeds, rng: random.Random, workdir: Path) -> None:
        super().__init__(seeds, rng, workdir)
        from tractionecu.bus.dbc import default_codec

        self.codec = default_codec()
        self.pgns = self.codec.pgns()
        self.mut = Mutator(rng, [d for _, _, d in seeds.can_frames])
        self.bounds = {n: (s.minimum, s.maximum) for n, s in self.codec.signals.items()}
        self.t = 1783670400.0
        self.svc: Any = None
        self.cases_on_service = 0
        self.grid_t: float | None = None

    # ------------------------------------------------------------ service
    def _new_service(self) -> Any:
        from tractionecu.service.clock import ServiceClock
        from tractionecu.service.config import ServiceConfig, with_overrides
        from tractionecu.service.daemon import Service

        cfg = with_overrides(ServiceConfig(), gps={"source": "none"}, map={"enabled": False},
                             can={"interface": "virtual", "channel": "fuzz"})
        clock = ServiceClock(epoch0=self.t, monotonic=lambda: self.t)
        svc = Service(cfg, clock=clock, codec=self.codec, env={})
        svc.estimation.build_estimator()
        if svc.network.claimer is not None:
            svc.network.claimer.start(self.t)
        return svc

    # ------------------------------------------------------------ cases
    def _frame(self) -> list:
        rng, mut = self.rng, self.mut
        r = rng.random()
        ext, flags = True, ""
        if r < 0.45:  # a seed frame, mutated
            cid, ext, data = rng.choice(self.seeds.can_frames)
            for _ in range(rng.randint(1, 3)):
                op = rng.randrange(8)
                if op == 0:
                    cid = (cid & ~0xFF) | rng.randrange(256)  # other source address
                elif op == 1:
                    cid ^= 1 << rng.randrange(29)
                elif op == 2:
                    data = mut.mutate_bytes(data)
                elif op == 3:
                    data = rng.randbytes(rng.choice((0, 1, 7, 8, 8, 8, 9, 12, 16, 64)))
                elif op == 4:
                    data = bytes([rng.choice((0x00, 0xFF, 0x7F, 0x80, 0xFE, 0x01))]) * len(data or b"\0" * 8)
                elif op == 5:
                    data = bytes(b if rng.random() < 0.7 else rng.choice((0, 0xFF, 0x7F, 0x80)) for b in data)
                elif op == 6:
                    pgn = rng.choice(self.pgns)
                    cid = (rng.randrange(8) << 26) | (pgn << 8) | rng.randrange(256)
                else:
                    ext = not ext if rng.random() < 0.1 else ext
        elif r < 0.75:  # a DBC PGN, any SA/priority/DA, random data (mostly DLC 8)
            pgn = rng.choice(self.pgns)
            ps = rng.randrange(256) if (pgn >> 8) & 0xFF < 240 else 0
            cid = (rng.randrange(8) << 26) | ((pgn | ps) << 8) | rng.randrange(256)
            n = 8 if rng.random() < 0.85 else rng.randint(0, 64)
            data = rng.randbytes(n)
        elif r < 0.85:  # network management: Address Claimed / Request
            pgn = rng.choice((60928, 59904))
            cid = (6 << 26) | ((pgn | rng.choice((0xFF, 0x90, rng.randrange(256)))) << 8) | rng.choice((0xFE, 0x90, rng.randrange(256)))
            n = rng.choice((0, 2, 3, 3, 7, 8, 8, 8, 9))
            data = rng.randbytes(n) if rng.random() < 0.7 else bytes([0x00, 0xEE, 0x00])[:n] + rng.randbytes(max(0, n - 3))
        else:  # anything: random ID of any width, random DLC up to 64
            if rng.random() < 0.2:
                cid = rng.choice(INTERESTING_INTS)
            else:
                cid = rng.getrandbits(rng.choice((11, 29, 29, 32)))
            ext = rng.random() < 0.8
            data = rng.randbytes(rng.choice((0, 8, rng.randint(0, 64))))
        f = rng.random()
        if f < 0.03:
            flags = "E"
        elif f < 0.05:
            flags = "R"
        elif f < 0.07:
            flags = "F"
        return [int(cid), bool(ext), bytes(data), flags]

    def generate(self) -> dict[str, Any]:
        return {"frames": [self._frame() for _ in range(self.rng.randint(1, 32))]}

    def size(self, case: dict[str, Any]) -> int:
        return len(case["frames"])

    def dump(self, case: dict[str, Any]) -> dict[str, Any]:
        return {"frames": [[c, e, d.hex(), f] for c, e, d, f in case["frames"]]}

    def load(self, data: dict[str, Any]) -> dict[str, Any]:
        return {"frames": [[int(c), bool(e), bytes.fromhex(d), f] for c, e, d, f in data["frames"]]}

    # ------------------------------------------------------------ run
    def _decode(self, cid: int, ext: bool, data: bytes) -> None:
        from tractionecu.errors import DecodeError, UnknownFrame

        try:
            name, values = self.codec.decode(cid, data, ext)
        except UnknownFrame:
            self.counts["reject:unknown_pgn" if ext else "reject:11bit_frame"] += 1
            return
        except DecodeError as e:
            msg = str(e)
            self.counts["reject:wrong_dlc" if "DLC" in msg else "reject:bad_id" if "29-bit" in msg else "reject:decode"] += 1
            return
        for sig, v in values.items():
            lo, hi = self.bounds[sig]
            if not isinstance(v, float) or not (math.isnan(v) or lo - 1e-9 * abs(lo) - 1e-12 <= v <= hi + 1e-9 * abs(hi) + 1e-12):
                raise ContractViolation(f"{name}.{sig} = {v!r} outside [{lo}, {hi}] and not NaN")
        self.counts["ok:decoded"] += 1

    def run(self, case: dict[str, Any]) -> int:
        import can

        if self.svc is None or self.cases_on_service >= 2000:
            if self.svc is not None:
                self._collect()
            self.svc = self._new_service()
            self.cases_on_service = 0
            self.grid_t = None
        self.cases_on_service += 1
        svc = self.svc
        for cid, ext, data, flags in case["frames"]:
            self._decode(cid, ext, data)
            self.t += 0.001
            msg = can.Message(timestamp=self.t, arbitration_id=cid, is_extended_id=ext, data=data,
                              is_error_frame="E" in flags, is_remote_frame="R" in flags, is_fd="F" in flags,
                              check=False)
            svc.dispatcher.on_frame(self.t, msg)
            if svc.steps.anchor is not None:  # the 100 Hz estimation grid, as the daemon's loop runs it
                if self.grid_t is None:
                    self.grid_t = svc.steps.anchor
                while self.grid_t <= self.t:
                    with warnings.catch_warnings(record=True) as caught:
                        warnings.simplefilter("always")
                        svc.estimation.step(self.grid_t)
                    for w in caught:  # counted, not raised: the daemon runs with default warning filters
                        self.extra[f"estimator_warning.{w.category.__name__}: {str(w.message)[:60]}"] += 1
                    self.grid_t += 0.01
        return len(case["frames"])

    def finish(self) -> None:
        """Fold the last service's statistics into :attr:`extra`."""
        if self.svc is not None:
            self._collect()
            self.svc = None

    def _collect(self) -> None:
        svc = self.svc
        for k, v in svc.stats.items():
            if not k.startswith("rx_"):
                self.extra["service." + k] += v
        if svc.network.claimer is not None:
            for k, v in svc.network.claimer.counts.items():
                self.extra["address_claim." + k] += v


# =========================================================================== NMEA
_NMEA_TYPES = ("GGA", "RMC", "VTG", "GNS", "ZDA", "GSA", "GSV", "TXT", "GLL")
_TALKERS = ("GN", "GP", "GL", "GA", "GB", "GQ", "P", "XX", "")


def nmea_checksum(body: bytes) -> bytes:
    c = 0
    for ch in body:
        c ^= ch
    return f"{c:02X}".encode()


class NmeaLines:
    """Format-aware NMEA line mutations (shared by the NMEA and recording targets)."""

    def __init__(self, seeds: Seeds, rng: random.Random) -> None:
        self.rng = rng
        self.seeds = [s.encode("ascii", "replace") for s in seeds.nmea_lines]
        self.mut = Mutator(rng, self.seeds)

    def field_mutation(self, line: bytes) -> bytes:
        """Change fields of a sentence and write a correct checksum again."""
        rng, mut = self.rng, self.mut
        body = line[1:].split(b"*")[0] if line.startswith((b"$", b"!")) else line
        parts = body.split(b",")
        for _ in range(rng.randint(1, 3)):
            op = rng.randrange(6)
            i = rng.randrange(len(parts))
            if op <= 2:
                parts[i] = mut.number_text().encode("utf-8", "replace") if rng.random() < 0.7 else mut.token().encode("utf-8", "replace")
            elif op == 3:
                del parts[i]
                if not parts:
                    parts = [b""]
            elif op == 4:
                parts.insert(i, parts[i])
            else:
                parts[i] = mut.mutate_bytes(parts[i], 2)
        body = b",".join(parts)
        return b"$" + body + b"*" + nmea_checksum(body)

    def synthetic(self) -> bytes:
        """A sentence of a random type with random fields and a correct checksum."""
        rng, mut = self.rng, self.mut
        head = (rng.choice(_TALKERS) + rng.choice(_NMEA_TYPES)).encode()
        fields_ = [mut.number_text().encode("utf-8", "replace") if rng.random() < 0.6 else b"" for _ in range(rng.randint(0, 16))]
        body = b",".join([head] + fields_)
        return b"$" + body + b"*" + nmea_checksum(body)

    def line(self) -> bytes:
        """One line (without terminator)."""
        rng = self.rng
        seed = rng.choice(self.seeds)
        r = rng.random()
        if r < 0.10:
            return seed
        if r < 0.50:
            return self.field_mutation(seed)
        if r < 0.72:
            return self.mut.mutate_bytes(seed)
        if r < 0.82:
            return self.synthetic()
        if r < 0.90:
            return self.mut.random_bytes() if rng.random() < 0.6 else ubx_frame(rng)
        if r < 0.98:
            return seed[: rng.randrange(len(seed) + 1)]  # cut mid-line
        if r < 0.995:
            return seed * rng.randint(2, 200)  # several sentences glued together
        return seed + b"," * rng.randint(0, 1) + bytes([rng.randrange(32, 127)]) * rng.randint(1000, 200_000)


class NmeaTarget(Target):
    """NMEA lines: ``parse_line`` (strict, pynmea2 check=True), the
    ``EpochAssembler`` and ``align_gps`` of the recording reader, and the
    service's byte stream (``NmeaStream.feed``: UBX mixed in, lines cut,
    overlong lines)."""

    name = "nmea"
    unit = "lines"

    def __init__(self, seeds: Seeds, rng: random.Random, workdir: Path) -> None:
        super().__init__(seeds, rng, workdir)
        self.gen = NmeaLines(seeds, rng)
        self.t_arrival = 1783670400.0

    def generate(self) -> dict[str, Any]:
        rng = self.rng
        lines = [self.gen.line() for _ in range(rng.randint(1, 16))]
        terms = [rng.choice((b"\r\n", b"\r\n", b"\r\n", b"\n", b"", b"\r")) for _ in lines]
        can_t0 = rng.choice((1783670400.0, 1783670400.0, 0.0, 86399.5, 1e9, 253402300799.0, 1e12, 1e300, rng.uniform(0, 4e9)))
        return {"lines": lines, "terms": terms, "can_t0": can_t0}

    def size(self, case: dict[str, Any]) -> int:
        return len(case["lines"])

    def dump(self, case: dict[str, Any]) -> dict[str, Any]:
        return {"lines": [_b64(x) for x in case["lines"]], "terms": [_b64(x) for x in case["terms"]], "can_t0": case["can_t0"]}

    def load(self, data: dict[str, Any]) -> dict[str, Any]:
        return {"lines": [_unb64(x) for x in data["lines"]], "terms": [_unb64(x) for x in data["terms"]], "can_t0": data["can_t0"]}

    def run(self, case: dict[str, Any]) -> int:
        from tractionecu.errors import DecodeError, RecordingError
        from tractionecu.gnss.nmea import EpochAssembler, NmeaStats, parse_line
        from tractionecu.recording.gps import align_gps
        from tractionecu.service.config import GpsConfig
        from tractionecu.service.gps import NmeaStream

        asm = EpochAssembler()
        fixes = []
        samples: list = []
        stream = NmeaStream(GpsConfig(), samples.append)
        for lineno, (raw, term) in enumerate(zip(case["lines"], case["terms"]), start=1):
            text = raw.decode("ascii", "replace")  # as read_nmea / the reader open the file
            try:
                rec = parse_line(text)
            except DecodeError as e:
                reason = getattr(e, "reason", None)
                if reason is None:
                    raise ContractViolation(f"DecodeError without a reason: {e}") from None
                self.counts["reject:" + reason] += 1
                rec = None
            else:
                if rec is None:
                    self.counts["ok:ignored_type" if text.strip() else "ok:blank"] += 1
                else:
                    self.counts["ok:" + rec.sentence] += 1
                    self._check_record(rec)
                    done = asm.push(lineno, rec)
                    if done is not None:
                        fixes.append(done)
            self.t_arrival += 0.1 if self.rng.random() < 0.95 else self.rng.uniform(-5, 5)
            stream.feed(raw + term, self.t_arrival)
        last = asm.flush()
        if last is not None:
            fixes.append(last)
        stream.feed(b"\r\n", self.t_arrival)
        for k, v in stream.stats.items():
            self.extra["service.gps." + k] += v
        self.extra["epochs"] += len(fixes)
        ns = NmeaStats()
        try:
            track, _ = align_gps(fixes, case["can_t0"], ns)
        except RecordingError:
            self.extra["align_gps.recording_error"] += 1
        else:
            self.extra["align_gps.epochs"] += len(track)
        return len(case["lines"])

    @staticmethod
    def _check_record(rec: Any) -> None:
        for f in fields(rec):
            v = getattr(rec, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise ContractViolation(f"{rec.sentence}.{f.name} = {v!r} is not finite")
        if rec.lat_deg is not None and not -90.0 <= rec.lat_deg <= 90.0:
            raise ContractViolation(f"{rec.sentence}.lat_deg = {rec.lat_deg}")
        if rec.lon_deg is not None and not -180.0 <= rec.lon_deg <= 180.0:
            raise ContractViolation(f"{rec.sentence}.lon_deg = {rec.lon_deg}")
        if rec.tod_s is not None and not 0.0 <= rec.tod_s < 86401.0:
            raise ContractViolation(f"{rec.sentence}.tod_s = {rec.tod_s}")


# =========================================================================== candump recordings
class CandumpTarget(Target):
    """Whole recording directories: ``can.log`` of mutated candump lines and
    (mostly) a ``gps.nmea`` of mutated sentences, through ``read_recording``
    and the ``inspect`` summary."""

    name = "candump"
    unit = "lines"

    def __init__(self, seeds: Seeds, rng: random.Random, workdir: Path) -> None:
        super().__init__(seeds, rng, workdir)
        from tractionecu.bus.dbc import default_codec

        self.codec = default_codec()
        self.lines = [s.encode("ascii", "replace") for s in seeds.candump_lines]
        self.mut = Mutator(rng, self.lines)
        self.nmea = NmeaLines(seeds, rng)
        self.dir = self.workdir / "rec"
        self.dir.mkdir(parents=True, exist_ok=True)

    def _field_mutation(self, line: bytes) -> bytes:
        rng, mut = self.rng, self.mut
        parts = line.split(b" ")
        if len(parts) < 3:
            return mut.mutate_bytes(line)
        ts, iface, frame = parts[0], parts[1], b" ".join(parts[2:])
        ident, _, payload = frame.partition(b"#")
        op = rng.randrange(7)
        if op == 0:
            ts = b"(" + mut.number_text().encode("utf-8", "replace") + b")"
        elif op == 1:
            ident = rng.choice((b"%08X" % rng.getrandbits(32), b"%03X" % rng.getrandbits(12), b"%X" % rng.getrandbits(rng.randint(1, 40))))
        elif op == 2:
            payload = rng.randbytes(rng.randint(0, 12)).hex().upper().encode()
        elif op == 3:
            payload = payload[: rng.randrange(len(payload) + 1)]
        elif op == 4:
            iface = rng.choice((b"", b"vcan0", b"can0\tx", mut.token().encode("utf-8", "replace")))
        elif op == 5:
            payload = rng.choice((b"#", b"R", b"#1" + payload, b"R8", b".".join(payload[i:i + 2] for i in range(0, len(payload), 2))))
        else:
            frame = frame + rng.choice((b" T", b" R", b" X", b" T R"))
            return b" ".join((ts, iface, frame))
        return ts + b" " + iface + b" " + ident + b"#" + payload

    def _can_lines(self) -> list[bytes]:
        rng = self.rng
        n = rng.choice((1, 2, 5, 50, 100, 100, 200, 300))
        start = rng.randrange(len(self.lines))
        p = rng.choice((0.02, 0.1, 0.3, 1.0))
        out = []
        for k in range(n):
            line = self.lines[(start + k) % len(self.lines)]
            if rng.random() < p:
                line = self._field_mutation(line) if rng.random() < 0.5 else self.mut.mutate_bytes(line)
            out.append(line)
        if rng.random() < 0.01:
            out.insert(rng.randrange(len(out) + 1), b"(" * rng.randint(1000, 300_000))
        return out

    def _gps_lines(self) -> list[bytes] | None:
        rng = self.rng
        if rng.random() < 0.35:
            return None
        seeds = self.nmea.seeds
        n = rng.choice((0, 1, 3, 30, 60, 90))
        start = rng.randrange(len(seeds))
        p = rng.choice((0.0, 0.05, 0.2, 1.0))
        drop_rmc = rng.random() < 0.3
        out = []
        for k in range(n):
            line = seeds[(start + k) % len(seeds)]
            if drop_rmc and b"RMC" in line[:7]:
                continue
            if rng.random() < p:
                line = self.nmea.line()
            out.append(line)
        return out

    def generate(self) -> dict[str, Any]:
        rng = self.rng
        nl = rng.choice((b"\n", b"\n", b"\r\n", b"\r"))
        can_log = nl.join(self._can_lines()) + (nl if rng.random() < 0.9 else b"")
        gps = self._gps_lines()
        return {"can.log": can_log, "gps.nmea": None if gps is None else nl.join(gps) + nl}

    def size(self, case: dict[str, Any]) -> int:
        n = case["can.log"].count(b"\n") or 1
        if case["gps.nmea"] is not None:
            n += case["gps.nmea"].count(b"\n")
        return n

    def dump(self, case: dict[str, Any]) -> dict[str, Any]:
        return {k: None if v is None else _b64(v) for k, v in case.items()}

    def load(self, data: dict[str, Any]) -> dict[str, Any]:
        return {k: None if v is None else _unb64(v) for k, v in data.items()}

    def run(self, case: dict[str, Any]) -> int:
        from tractionecu.errors import RecordingError
        from tractionecu.recording.reader import read_recording
        from tractionecu.recording.summary import summarize

        (self.dir / "can.log").write_bytes(case["can.log"])
        gps = self.dir / "gps.nmea"
        if case["gps.nmea"] is None:
            gps.unlink(missing_ok=True)
        else:
            gps.write_bytes(case["gps.nmea"])
        try:
            rec = read_recording(self.dir, self.codec)
        except RecordingError as e:
            self.counts["reject:file:" + _file_reason(str(e))] += 1
            return self.size(case)
        st = rec.stats
        can = st.files.get("can.log")
        self.counts["ok:frames"] += getattr(can, "frames", 0)
        for reason, n in getattr(can, "rejected", {}).items():
            self.counts["reject:candump:" + reason] += n
        self.counts["reject:frame:unknown_pgn"] += st.unknown_frames
        self.counts["reject:frame:wrong_dlc"] += sum(st.decode_errors.values())
        self.counts["reject:frame:11bit"] += st.non_extended_frames
        ns = st.files.get("gps.nmea")
        if ns is not None:
            self.counts["ok:nmea_sentences"] += ns.accepted
            for reason, n in ns.rejected.items():
                self.counts["reject:nmea:" + reason] += n
        self.extra["gps_epochs"] += len(rec.gps)
        summarize(rec)
        return self.size(case)


def _file_reason(msg: str) -> str:
    for key, reason in (("empty file", "empty"), ("no valid candump frame", "no_valid_frame"),
                        ("no date", "gps_no_date"), ("no data rows", "no_data_rows"),
                        ("no time column", "no_time_column"), ("none of the mapped columns", "no_mapped_column"),
                        ("not a PolyCAN export", "not_polycan"), ("cannot read", "unreadable"),
                        ("data bytes", "dlc_gt_8"), ("line", "bad_row")):
        if key in msg:
            return reason
    return "other"


# =========================================================================== CSV
class CsvTarget(Target):
    """Decoded-signal CSV exports (``import_csv`` with the contract and the
    J1939-logger mappings) and PolyCAN exports (``polycan_to_candump``, then
    read back with ``read_candump``)."""

    name = "csv"
    unit = "lines"

    def __init__(self, seeds: Seeds, rng: random.Random, workdir: Path) -> None:
        super().__init__(seeds, rng, workdir)
        self.mut = Mutator(rng, [",".join(r).encode() for r in seeds.csv_contract_rows[:50] + seeds.polycan_rows[:50]])
        self.path = self.workdir / "in.csv"
        self.out = self.workdir / "out.log"

    def _row(self, row: list[str]) -> list[str]:
        rng, mut = self.rng, self.mut
        row = list(row)
        for _ in range(rng.randint(1, 3)):
            op = rng.randrange(6)
            i = rng.randrange(len(row)) if row else 0
            if op <= 2 and row:
                row[i] = mut.number_text() if rng.random() < 0.7 else mut.token()
            elif op == 3 and row:
                del row[i]
            elif op == 4:
                row.insert(i, mut.number_text())
            elif row:
                row[i] = mut.mutate_text(row[i], 2)
        return row

    def generate(self) -> dict[str, Any]:
        rng, s = self.rng, self.seeds
        kind = rng.choice(("contract", "contract", "logger", "polycan"))
        header, rows = {
            "contract": (s.csv_contract_header, s.csv_contract_rows),
            "logger": (s.csv_logger_header, s.csv_logger_rows),
            "polycan": (s.polycan_header, s.polycan_rows),
        }[kind]
        delim = "," if kind == "polycan" else rng.choice((",", ",", ";", "\t"))
        header = list(header)
        if rng.random() < 0.1:
            header = self._row(header)
        n = rng.choice((0, 1, 5, 50, 100, 200))
        start = rng.randrange(len(rows))
        p = rng.choice((0.02, 0.1, 0.3, 1.0))
        buf = io.StringIO()
        w = csv.writer(buf, delimiter=delim, lineterminator=rng.choice(("\n", "\r\n")))
        w.writerow(header)
        lines = [buf.getvalue().encode("utf-8", "surrogatepass")]
        for k in range(n):
            row = rows[(start + k) % len(rows)]
            if rng.random() < p:
                row = self._row(row)
            buf.seek(0)
            buf.truncate()
            w.writerow(row)
            line = buf.getvalue().encode("utf-8", "surrogatepass")
            if rng.random() < p * 0.3:
                line = self.mut.mutate_bytes(line)
            lines.append(line)
        if rng.random() < 0.01:
            lines.insert(rng.randint(1, len(lines)), b"1" * rng.randint(1000, 300_000) + b"\n")
        data = b"".join(lines)
        if rng.random() < 0.05:
            data = b"\xef\xbb\xbf" + data
        opts = {
            "time_unit": rng.choice((None, None, "s", "ms")),
            "time_offset_s": rng.choice((0.0, 0.0, 1.7e9, -1e300, 1e308)),
            "reference_torque_nm": rng.choice((400.0, 400.0, None, 0.0, 1e308)),
            "epoch0": rng.choice((1538352000.0, 0.0, -1.0, 1e300)),
        }
        return {"kind": kind, "file": data, "opts": opts}

    def size(self, case: dict[str, Any]) -> int:
        return max(1, case["file"].count(b"\n"))

    def dump(self, case: dict[str, Any]) -> dict[str, Any]:
        return {"kind": case["kind"], "file": _b64(case["file"]), "opts": case["opts"]}

    def load(self, data: dict[str, Any]) -> dict[str, Any]:
        return {"kind": data["kind"], "file": _unb64(data["file"]), "opts": data["opts"]}

    def run(self, case: dict[str, Any]) -> int:
        from tractionecu.bus.candump import ReadStats, read_candump
        from tractionecu.errors import ConfigError, RecordingError
        from tractionecu.recording.csv_import import J1939_LOGGER_MAPPING, import_csv
        from tractionecu.recording.polycan import polycan_to_candump
        from tractionecu.recording.summary import summarize

        self.path.write_bytes(case["file"])
        o = case["opts"]
        kind = case["kind"]
        try:
            if kind == "polycan":
                n = polycan_to_candump(self.path, self.out, epoch0=o["epoch0"])
                st = ReadStats()
                back = sum(1 for _ in read_candump(self.out, st))
                # rows out of time order are converted as they come and then refused by the candump reader
                order = st.rejected["time_backwards"] + st.rejected["time_ahead"]
                if back + order != n or st.total_rejected != order:
                    raise ContractViolation(f"PolyCAN -> candump wrote {n} frames, read back {back}, rejected {dict(st.rejected)}")
                self.counts["reject:candump_readback:time_backwards"] += st.rejected["time_backwards"]
                self.counts["reject:candump_readback:time_ahead"] += st.rejected["time_ahead"]
                self.counts["ok:frames"] += n
                return self.size(case)
            if kind == "contract":
                rec = import_csv(self.path, time_unit=o["time_unit"], time_offset_s=o["time_offset_s"])
            else:
                rec = import_csv(self.path, J1939_LOGGER_MAPPING, time_unit=o["time_unit"],
                                 time_offset_s=o["time_offset_s"], reference_torque_nm=o["reference_torque_nm"])
        except RecordingError as e:
            self.counts[f"reject:file:{_file_reason(str(e))}"] += 1
            return self.size(case)
        except ConfigError as e:
            self.counts["reject:config:" + str(e).split(":")[0]] += 1
            return self.size(case)
        st = rec.stats.files[self.path.name]
        self.counts["ok:rows"] += st.rows - sum(st.rejected[r] for r in ("bad_time", "time_backwards", "short_row"))
        for reason, n in st.rejected.items():
            self.counts["reject:" + reason] += n
        summarize(rec)
        return self.size(case)


# =========================================================================== config
def dump_toml(data: dict[str, Any]) -> str:
    """A TOML document: top-level scalars first, then one ``[table]`` per dict (nested as ``[a.b]``)."""
    from tractionecu.config import toml_key, toml_value

    lines: list[str] = []

    def table(prefix: list[str], d: dict[str, Any]) -> None:
        subs = []
        for k, v in d.items():
            if isinstance(v, dict) and v:
                subs.append((k, v))
            else:
                lines.append(f"{toml_key(k)} = {toml_value(v)}")
        for k, v in subs:
            lines.append("")
            lines.append("[" + ".".join(toml_key(x) for x in prefix + [k]) + "]")
            table(prefix + [k], v)

    table([], data)
    return "\n".join(lines) + "\n"


class ConfigTarget(Target):
    """TOML configuration files: ``vehicle.toml`` (``config.load_vehicle``),
    the service config (``service.config.load_config``) and the estimator
    config (``estimation.estimator.load_estimator_config``).  Errors must be
    ``ConfigError`` and, when one key was changed, name it."""

    name = "config"
    unit = "documents"

    KINDS = ("vehicle", "service", "estimator")

    def __init__(self, seeds: Seeds, rng: random.Random, workdir: Path) -> None:
        super().__init__(seeds, rng, workdir)
        self.mut = Mutator(rng, [seeds.vehicle_toml.encode(), seeds.service_toml.encode(), seeds.estimator_toml.encode()])
        self.base = {
            "vehicle": tomllib.loads(seeds.vehicle_toml),
            "service": tomllib.loads(seeds.service_toml),
            "estimator": tomllib.loads(seeds.estimator_toml),
        }
        self.path = self.workdir / "cfg.toml"

    # ------------------------------------------------------------ values
    def _value(self) -> Any:
        rng = self.rng
        r = rng.randrange(14)
        if r == 0:
            return rng.choice(INTERESTING_INTS)
        if r == 1:
            return rng.randint(-(10 ** rng.randint(0, 30)), 10 ** rng.randint(0, 30))
        if r == 2:
            return rng.choice((math.nan, math.inf, -math.inf, 0.0, -0.0, 5e-324, 1.7976931348623157e308))
        if r == 3:
            return rng.uniform(-1, 1) * 10 ** rng.randint(-20, 20)
        if r == 4:
            return rng.choice((True, False))
        if r == 5:
            return self.mut.token()
        if r == 6:
            return rng.choice(("", "socketcan", "virtual", "kernel", "serial", "none", "0x" + "F" * 16, "0xA200000000000001",
                               "stubble", "tilled", "/dev/null", "/", "x" * 5000, "0x" + "1" * 5000))
        if r == 7:
            return [self._scalar() for _ in range(rng.randint(0, 4))]
        if r == 8:
            return {self._key(): self._scalar() for _ in range(rng.randint(0, 3))}
        if r == 9:
            return datetime(2026, 7, 10, 8, 0, tzinfo=timezone.utc) + timedelta(seconds=rng.randint(0, 10**6))
        if r == 10:
            return rng.randint(0, 300)
        if r == 11:
            return rng.uniform(-10, 1000)
        if r == 12:
            return [rng.choice(("stubble", "grassland", "tilled", "road", "sand", 1, 2.5))]
        return self._scalar()

    def _scalar(self) -> Any:
        rng = self.rng
        return rng.choice((rng.randint(-5, 500), rng.uniform(-5, 500), True, "", "x", math.nan, 10**30))

    def _key(self) -> str:
        rng = self.rng
        return rng.choice(("x", "mass", "MASS_KG", "rate", "vehicle", "can", "fuzzy", "options", "a b", "é", "0", "",
                           "__class__", "__init__", "self", "cls", "kw", "data")) + (str(rng.randrange(10)) if rng.random() < 0.3 else "")

    # ------------------------------------------------------------ cases
    def generate(self) -> dict[str, Any]:
        rng = self.rng
        kind = rng.choice(self.KINDS)
        data = _deep_copy(self.base[kind])
        if kind == "vehicle" and rng.random() < 0.3:
            data = data["vehicle"]  # keys at the top level are allowed too
        expect: list[str] = []
        r = rng.random()
        if r < 0.75:
            for _ in range(1 if rng.random() < 0.8 else rng.randint(2, 3)):
                expect.extend(self._mutate_one(kind, data))
        elif r < 0.80:
            pass  # the seed as is (or without its [vehicle] table): must load
        mutate_text = rng.random() < 0.2
        text = dump_toml(data).encode("utf-8", "surrogatepass")
        if mutate_text:
            text = self.mut.mutate_bytes(text, rng.randint(1, 6))
            expect = []
        if rng.random() < 0.01:
            text = b"\xff\xfe" + text
            expect = []
        return {"kind": kind, "file": text, "expect": expect}

    @staticmethod
    def _tables(kind: str, data: dict[str, Any]) -> list[tuple[list[str], dict[str, Any], Any, Any]]:
        """(dotted path as the loader names it, table, parent, key in parent) of each table to mutate."""
        if kind == "vehicle":
            v = data.get("vehicle")
            if "vehicle" in data:
                return [(["vehicle"], v, data, "vehicle")] if isinstance(v, dict) else []
            return [(["vehicle"], data, None, None)]
        if kind == "estimator":
            est = data.get("estimator")
            if not isinstance(est, dict):
                return []
            out = [(["estimator"], est, data, "estimator")]
            if isinstance(est.get("fuzzy"), dict):
                out.append((["estimator", "fuzzy"], est["fuzzy"], est, "fuzzy"))
            return out
        out = [([], data, None, None)]
        for k, v in data.items():
            if isinstance(v, dict):
                out.append(([k], v, data, k))
                if isinstance(v.get("options"), dict):
                    out.append(([k, "options"], v["options"], v, "options"))
        return out

    def _mutate_one(self, kind: str, data: dict[str, Any]) -> list[str]:
        """Change one thing in ``data``; returns the dotted key names the error may name
        (empty: any ConfigError, or success, is right)."""
        rng = self.rng
        tables = self._tables(kind, data)
        if not tables:
            return []
        path, tab, parent, pkey = rng.choice(tables)
        free = path[-1:] == ["options"]  # can.options is passed through to python-can
        op = rng.randrange(10)
        keys = list(tab)
        out: list[str] = []
        if op <= 5 and keys:  # a value of another type or range
            k = rng.choice(keys)
            tab[k] = self._value()
            out = [".".join(path + [k])]
        elif op == 6:  # an unknown key
            k = self._key()
            if k not in tab and not (parent is None and k == kind):  # a top-level [vehicle] is the table itself
                tab[k] = self._scalar()
                out = [".".join(path + [k])]
        elif op == 7 and keys:  # a key dropped: defaults apply
            del tab[rng.choice(keys)]
        elif op == 8 and parent is not None:  # a table replaced by a scalar
            parent[pkey] = self._scalar()
            return [".".join(path)]
        elif keys:  # a key renamed (case, suffix)
            k = rng.choice(keys)
            new = rng.choice((k.upper(), k + "_", k.replace("_", "-"), k + " "))
            if new not in tab:
                tab[new] = tab.pop(k)
                out = [".".join(path + [new])]
        return [] if free else out

    def dump(self, case: dict[str, Any]) -> dict[str, Any]:
        return {**case, "file": _b64(case["file"])}

    def load(self, data: dict[str, Any]) -> dict[str, Any]:
        return {**data, "file": _unb64(data["file"])}

    # ------------------------------------------------------------ run
    def run(self, case: dict[str, Any]) -> int:
        from tractionecu.estimation.estimator import load_estimator_config as load_estimator
        from tractionecu.config import load_vehicle
        from tractionecu.errors import ConfigError
        from tractionecu.service.config import load_config as load_service

        self.path.write_bytes(case["file"])
        loader = {"vehicle": load_vehicle, "service": load_service, "estimator": load_estimator}[case["kind"]]
        try:
            obj = loader(self.path)
        except ConfigError as e:
            msg = str(e)
            self.counts["reject:" + _config_reason(msg)] += 1
            expect = case["expect"]
            if expect and not any(_names(msg, k) for k in expect):
                raise ContractViolation(f"ConfigError does not name {' or '.join(expect)}: {msg[:300]}") from None
            return 1
        self._check_types(obj, case["kind"])
        self.counts["ok:loaded"] += 1
        return 1

    def _check_types(self, obj: Any, section: str) -> None:
        """Every accepted value has its default's type (bool, int, float, str)."""
        from dataclasses import MISSING, is_dataclass

        for f in fields(obj):
            v = getattr(obj, f.name)
            key = f"{section}.{f.name}"
            if is_dataclass(v):
                self._check_types(v, key if section != "service" else f.name)
                continue
            d = f.default
            if d is MISSING:
                continue
            ok = (isinstance(v, bool) if isinstance(d, bool) else
                  isinstance(v, int) and not isinstance(v, bool) if isinstance(d, int) else
                  isinstance(v, float) if isinstance(d, float) else
                  isinstance(v, str) if isinstance(d, str) else True)
            if not ok:
                raise ContractViolation(f"{key} = {v!r} accepted, expected {type(d).__name__}")
            if isinstance(v, float) and not math.isfinite(v) and not (math.isnan(v) and f.metadata.get("nan_ok")):
                raise ContractViolation(f"{key} = {v!r} accepted")


def _names(msg: str, key: str) -> bool:
    """True if ``msg`` names the dotted ``key``, literally or by a ``*`` pattern
    (``estimator.fuzzy.accel_*_mps2`` names the three ``accel_`` keys)."""
    if key in msg or key.strip() in msg:
        return True
    return any(fnmatch.fnmatchcase(key, pat) for pat in re.findall(r"[\w.]*\*[\w.*]*", msg))


def _config_reason(msg: str) -> str:
    for key, reason in (("not valid TOML", "toml_syntax"), ("cannot read", "unreadable"), ("not found", "not_found"),
                        ("unknown key", "unknown_key"), ("unknown table", "unknown_table"), ("unknown", "unknown_value"),
                        ("expected a table", "not_a_table"), ("expected", "wrong_type"), ("outside", "out_of_range"),
                        ("does not divide", "cross_key"), ("below", "cross_key"), ("give both", "cross_key"),
                        ("must", "cross_key"), ("industry group", "bad_value"), ("not an integer", "bad_value")):
        if key in msg:
            return reason
    return "other"


def _deep_copy(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _deep_copy(v) for k, v in d.items()}
    if isinstance(d, list):
        return [_deep_copy(v) for v in d]
    return d


TARGETS: dict[str, type[Target]] = {
    "can": CanTarget,
    "nmea": NmeaTarget,
    "candump": CandumpTarget,
    "csv": CsvTarget,
    "config": ConfigTarget,
}

"""Coverage-guided fuzzing of one input path with atheris (libFuzzer), optional.

Usage, from the repository root (``pip install atheris`` first)::

    python fuzz/atheris_fuzz.py PATH [libFuzzer options] [CORPUS_DIR ...]
    python fuzz/atheris_fuzz.py nmea -runs=200000 -max_len=4096

PATH is one of can, nmea, candump, csv, config.  The raw bytes libFuzzer
hands over are turned into a case of the same harness ``fuzz/run.py`` uses
(:mod:`fuzz.targets`), so the rules are the same: project errors and
counted rejects are fine; any other exception, or a broken contract, is a
crash that libFuzzer reports with its input.  Without a corpus directory
the seeds of :mod:`fuzz.corpus` are written to a temporary one first.
"""

from __future__ import annotations

import logging
import random
import shutil
import sys
import tempfile
from pathlib import Path

import atheris

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

with atheris.instrument_imports(include=["tractionecu"]):
    import tractionecu.bus.candump  # noqa: F401
    import tractionecu.bus.dbc  # noqa: F401
    import tractionecu.cli.replay  # noqa: F401
    import tractionecu.config  # noqa: F401
    import tractionecu.gnss.nmea  # noqa: F401
    import tractionecu.recording.csv_import  # noqa: F401
    import tractionecu.recording.polycan  # noqa: F401
    import tractionecu.recording.reader  # noqa: F401
    import tractionecu.service.address_claim  # noqa: F401
    import tractionecu.service.config  # noqa: F401
    import tractionecu.service.daemon  # noqa: F401
    import tractionecu.service.gps  # noqa: F401

from fuzz.corpus import build_seeds  # noqa: E402
from fuzz.targets import TARGETS  # noqa: E402

KINDS_CSV = ("contract", "logger", "polycan")
KINDS_CONFIG = ("vehicle", "service", "estimator")
SPLIT = b"\n--gps--\n"


def case_from_bytes(path: str, data: bytes) -> dict:
    """Map libFuzzer's bytes onto a harness case."""
    if path == "can":
        fdp = atheris.FuzzedDataProvider(data)
        frames = []
        while fdp.remaining_bytes() and len(frames) < 64:
            cid = fdp.ConsumeIntInRange(0, 0xFFFFFFFF)
            ext = fdp.ConsumeBool()
            payload = fdp.ConsumeBytes(fdp.ConsumeIntInRange(0, 64))
            flags = fdp.PickValueInList(["", "", "", "E", "R", "F"])
            frames.append([cid, ext, payload, flags])
        return {"frames": frames}
    if path == "nmea":
        lines = data.split(b"\n")
        return {"lines": lines, "terms": [b"\r\n"] * len(lines), "can_t0": 1783670400.0}
    if path == "candump":
        can, _, gps = data.partition(SPLIT)
        return {"can.log": can, "gps.nmea": gps if _ else None}
    head, body = (data[0] if data else 0), data[1:]
    if path == "csv":
        return {"kind": KINDS_CSV[head % 3], "file": body,
                "opts": {"time_unit": None, "time_offset_s": 0.0, "reference_torque_nm": 400.0, "epoch0": 1538352000.0}}
    return {"kind": KINDS_CONFIG[head % 3], "file": body, "expect": []}


def seed_corpus(path: str, seeds, out: Path) -> None:
    """Write the harness seeds as libFuzzer corpus files."""
    out.mkdir(parents=True, exist_ok=True)
    items: list[bytes] = []
    if path == "can":
        for cid, ext, data in seeds.can_frames[:200]:
            items.append(cid.to_bytes(4, "little") + bytes([ext, len(data)]) + data + b"\0")
    elif path == "nmea":
        items = [ln.encode("ascii", "replace") for ln in seeds.nmea_lines]
    elif path == "candump":
        can = "\n".join(seeds.candump_lines[:60]).encode()
        items = [can, can + SPLIT + "\n".join(seeds.nmea_lines[:30]).encode()]
    elif path == "csv":
        for k, (h, rows) in enumerate(((seeds.csv_contract_header, seeds.csv_contract_rows),
                                       (seeds.csv_logger_header, seeds.csv_logger_rows),
                                       (seeds.polycan_header, seeds.polycan_rows))):
            items.append(bytes([k]) + "\n".join(",".join(r) for r in [h] + rows[:40]).encode())
    else:
        items = [bytes([k]) + t.encode() for k, t in enumerate((seeds.vehicle_toml, seeds.service_toml, seeds.estimator_toml))]
    for i, b in enumerate(items):
        (out / f"seed{i:04d}").write_bytes(b)


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] not in TARGETS:
        raise SystemExit(f"usage: python fuzz/atheris_fuzz.py {{{','.join(TARGETS)}}} [libFuzzer options] [CORPUS_DIR ...]")
    path = sys.argv.pop(1)
    logging.disable(logging.CRITICAL)
    seeds = build_seeds()
    shm = Path("/dev/shm")
    # libFuzzer ends the process itself, so the scratch directory has a fixed name and is emptied here
    work = (shm if shm.is_dir() else Path(tempfile.gettempdir())) / f"tecu-atheris-{path}"
    shutil.rmtree(work, ignore_errors=True)
    target = TARGETS[path](seeds, random.Random(0), work / "scratch")
    if not any(not a.startswith("-") for a in sys.argv[1:]):
        seed_corpus(path, seeds, work / "corpus")
        sys.argv.append(str(work / "corpus"))

    def one_input(data: bytes) -> None:
        target.run(case_from_bytes(path, data))

    atheris.Setup(sys.argv, one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main()

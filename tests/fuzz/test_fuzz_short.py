"""Short, seeded versions of the fuzz harnesses (``fuzz/run.py``) and the
regression inputs of every crash they found (``tests/data/fuzz``).

The long form (1,000,000 inputs per path) is ``python fuzz/run.py``; its
figures are in ``fuzz/README.md``.
"""

from __future__ import annotations

import json
import logging
import os
import random
import sys
import tempfile
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from fuzz.corpus import build_seeds  # noqa: E402
from fuzz.run import fuzz_worker  # noqa: E402
from fuzz.targets import TARGETS  # noqa: E402

FIXTURES = REPO / "tests" / "data" / "fuzz"

SHORT_INPUTS = {"can": 12000, "nmea": 15000, "candump": 25000, "csv": 25000, "config": 8000}
"""Inputs per path in CI (a few seconds each)."""


@pytest.fixture(scope="module")
def seeds():
    return build_seeds()


@pytest.fixture
def workdir(tmp_path):
    """Scratch directory for the harness's files: in memory (/dev/shm) where there is one."""
    shm = Path("/dev/shm")
    if shm.is_dir() and os.access(shm, os.W_OK):
        with tempfile.TemporaryDirectory(prefix="tecu-fuzz-test-", dir=shm) as d:
            yield Path(d)
    else:
        yield tmp_path / "work"


@pytest.mark.parametrize("path", list(TARGETS))
def test_fuzz_short(path, seeds, workdir, tmp_path):
    res = fuzz_worker((path, SHORT_INPUTS[path], 20240601, 0, seeds, str(workdir),
                       str(tmp_path / "crashes"), 0.0))
    assert res["inputs"] >= SHORT_INPUTS[path]
    problems = [f"{f['count']} x {sig}: {f['message'][:200]} ({f['file']})" for sig, f in res["failures"].items()]
    assert not problems, "\n".join(problems)
    rejects = sum(v for k, v in res["counts"].items() if k.startswith("reject:"))
    accepted = sum(v for k, v in res["counts"].items() if k.startswith("ok:"))
    assert rejects > 0 and accepted > 0  # the mutations reach both sides of every check


def _fixtures() -> list[Path]:
    return sorted(FIXTURES.glob("*.json"))


@pytest.mark.parametrize("fixture", _fixtures(), ids=lambda p: p.stem)
def test_regression(fixture, seeds, tmp_path):
    """Every input that once crashed a harness now runs through without an unhandled exception."""
    rec = json.loads(fixture.read_text(encoding="utf-8"))
    target = TARGETS[rec["path"]](seeds, random.Random(0), tmp_path)
    prev = logging.root.manager.disable
    logging.disable(logging.CRITICAL)
    try:
        target.run(target.load(rec["case"]))
    finally:
        logging.disable(prev)


def test_fixtures_name_their_bug():
    for f in _fixtures():
        rec = json.loads(f.read_text(encoding="utf-8"))
        assert rec["path"] in TARGETS and rec.get("bug") and rec.get("fixed_in"), f.name


def test_epoch_same_time_flood_is_linear():
    """One epoch that never closes (the same GGA time over and over, as
    ``tests/data/fuzz/epoch-same-time-flood.nmea`` repeated) took quadratic time:
    200,000 sentences 73 s, because every merge copied the growing list of
    sentence names.  100,000 must now take well under a second or two."""
    from tractionecu.gnss.nmea import EpochAssembler, parse_line

    line = (FIXTURES / "epoch-same-time-flood.nmea").read_text(encoding="ascii").strip()
    rec = parse_line(line)
    asm = EpochAssembler()
    t0 = time.perf_counter()
    for i in range(100_000):
        assert asm.push(i + 1, rec) is None
    fix = asm.flush()
    elapsed = time.perf_counter() - t0
    assert fix is not None and len(fix.sentences) <= 16
    assert elapsed < 5.0, f"{elapsed:.1f} s for 100,000 sentences of one epoch"

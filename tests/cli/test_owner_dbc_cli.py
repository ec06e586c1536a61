"""A user DBC with renamed messages through ``--dbc`` and ``[signals]``: the same estimates as the original.

The shared simulated recording's wheel speeds (TECU_WheelSpeeds, 0.001 rad/s per bit) are re-encoded into
the owner's DriveCtrl_3 (another PGN and source address, 0.01 rpm per bit, ``tests/data/dbc``) and mapped back
with ``scale = 2π/60``.  The re-quantisation moves a wheel speed by at most 0.005 rpm = 5.2e-4 rad/s, a
twentieth of the wheel-speed noise the estimator assumes (≈ 0.011 rad/s at 3 rad/s), so the estimates may
differ by a small fraction of their own standard deviation, and in nothing else.
"""

from __future__ import annotations

import csv
import math
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest

from tractionecu.bus import j1939
from tractionecu.bus.candump import format_line, read_candump
from tractionecu.bus.dbc import WHEELS, default_codec
from tractionecu.cli.main import main

REPO = Path(__file__).resolve().parents[2]
OWNER = REPO / "tests" / "data" / "dbc" / "owner_drivectrl.dbc"
SCALE = 2 * math.pi / 60                      # rpm -> rad/s
FRACTION_OF_SIGMA = 0.1
"""Largest change of μ and ρ_s, in units of the estimator's own posterior σ of the step."""


@pytest.fixture(scope="module")
def owner_recording(short_recording: Path, tmp_path_factory) -> Path:
    """The shared recording with its wheel speeds in the owner's DriveCtrl_3 and a [signals] table."""
    own = tmp_path_factory.mktemp("owner") / "rec"
    shutil.copytree(short_recording, own)
    codec = default_codec()
    lines = []
    for f in read_candump(short_recording / "can.log"):
        if f.is_extended and j1939.pgn_of(f.can_id) == 65296:
            _, v = codec.decode(f.can_id, f.data)
            raw = [0xFFFF if math.isnan(v[f"WheelSpeed_{w}"]) else round(v[f"WheelSpeed_{w}"] / SCALE / 0.01)
                   for w in WHEELS]
            lines.append(format_line(f.t, f.channel, 0x18FF5527, True, struct.pack("<4H", *raw)))
        else:
            lines.append(format_line(f.t, f.channel, f.can_id, f.is_extended, f.data))
    (own / "can.log").write_text("\n".join(lines) + "\n")
    with open(own / "vehicle.toml", "a", encoding="utf-8") as fh:
        fh.write("\n[signals]\n" + "".join(f'WheelSpeed_{w} = {{ signal = "DriveCtrl_3.WhlSpd{w}", scale = {SCALE!r} }}\n'
                                          for w in WHEELS))
    return own


def estimates(run: Path) -> dict[str, np.ndarray]:
    with open(run / "estimates.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    text = {"soil_class", "curve_path"}                      # the columns that are names, not numbers
    return {k: np.array([float(r[i]) if k not in text else 0.0 for r in rows[1:]]) for i, k in enumerate(rows[0])}


def test_replay_through_the_owner_dbc_gives_the_original_estimates(short_recording, owner_recording, tmp_path):
    assert main(["replay", str(short_recording), "--out", str(tmp_path / "a"), "--no-map"]) == 0
    assert main(["replay", str(owner_recording), "--out", str(tmp_path / "b"), "--no-map", "--dbc", str(OWNER)]) == 0
    a, b = estimates(tmp_path / "a"), estimates(tmp_path / "b")
    assert np.array_equal(a["t"], b["t"]) and np.array_equal(a["valid"], b["valid"]) and a["valid"].sum() > 1000
    ok = a["valid"] == 1
    for key in [f"mu_{w}" for w in WHEELS] + ["rho_s"]:
        moved = np.abs(a[key] - b[key])[ok] / np.sqrt(a[f"var_{key}"][ok])
        assert moved.max() <= FRACTION_OF_SIGMA, (key, moved.max())
    assert not np.array_equal(a["mu_FL"], b["mu_FL"])        # the owner's messages were really used


def test_inspect_lists_the_mapped_signals_and_their_source(owner_recording, capsys):
    assert main(["inspect", str(owner_recording), "--dbc", str(OWNER)]) == 0
    out = capsys.readouterr().out
    assert "DriveCtrl_3" in out and "TECU_WheelSpeeds" not in out
    assert "wheel speed FL   WheelSpeed_FL from DriveCtrl_3.WhlSpdFL x 0.10472" in out
    assert "drive torque RR  DriveTorque_RR from TECU_DriveTorques" in out
    assert "hub (replay runs this one): 11 of 11 found" in out and "motion: moving" in out
    assert "owner DBC owner_drivectrl.dbc: 3 messages (DriveCtrl_3, DriveCtrl_4, Dash_Lamps)" in out
    assert "skipped DriveCtrl_5: multiplexed" in out


def test_without_the_owner_dbc_the_mapping_is_an_error_naming_the_key(owner_recording, tmp_path, capsys):
    assert main(["replay", str(owner_recording), "--out", str(tmp_path / "c")]) == 1
    err = capsys.readouterr().err
    assert "signals.WheelSpeed_FL: no message 'DriveCtrl_3'" in err and "--dbc" in err
    assert not (tmp_path / "c").exists()
    assert main(["inspect", str(owner_recording), "--dbc", str(tmp_path / "absent.dbc")]) == 1
    assert "absent.dbc" in capsys.readouterr().err


def test_inspect_lists_a_message_on_several_identifiers_once(owner_recording, tmp_path, capsys):
    """The CANedge gnss.dbc defines each of its nine messages on two 11-bit identifiers (two GNSS
    modules); inspect listed every skipped definition, each name as often as it was skipped."""
    p = tmp_path / "gnss.dbc"
    p.write_text('VERSION ""\nNS_ :\nBS_:\nBU_: X\n'
                 'BO_ 3 gnss_pos: 8 X\n SG_ Lat : 0|16@1+ (1,0) [0|0] "" X\n'
                 'BO_ 19 gnss_pos: 8 X\n SG_ Lat : 0|16@1+ (1,0) [0|0] "" X\n'
                 'BO_ 35 gnss_pos: 8 X\n SG_ Lat : 0|16@1+ (1,0) [0|0] "" X\n'
                 'BO_ 7 gnss_speed: 8 X\n SG_ Speed : 0|16@1+ (1,0) [0|0] "" X\n')
    assert main(["inspect", str(owner_recording), "--dbc", str(OWNER), "--dbc", str(p)]) == 0
    out = capsys.readouterr().out
    assert "owner DBC gnss.dbc: 2 messages (gnss_pos, gnss_speed)" in out
    lines = [x.strip() for x in out.splitlines() if x.strip().startswith("skipped gnss")]
    assert lines == ["skipped gnss_pos (2 identifiers): defined again on another 11-bit identifier (the first is "
                     "decoded)"]

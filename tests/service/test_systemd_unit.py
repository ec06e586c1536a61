"""systemd/tractionecu.service: systemd-analyze verify is clean and the exposure stays low."""

from __future__ import annotations

import configparser
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

UNIT = Path(__file__).resolve().parents[2] / "systemd" / "tractionecu.service"
ANALYZE = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze not installed (apt-get install systemd)")


def unit_text() -> str:
    return UNIT.read_text(encoding="utf-8")


def test_unit_contract() -> None:
    cp = configparser.ConfigParser(strict=False, interpolation=None)
    cp.optionxform = str  # type: ignore[assignment,method-assign]
    cp.read_string(re.sub(r"^(DeviceAllow|SystemCallFilter)=", r"\1_=", unit_text(), flags=re.M))
    s = cp["Service"]
    assert s["Type"] == "notify" and s["NotifyAccess"] == "main"
    assert s["Restart"] == "on-failure" and s["WatchdogSec"]
    assert s["DynamicUser"] == "yes" and s["StateDirectory"] == "tractionecu"
    assert s["ProtectSystem"] == "strict" and s["NoNewPrivileges"] == "yes"
    assert s["CapabilityBoundingSet"] == ""
    assert "AF_CAN" in s["RestrictAddressFamilies"]
    assert s["ExecStart"].split()[1:3] == ["run", "--config"]


@needs_analyze
def test_verify_is_clean(tmp_path: Path) -> None:
    # verify also checks that ExecStart exists: point it at this environment's entry point
    exe = Path(sys.executable).with_name("tractionecu")
    assert exe.exists(), "pip install -e . first"
    unit = tmp_path / "tractionecu.service"
    unit.write_text(unit_text().replace("/opt/tractionecu/bin/tractionecu", str(exe)), encoding="utf-8")
    r = subprocess.run([ANALYZE, "verify", str(unit)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout == "" and r.stderr == "", r.stdout + r.stderr


@needs_analyze
def test_security_exposure() -> None:
    r = subprocess.run([ANALYZE, "security", "--offline=yes", "--no-pager", str(UNIT)],
                       capture_output=True, text=True, timeout=60)
    m = re.search(r"Overall exposure level for tractionecu\.service: ([0-9.]+)", r.stdout)
    assert m, r.stdout + r.stderr
    assert float(m.group(1)) <= 1.5

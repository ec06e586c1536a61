"""The public Python API: the names at the package top, the README example, ``python -m tractionecu``."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import tractionecu

ROOT = Path(__file__).resolve().parents[1]


def test_public_names_import_from_the_package() -> None:
    from tractionecu import Estimator, EstimatorConfig, SensorSpec, VehicleParams, read_recording, replay
    from tractionecu.estimation.estimator import Estimator as E
    from tractionecu.pipeline.replay import replay as r
    from tractionecu.recording.reader import read_recording as rr

    assert Estimator is E and replay is r and read_recording is rr
    assert VehicleParams().mass_kg > 0 and SensorSpec() and EstimatorConfig()
    assert set(tractionecu.__all__) <= set(dir(tractionecu))


def test_import_stays_light() -> None:
    code = "import sys, tractionecu; print(sorted(m for m in sys.modules if m.startswith(('numpy', 'scipy', 'can', 'tractionecu.'))))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_unknown_name_is_an_attribute_error() -> None:
    try:
        tractionecu.NoSuchThing  # noqa: B018
    except AttributeError as e:
        assert "NoSuchThing" in str(e)
    else:  # pragma: no cover
        raise AssertionError("no AttributeError")


def readme_example() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    m = re.search(r"<!-- api-example[^>]*-->\s*```python\n(.*?)```", text, re.S)
    assert m, "README has no api-example block"
    return m.group(1)


def test_readme_example_runs_and_is_short() -> None:
    code = readme_example()
    assert len([ln for ln in code.splitlines() if ln.strip()]) <= 12
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    m = re.search(r"mu per wheel \[([^\]]*)\], rho_s (\S+), valid (\w+)", out.stdout)
    assert m, out.stdout
    mu = [float(x) for x in m.group(1).split()]
    assert len(mu) == 4 and all(0.0 < x < 1.5 for x in mu)
    assert m.group(3) == "True"


def test_python_m_tractionecu_is_the_command() -> None:
    out = subprocess.run([sys.executable, "-m", "tractionecu", "--help"], capture_output=True, text=True, check=True)
    assert out.stdout.startswith("usage: tractionecu")
    for cmd in ("inspect", "replay", "map", "run", "simulate", "diagnose"):
        assert cmd in out.stdout
    assert "``" not in out.stdout and ":func:" not in out.stdout   # product text, not developer notes
    v = subprocess.run([sys.executable, "-m", "tractionecu", "--version"], capture_output=True, text=True, check=True)
    assert v.stdout.strip() == f"tractionecu {tractionecu.__version__}"


def test_replay_takes_a_path_and_bounds_its_rate(tmp_path, short_recording) -> None:
    """replay("path") raised AttributeError; replay(rec, rate_hz=1e6) on 40 s grew past 21 GB."""
    import pytest

    from tractionecu.errors import ConfigError
    from tractionecu.pipeline.replay import replay

    with pytest.raises(ConfigError, match=r"rate_hz: an estimator step rate in \[1, 1000\] Hz"):
        replay(tmp_path, rate_hz=1e6)
    with pytest.raises(ConfigError, match="rate_hz"):
        replay(tmp_path, rate_hz=float("nan"))
    assert replay(str(short_recording)).steps > 1000

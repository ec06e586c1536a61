"""Dask and the fleet package stay out of the daemon and of the command's start."""

from __future__ import annotations

import subprocess
import sys

HEAVY = ("dask", "distributed", "tractionecu.fleet")
# pyarrow is not listed: pandas imports it when installed, and python-can pulls pandas in through
# asammdf when the daemon module is imported on its own (`tractionecu run` keeps asammdf out).


def _loaded(code: str) -> list[str]:
    probe = (f"{code}\nimport sys\nprint(' '.join(sorted(m for m in sys.modules "
             f"if m.split('.')[0] in {HEAVY!r} or m.startswith('tractionecu.fleet'))))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    return out.stdout.split()


def test_daemon_never_imports_the_fleet_extra() -> None:
    assert _loaded("import tractionecu.service.daemon") == []


def test_cli_parser_does_not_import_dask() -> None:
    assert _loaded("from tractionecu.cli.main import build_parser; build_parser().parse_args(['fleet', 'map', 'x', '--out', 'y'])") == []

"""The on-board core imports neither the simulator, nor scoring, nor diagnosis, nor the CLI.

The core is what runs on the tractor: ``bus``, ``gnss``, ``recording``,
``estimation``, ``mapping``, ``service``, ``pipeline`` and the top-level
``config``, ``errors``, ``counting``.  Truth scoring lives in
:mod:`tractionecu.evaluation`, simulation in :mod:`tractionecu.sim`.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import tractionecu

PKG = Path(tractionecu.__file__).resolve().parent
CORE_PACKAGES = ("bus", "gnss", "recording", "estimation", "mapping", "service", "pipeline")
CORE_MODULES = ("config.py", "errors.py", "counting.py")
FORBIDDEN = ("tractionecu.sim", "tractionecu.evaluation", "tractionecu.diagnose", "tractionecu.cli")


def _forbidden(name: str) -> bool:
    return any(name == f or name.startswith(f + ".") for f in FORBIDDEN)


def core_files() -> list[Path]:
    files = [PKG / m for m in CORE_MODULES]
    for pkg in CORE_PACKAGES:
        files += sorted((PKG / pkg).rglob("*.py"))
    return files


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_names(source: str, module: str, is_package: bool = False) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in ``source`` (any depth; relative ones resolved).

    ``from X import y`` counts as X, and as X.y when X itself is allowed (y may be a submodule);
    ``importlib.import_module("X")`` and ``__import__("X")`` with a literal name count as X.
    """
    package = module if is_package else module.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                head = ".".join(base + ([node.module] if node.module else []))
            else:
                head = node.module or ""
            found.append((node.lineno, head))
            if not _forbidden(head):
                found += [(node.lineno, f"{head}.{alias.name}") for alias in node.names]
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and getattr(node.func, "attr", getattr(node.func, "id", None)) in ("import_module", "__import__")):
            found.append((node.lineno, str(node.args[0].value)))
    return found


def test_core_files_import_nothing_outside_the_core():
    bad = [f"{p.relative_to(PKG.parent)}:{line}: {name}" for p in core_files()
           for line, name in imported_names(p.read_text(encoding="utf-8"), _module_name(p), p.name == "__init__.py")
           if _forbidden(name)]
    assert not bad, "core modules import simulation, scoring, diagnosis or the CLI:\n" + "\n".join(bad)


def test_the_import_check_sees_relative_nested_and_dynamic_imports():
    src = ("import numpy as np\n"
           "from . import store\n"
           "from .. import sim\n"
           "def f():\n"
           "    from ..evaluation.scoring import S_GRID\n"
           "    import tractionecu.cli.main\n"
           "    return importlib.import_module('tractionecu.diagnose.engine')\n")
    names = [n for _, n in imported_names(src, "tractionecu.mapping.probe")]
    assert [n for n in names if _forbidden(n)] == ["tractionecu.sim", "tractionecu.evaluation.scoring",
                                                   "tractionecu.cli.main", "tractionecu.diagnose.engine"]
    assert "tractionecu.mapping.store" in names and "numpy" in names
    pkg = [n for _, n in imported_names("from .sampler import x\nfrom ..sim.field import Field\n",
                                        "tractionecu.mapping", is_package=True)]
    assert pkg == ["tractionecu.mapping.sampler", "tractionecu.mapping.sampler.x", "tractionecu.sim.field"]
    assert not _forbidden("tractionecu.simulation_free") and _forbidden("tractionecu.sim")


def test_importing_the_core_loads_no_simulation_scoring_diagnosis_or_cli():
    mods = ["tractionecu.service.daemon", "tractionecu.estimation", "tractionecu.estimation.estimator",
            "tractionecu.mapping", "tractionecu.mapping.from_replay"]
    if (PKG / "pipeline").is_dir():
        mods.append("tractionecu.pipeline")
    code = ("import importlib, json, sys\n"
            f"for m in {mods!r}:\n    importlib.import_module(m)\n"
            "print(json.dumps(sorted(sys.modules)))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    loaded = [m for m in json.loads(res.stdout.splitlines()[-1]) if _forbidden(m)]
    assert not loaded, f"importing {mods} loaded: {loaded}"


def test_the_daemon_itself_does_not_load_asammdf():
    """asammdf (the ``mf4`` extra: pandas, polars, lxml…) is for reading MF4 files off-board; the on-board
    daemon imports it nowhere.  python-can (>= 4.4) loads it on ``import can`` when it is installed, for its
    own MF4 reader and writer: that importer is the only one allowed."""
    code = ("import json, sys\n"
            "importers = []\n"
            "class Watch:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name == 'asammdf':\n"
            "            f = sys._getframe(1)\n"
            "            while f is not None and f.f_globals.get('__name__', '').startswith('importlib'):\n"
            "                f = f.f_back\n"
            "            importers.append(f.f_globals.get('__name__') if f is not None else None)\n"
            "sys.meta_path.insert(0, Watch())\n"
            "import tractionecu.service.daemon\n"
            "print(json.dumps(importers))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    importers = json.loads(res.stdout.splitlines()[-1])
    assert set(importers) <= {"can.io.mf4"}, f"asammdf imported by {importers}"


def test_the_daemon_process_keeps_asammdf_out():
    """``tractionecu run`` (the daemon) does not carry asammdf, which python-can would import when installed."""
    code = ("import sys\n"
            "from tractionecu.cli.run import keep_mf4_reader_out\n"
            "keep_mf4_reader_out()\n"
            "import tractionecu.service.daemon\n"
            "import can\n"
            "print(sys.modules.get('asammdf') is None and 'pandas' not in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True", out.stderr

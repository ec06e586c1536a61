"""The compiled kernels' cache directory follows every source their code comes from (model/jitcache.py)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from tractionecu.model import jitcache


@pytest.fixture()
def fresh_caches():
    jitcache._imports.cache_clear()
    jitcache._fingerprint.cache_clear()
    yield
    jitcache._imports.cache_clear()
    jitcache._fingerprint.cache_clear()


def _package(tmp_path: Path) -> Path:
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from .b import X\nfrom . import c\n\ndef k():\n    return compiled(f)\n")
    (pkg / "b.py").write_text("X = 1.0\n")                                  # a constant, no kernels
    (pkg / "c.py").write_text("from .d import Y\nK = njit(lambda: 0)\n")   # defines kernels: followed
    (pkg / "d.py").write_text("from .e import Z\nY = 2.0\n")               # no kernels: not followed
    (pkg / "e.py").write_text("Z = 3.0\n")
    (pkg / "unrelated.py").write_text("W = 4.0\n")
    return pkg


def test_a_kernels_fingerprint_follows_its_imports_through_kernel_modules(tmp_path: Path, fresh_caches) -> None:
    pkg = _package(tmp_path)
    deps = {p.name for p in jitcache.dependencies(pkg / "a.py")}
    assert deps == {"__init__.py", "a.py", "b.py", "c.py", "d.py"}     # (``from . import c`` runs the package's)
    fp0 = jitcache.fingerprint(pkg / "a.py")
    for name, moves in (("b.py", True), ("d.py", True), ("e.py", False), ("unrelated.py", False)):
        (pkg / name).write_text((pkg / name).read_text() + "# edited\n")
        jitcache._fingerprint.cache_clear()
        fp = jitcache.fingerprint(pkg / "a.py")
        assert (fp != fp0) is moves, name
        fp0 = fp


def test_the_loop_kernels_dependencies_are_the_files_its_code_comes_from(fresh_caches) -> None:
    """The regression: a kernel of _loop_kernel.py compiles in _kernels.py's functions and vehicle.py's, and
    constants of kinematics.py and rates.py; numba's cache looked at _loop_kernel.py alone."""
    root = jitcache.PACKAGE_ROOT
    deps = {p.relative_to(root).as_posix() for p in jitcache.dependencies(root / "estimation" / "_loop_kernel.py")}
    assert {"estimation/_loop_kernel.py", "estimation/_kernels.py", "estimation/_curve_kernel.py",
            "model/vehicle.py", "estimation/kinematics.py", "estimation/rates.py", "config.py"} <= deps


def test_older_versions_of_a_module_are_removed_and_other_trees_kept(tmp_path: Path, monkeypatch,
                                                                    fresh_caches) -> None:
    pytest.importorskip("numba")
    from numba.core.caching import UserProvidedCacheLocator

    pkg = _package(tmp_path)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    root = tmp_path / "cache" / jitcache.SUBDIR
    tag = "a"                                        # a file outside the package: its stem
    sub = UserProvidedCacheLocator.get_suitable_cache_subpath(str(pkg / "a.py"))
    old_only = root / f"{tag}-{'0' * 16}" / sub
    shared = root / f"{tag}-{'1' * 16}"
    other_module = root / f"{tag}x-{'2' * 16}" / sub            # another module whose name starts alike
    recent = root / f"{tag}-{'3' * 16}" / sub                   # written to within PRUNE_AGE_S: perhaps in use
    aged = time.time() - 2.0 * jitcache.PRUNE_AGE_S
    for d in (old_only, shared / sub, shared / "pkg_othertree", other_module, recent):
        d.mkdir(parents=True)
        (d / "a.k-1.py311.nbi").write_bytes(b"old")
        if d != recent:
            os.utime(d / "a.k-1.py311.nbi", (aged, aged))
    d = Path(jitcache.kernel_cache_dir(pkg / "a.py"))
    assert d.parent == root and d.name == f"{tag}-{jitcache.fingerprint(pkg / 'a.py')}"
    assert not old_only.parent.exists()                          # only this tree's caches: removed
    assert not (shared / sub).exists() and (shared / "pkg_othertree" / "a.k-1.py311.nbi").exists()
    assert other_module.exists() and recent.exists()


def test_compiled_caches_a_kernel_in_its_versions_directory(tmp_path: Path, monkeypatch, fresh_caches) -> None:
    from tractionecu.model import vehicle

    if vehicle.njit is None:
        pytest.skip("numba off (TRACTIONECU_JIT=0 or not installed)")
    from numba.core import config as numba_config

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))

    def twice(x):                                                # pragma: no cover - compiled
        return 2.0 * x

    k = vehicle.compiled(twice)
    assert k(1.5) == 3.0
    want = jitcache.kernel_cache_dir(__file__)
    assert k._cache._impl.locator.get_cache_path().startswith(want)
    assert numba_config.CACHE_DIR != want       # numba's own setting (from the environment) for everyone else

"""Where the compiled kernels are cached on disk: one directory per module and version of its sources.

numba's on-disk cache (``cache=True``) keeps a compiled function until the file that defines it changes. It does
not look at the files the function calls into or takes constants from. Two modules had guarded some of their
functions by hand: ``estimation/_kernels.py``'s predict functions and ``estimation/_loop_kernel.py``'s stages
close over a hash of a listed set of sources (``_kernels._model_tag``, ``_loop_kernel._dep_tag``). Every other
cross-file kernel had no guard (``_kernels.estimate_outputs`` compiles in ``model/vehicle.py``'s
``wheel_radii``, ``_kernels.add_kappa_noise`` its ``_radius`` and ``_wheel_terms``), and the lists had to be kept
by hand. After an edit of such a callee alone numba loads the caller's old machine code (a
crash, ``NRT_adapt_ndarray_to_python``, was seen once in a development tree; old numbers would be silent).
:func:`kernel_cache_dir` gives each kernel module a cache directory named by a fingerprint of its own source and
of every package module it imports, following the imports of those that define kernels themselves: an edit
anywhere a kernel's code or constants come from gives a new directory, so a fresh compile (the two hand-kept tags
are now a second guard for the functions they cover). Directories of older versions of the same module (same
source tree) are removed when a new one is made, once nothing has been written to them for :data:`PRUNE_AGE_S`
(a process of the older version may still be running and compiling into them).

The base directory is ``NUMBA_CACHE_DIR`` where set (the systemd unit's), else the package's own ``__pycache__``,
else ``$XDG_CACHE_HOME/tractionecu`` (``~/.cache/tractionecu``); none writable: numba's own choice (its locators
after the user-provided one, or no cache).
"""

from __future__ import annotations

import ast
import hashlib
import os
import shutil
import time
from functools import lru_cache
from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parents[1]
"""The ``tractionecu`` package directory: the imports followed are those inside it."""
SUBDIR = "tractionecu-kernels"
PRUNE_AGE_S = 3600.0
"""An older version's cache directory is removed only when its newest file is at least this old [s]."""
KERNEL_MARKERS = ("compiled(", "njit(")
"""Text that marks a module defining compiled kernels (whose own imports are followed)."""


def _module_file(pkg: Path, dotted: str) -> Path | None:
    """The file of module ``dotted`` (relative to the directory ``pkg``), or None when it is not a package file."""
    base = pkg.joinpath(*dotted.split(".")) if dotted else pkg
    for cand in (base.with_suffix(".py"), base / "__init__.py"):
        if cand.is_file():
            return cand.resolve()
    return None


@lru_cache(maxsize=None)
def _imports(py_file: Path) -> tuple[Path, ...]:
    """The package files ``py_file`` imports (relative imports, and absolute ones of ``tractionecu``), anywhere
    in the file, sorted."""
    try:
        tree = ast.parse(py_file.read_text(encoding="utf-8"), filename=str(py_file))
    except (OSError, SyntaxError, ValueError):
        return ()
    here = py_file.parent
    out: set[Path] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                pkg = here
                for _ in range(node.level - 1):
                    pkg = pkg.parent
                mod = node.module or ""
            elif node.module and node.module.split(".")[0] == PACKAGE_ROOT.name:
                pkg, mod = PACKAGE_ROOT, node.module.partition(".")[2]
            else:
                continue
            f = _module_file(pkg, mod)
            if f is not None:
                out.add(f)
            for alias in node.names:                       # ``from . import _kernels``: a submodule
                g = _module_file(pkg, f"{mod}.{alias.name}" if mod else alias.name)
                if g is not None:
                    out.add(g)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == PACKAGE_ROOT.name:
                    f = _module_file(PACKAGE_ROOT, alias.name.partition(".")[2])
                    if f is not None:
                        out.add(f)
    return tuple(sorted(out))


def _defines_kernels(py_file: Path) -> bool:
    try:
        text = py_file.read_text(encoding="utf-8")
    except OSError:
        return False
    return any(m in text for m in KERNEL_MARKERS)


def dependencies(py_file: str | Path) -> list[Path]:
    """``py_file`` and the package files its compiled code may come from (module doc), sorted."""
    start = Path(py_file).resolve()
    seen = {start}
    todo = [start]
    while todo:
        f = todo.pop()
        for g in _imports(f):
            if g not in seen:
                seen.add(g)
                if _defines_kernels(g):
                    todo.append(g)
    return sorted(seen)


def fingerprint(py_file: str | Path) -> str:
    """16 hex digits of the SHA-256 of the contents of :func:`dependencies` (names relative to the package)."""
    return _fingerprint(Path(py_file).resolve())


@lru_cache(maxsize=None)
def _fingerprint(py_file: Path) -> str:
    """:func:`fingerprint` once per process and file (a module's kernels are decorated one by one)."""
    h = hashlib.sha256()
    for f in dependencies(py_file):
        try:
            rel = f.relative_to(PACKAGE_ROOT).as_posix()
        except ValueError:
            rel = f.name
        h.update(rel.encode())
        h.update(b"\0")
        h.update(f.read_bytes())
        h.update(b"\0")
    return h.hexdigest()[:16]


def _writable(d: Path) -> bool:
    p = d
    while not p.exists():                 # the nearest existing ancestor decides
        if p.parent == p:
            return False
        p = p.parent
    return p.is_dir() and os.access(p, os.W_OK | os.X_OK)


def base_dir() -> Path | None:
    """The first writable of ``NUMBA_CACHE_DIR``, the package's ``__pycache__`` and the user's cache (module doc)."""
    cands = []
    env = os.environ.get("NUMBA_CACHE_DIR", "").strip()
    if env:
        cands.append(Path(env))
    cands.append(PACKAGE_ROOT / "__pycache__")
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    cands.append((Path(xdg) if xdg else Path.home() / ".cache") / "tractionecu")
    return next((c for c in cands if _writable(c)), None)


def _module_tag(py_file: Path) -> str:
    try:
        rel = py_file.relative_to(PACKAGE_ROOT).with_suffix("")
        return ".".join(rel.parts)
    except ValueError:
        return py_file.stem


def kernel_cache_dir(py_file: str | Path) -> str | None:
    """The cache directory (numba's ``CACHE_DIR``) for the kernels defined in ``py_file``, made and with the older
    versions' of the same module in the same tree removed; None without a writable base (module doc)."""
    base = base_dir()
    if base is None:
        return None
    f = Path(py_file).resolve()
    tag = _module_tag(f)
    root = base / SUBDIR
    d = root / f"{tag}-{fingerprint(f)}"
    if not d.is_dir():
        _prune(root, tag, f, keep=d)
    return str(d)


def _prune(root: Path, tag: str, py_file: Path, keep: Path) -> None:
    """Remove the caches of other versions of ``py_file``'s module in ``root`` (only this source tree's: numba
    names its directory by the hash of the source's directory, so another tree's caches stay)."""
    from numba.core.caching import UserProvidedCacheLocator

    sub = UserProvidedCacheLocator.get_suitable_cache_subpath(str(py_file))
    try:
        old = [p for p in root.glob(f"{tag}-*") if p != keep and p.is_dir() and len(p.name) == len(tag) + 17]
    except OSError:
        return
    now = time.time()
    for p in old:
        try:
            newest = max((f.stat().st_mtime for f in (p / sub).rglob("*")), default=0.0)
        except OSError:
            continue
        if now - newest < PRUNE_AGE_S:
            continue                           # perhaps in use by a process of that version
        shutil.rmtree(p / sub, ignore_errors=True)
        try:
            p.rmdir()                          # empty: no other tree's caches left in it
        except OSError:
            pass

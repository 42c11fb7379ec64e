"""Compiled hot kernels: numba with an on-disk cache that also works inside extracted FMUs.

Decorate a kernel with :func:`kernel` (``numba.njit`` with caching) in any module of the
``fmus`` package. numba's own cache keys a function by the folder of its source file, so a
kernel inside an FMU, which every host extracts to a fresh folder, would be compiled again in
every process (about a second per kernel). Here the cache folder is keyed by the *content* of
the package instead: the bundle id that ``orchestration/build.py`` writes into every FMU
(``BUNDLE_ID``: the hash of all of the package's sources), or the same hash computed over the
working tree's ``fmus``. So every FMU of one build, every process, and the working tree with the
same sources share one compiled copy, and any change of any source (a kernel, or a function it
calls in another module) gives a new folder: nothing stale is ever loaded.

Where the cache lives: ``$FLEXFUSION_CACHE_DIR``, else ``$XDG_CACHE_HOME/flexfusion``, else
``~/.cache/flexfusion``, under ``numba/<16 hex of the bundle id>-<package name>/``; if that cannot be written,
a folder in the system's temporary directory. ``NUMBA_DISABLE_JIT=1`` runs the kernels as plain
Python (numba's own switch), for debugging.

Kernels are compiled without ``fastmath``: floating point is evaluated in source order with no
contraction into fused multiply-adds, so a scalar kernel rounds as the same Python code does.
"""
from __future__ import annotations

import functools
import hashlib
import os
import tempfile
from pathlib import Path
from typing import Any, Callable

PACKAGE = Path(__file__).resolve().parent.parent      # ``fmus``, or ``fmus_<hash>`` in an FMU
BUNDLE_ID_FILE = "BUNDLE_ID"


def package_sources(root: Path) -> list[Path]:
    """The source files below the package folder ``root`` that its bundle id covers: every
    ``*.py`` but the FMU scripts (each FMU carries its own script beside the shared package),
    sorted."""
    return sorted(p for p in root.rglob("*.py")
                  if not p.name.endswith("_fmu.py") and "__pycache__" not in p.parts)


def package_digest(root: Path) -> str:
    """SHA-256 (hex) of the package below ``root``: each source's relative path and bytes.

    The same function names an FMU's vendored package at build time and keys the kernel cache.
    """
    digest = hashlib.sha256()
    for f in package_sources(root):
        digest.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes())
    return digest.hexdigest()


@functools.lru_cache(maxsize=None)
def bundle_id() -> str:
    """This package's bundle id: read from an FMU's ``BUNDLE_ID``, else hashed from the tree."""
    stored = PACKAGE / BUNDLE_ID_FILE
    if stored.is_file():
        return stored.read_text().strip()
    return package_digest(PACKAGE)


def cache_dir() -> Path:
    """The folder holding the compiled kernels of this package's sources (see the module doc)."""
    base = os.environ.get("FLEXFUSION_CACHE_DIR")
    if not base:
        xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        base = os.path.join(xdg, "flexfusion")
    # the package's name too: an FMU's copy (``fmus_<hash>``, imports rewritten) and the working
    # tree (``fmus``) have one bundle id but different source files
    return Path(base) / "numba" / f"{bundle_id()[:16]}-{PACKAGE.name}"


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
        return True
    except OSError:
        return False


@functools.lru_cache(maxsize=None)
def _kernel_cache_dir() -> Path:
    preferred = cache_dir()
    if _writable(preferred):
        return preferred
    fallback = Path(tempfile.gettempdir()) / f"flexfusion-numba-{os.getuid()}" / preferred.name
    fallback.mkdir(parents=True, exist_ok=True)
    return fallback


@functools.lru_cache(maxsize=None)
def _register_locator() -> None:
    """Put a cache locator for this package's kernels in front of numba's own ones.

    numba picks the first locator class whose ``from_function`` accepts a function; ours
    accepts only functions defined in a file of this package, so other numba users in the same
    process (a host's own code) keep numba's default behaviour.
    """
    from numba.core import caching
    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl      # public from numba 0.61

    class BundleLocator(caching.UserProvidedCacheLocator):
        """The cache of one kernel: in the bundle's folder, one subfolder per source module.
        numba's source stamp (the SHA-256 of the file's content) guards each entry too."""

        def __init__(self, py_func: Any, py_file: str):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = str(_kernel_cache_dir() / Path(py_file).resolve().relative_to(PACKAGE).with_suffix(""))

        def get_cache_path(self) -> str:
            return self._cache_path

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> Any:
            try:
                Path(py_file).resolve().relative_to(PACKAGE)
            except (ValueError, OSError):
                return None
            # the source-file mixin's constructor-and-check (the user-dir base asks for NUMBA_CACHE_DIR)
            return super(caching.UserProvidedCacheLocator, cls).from_function(py_func, py_file)

    impl._locator_classes.insert(0, BundleLocator)


def kernel(function: Callable | None = None, *, aot: str | None = None, **options: Any) -> Any:
    """``numba.njit`` with the on-disk cache of this module; ``@kernel`` or ``@kernel(...)``.

    ``function`` is the kernel (or None when options are given); ``options`` go to
    ``numba.njit`` (``cache=True`` is implied; ``fastmath`` stays off). A function with no source
    file behind it (code run from a string, e.g. a benchmark's baseline taken from git) is
    compiled without the cache: there is nothing to key it by.

    ``aot``: the numba signature of a kernel that Python code calls (e.g.
    ``"float64(float64[:], float64)"``), for compiling it ahead of time; a kernel that only
    other kernels call needs none. The just-in-time path compiles lazily and ignores it.
    """
    import numba
    _register_locator()

    def decorate(fn: Callable) -> Any:
        cache = os.path.isfile(fn.__code__.co_filename)
        dispatcher = numba.njit(cache=cache, **options)(fn)
        dispatcher.aot_signature = aot
        return dispatcher
    return decorate if function is None else decorate(function)

"""Compiled hot kernels: ahead of time inside a built FMU, else numba with an on-disk cache that
also works inside extracted FMUs.

Decorate a kernel with :func:`kernel` in any module of the ``fmus`` package; one that Python code
calls carries its numba signature, ``@kernel(aot="float64(float64[:], float64)")`` (arrays any
layout, ``float64[:]``, unless the kernel needs C order; a kernel only other kernels call needs
none: it is compiled into its callers).

Ahead of time (in an FMU): ``flexfusion build`` compiles every kernel with a signature into one
extension module of the FMU's package, ``_compiled.<EXT_SUFFIX>`` (:func:`compile_package`,
numba.pycc; export names :func:`export_name`). Where it imports (:func:`compiled_module`),
:func:`kernel` returns its functions and numba is never imported: a process that runs our FMUs
saves numba's import and CPU-target initialisation (about 0.5 s, it imports scipy.linalg) and
any compilation or cache loading. The compiled kernels round as the JIT ones (no fastmath either;
tests/test_aot.py compares them bit for bit). Called with arguments of other types than its
signature, a compiled kernel raises TypeError (the JIT would compile another version): callers
pass one type (e.g. ``np.ascontiguousarray(x, float)``, ``float(v)``, ``tuple(s)``).

Just in time (the working tree, studies, an FMU built with ``FLEXFUSION_NO_AOT=1`` or without the
module for this Python, which then says so once): ``numba.njit(cache=True)``, numba's public
on-disk cache, which finds a kernel again by its source file's folder and content. Two rules
keep it from ever loading a stale kernel, since a cached kernel has its callees in other
modules compiled in and numba's check covers only its own file (a changed callee is not seen):

* in an FMU's package (a ``BUNDLE_ID`` file: ``orchestration/build.py``), numba's default
  place, ``__pycache__`` beside the sources. The FMU store extracts a package to a folder named
  by its content (shared by every FMU and process that bundles it), so a changed package is
  another folder: compiled once per package content (measured in ARCHITECTURE.md). A host
  that extracts each FMU afresh compiles in each process (the ahead-of-time module saves it);
* in the working tree, numba's ``NUMBA_CACHE_DIR`` names a folder of the whole package's
  content, ``<cache root>/numba/<16 hex of the bundle id>-fmus`` (the root of
  :mod:`fmus.common.disk_cache`; a folder of the system's temporary directory if that cannot
  be written): any source changed, another folder. It is set for the process (and its
  children) when numba is not imported yet and the variable is unset or another FlexFusion
  tree's; otherwise (numba imported first, or ``NUMBA_CACHE_DIR`` the user's) the kernels are
  compiled without a cache, with one warning naming the cause. numba loads code from that
  folder, so it is used only if private to this user
  (:func:`fmus.common.disk_cache.private_folder`), else no cache, with one warning.

``NUMBA_DISABLE_JIT=1`` runs the kernels as plain Python (numba's own switch), for debugging.

Kernels are compiled without ``fastmath``: floating point is evaluated in source order with no
contraction into fused multiply-adds, so a scalar kernel rounds as the same Python code does.
"""
from __future__ import annotations

import functools
import hashlib
import importlib
import logging
import os
import re
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable

from fmus.common.disk_cache import cache_root, private_folder

PACKAGE = Path(__file__).resolve().parent.parent      # ``fmus``, or ``fmus_<hash>`` in an FMU
BUNDLE_ID_FILE = "BUNDLE_ID"
COMPILED_MODULE = "_compiled"         # the ahead-of-time kernels' extension module


KERNEL_SUFFIXES = (".pyx", ".pxd", ".pxi")     # the Cython kernels' sources (fmus/common/cython_kernels.py)


def package_sources(root: Path) -> list[Path]:
    """The source files below the package folder ``root`` that its bundle id covers: every
    ``*.py`` but the FMU scripts (each FMU carries its own script beside the shared package), and
    the Cython kernels' sources (:data:`KERNEL_SUFFIXES`); sorted."""
    return sorted(p for p in root.rglob("*") if "__pycache__" not in p.parts and (
        (p.suffix == ".py" and not p.name.endswith("_fmu.py")) or p.suffix in KERNEL_SUFFIXES))


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
    """The working tree's folder of compiled kernels, named by its sources (module docstring)."""
    return cache_root() / "numba" / f"{bundle_id()[:16]}-{PACKAGE.name}"


_OURS = re.compile(r"[0-9a-f]{16}-\w+")        # the name of a cache_dir(), of any tree


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
        return True
    except OSError:
        return False


@functools.lru_cache(maxsize=None)
def _kernel_cache_dir() -> Path | None:
    """The kernel cache's folder: :func:`cache_dir`, else one in the system's temporary
    directory, each only if private (:func:`fmus.common.disk_cache.private_folder`: numba loads
    code from it); None (no cache, with one warning) if neither is."""
    preferred = cache_dir()
    shared = Path(tempfile.gettempdir()) / f"flexfusion-numba-{os.getuid()}"
    why = []
    for folder, top in ((preferred, cache_root()), (shared / preferred.name, shared)):
        try:
            private_folder(folder, top)
            if _writable(folder):
                return folder
            why.append(f"{folder}: not writable")
        except OSError as exc:
            why.append(str(exc))
    logging.getLogger(__name__).warning("no private folder for the compiled kernels (%s): they are "
                                        "compiled in every process", "; ".join(why))
    return None


@functools.lru_cache(maxsize=None)
def _cached() -> bool:
    """Whether this package's kernels use numba's on-disk cache; sets the working tree's
    ``NUMBA_CACHE_DIR`` first (the rules of the module docstring)."""
    if (PACKAGE / BUNDLE_ID_FILE).is_file():
        return True                          # an FMU's package: in its content-named folder
    folder = _kernel_cache_dir()
    if folder is None:
        return False                         # no private folder: said once by _kernel_cache_dir
    wanted = str(folder)
    current = os.environ.get("NUMBA_CACHE_DIR", "")
    if "numba" not in sys.modules and (not current or _OURS.fullmatch(Path(current).name)):
        os.environ["NUMBA_CACHE_DIR"] = wanted
        return True
    import numba
    if numba.config.CACHE_DIR == wanted:
        return True
    cause = (f"NUMBA_CACHE_DIR is set ({current})" if current
             else "numba was imported before fmus.common.jit")
    logging.getLogger(__name__).warning(
        "%s: the kernels of %s are compiled without numba's cache (a cache must be named by the "
        "package's content: %s)", cause, PACKAGE.name, wanted)
    return False


def export_name(function: Callable) -> str:
    """The name of the kernel ``function`` (its Python function) in the compiled module: its
    module's path inside the package and its own name, joined by ``__``
    (``common.kalman.time_update_kernel`` -> ``common__kalman__time_update_kernel``)."""
    module = function.__module__.split(".")[1:]
    return "__".join([*module, function.__name__])


@functools.lru_cache(maxsize=None)
def compiled_module() -> Any:
    """The package's ahead-of-time compiled kernels (``<package>/_compiled.<EXT_SUFFIX>``, made by
    :func:`compile_package` at ``flexfusion build``), or None: then the kernels are compiled
    just in time. A package whose module is there but does not import here (built for another
    Python or platform) says so once (a logging warning); one built without it (the build said
    why) and the working tree stay silent."""
    try:
        return importlib.import_module(f"{PACKAGE.name}.{COMPILED_MODULE}")
    except ImportError as exc:
        if any(PACKAGE.glob(COMPILED_MODULE + ".*")):
            logging.getLogger(__name__).warning(
                "%s: its ahead-of-time kernels do not load in this Python (%s): numba compiles them",
                PACKAGE.name, exc)
        return None


class PythonKernel:
    """A kernel with no ``aot`` signature (its Python function ``py_func``) in a package that runs
    its ahead-of-time compiled module: only compiled kernels call it, and they have it compiled
    in. Called from Python (a missing ``aot=``), it runs as plain Python, with one warning, so
    that numba stays unimported."""

    def __init__(self, py_func: Callable):
        self.py_func = py_func
        functools.update_wrapper(self, py_func)
        self._warned = False

    def __call__(self, *args: Any) -> Any:
        if not self._warned:
            self._warned = True
            logging.getLogger(__name__).warning(
                "kernel %s.%s is called from Python but has no aot= signature: it runs as plain "
                "Python (slow); give it @kernel(aot=...)", self.py_func.__module__, self.py_func.__name__)
        return self.py_func(*args)


def kernel(function: Callable | None = None, *, aot: str | None = None, **options: Any) -> Any:
    """``numba.njit`` with numba's on-disk cache (module docstring); ``@kernel`` or ``@kernel(...)``.

    ``function`` is the kernel (or None when options are given); ``options`` go to
    ``numba.njit`` (``cache=True`` is implied; ``fastmath`` stays off). A function with no source
    file behind it (code run from a string, e.g. a benchmark's baseline taken from git) is
    compiled without the cache: there is nothing to key it by.

    ``aot``: the numba signature of a kernel that Python code calls (e.g.
    ``"float64(float64[:], float64)"``; arrays any layout, ``float64[:]``, unless the kernel
    needs C order); a kernel that only other kernels call needs none. In a package with a
    compiled module (:func:`compiled_module`: an FMU built with a C compiler) the decorator
    returns the ahead-of-time function (numba is never imported) and a kernel without ``aot``
    a :class:`PythonKernel`; elsewhere the just-in-time dispatcher, with the signature kept as
    ``aot_signature`` for :func:`compile_package`.
    """
    def decorate(fn: Callable) -> Any:
        compiled = compiled_module()
        if compiled is not None:
            return getattr(compiled, export_name(fn)) if aot else PythonKernel(fn)
        cache = os.path.isfile(fn.__code__.co_filename) and _cached()
        import numba
        dispatcher = numba.njit(cache=cache, **options)(fn)
        dispatcher.aot_signature = aot
        return dispatcher
    return decorate if function is None else decorate(function)


def compile_package(output_dir: Path | None = None) -> list[str]:
    """Compile every kernel of this package that has an ``aot`` signature into one extension
    module, ``<output_dir>/_compiled.<EXT_SUFFIX>`` (default: the package's folder), with
    numba.pycc; needs a C compiler and linker. Run by ``flexfusion build`` in a process of its
    own (orchestration/build.py); the package must not have a compiled module yet.

    pycc compiles for the generic CPU of the architecture (no host-specific instructions: the
    FMU runs on any machine of the platform) with numba's defaults, as the JIT does (no
    ``fastmath``: no contraction into fused multiply-adds), so the compiled kernels round as
    the JIT ones (the tests compare them bit for bit).

    Returns
    -------
    list of str
        The export names, sorted.
    """
    from numba.core.registry import CPUDispatcher
    from numba.pycc import CC
    assert compiled_module() is None, "compile_package needs the just-in-time kernels"
    cc = CC(COMPILED_MODULE, source_module=__name__)
    cc.output_dir = str(output_dir or PACKAGE)
    exported: list[str] = []
    for source in package_sources(PACKAGE):
        if source.suffix != ".py" or "@kernel" not in source.read_text():
            continue
        module = importlib.import_module(
            ".".join((PACKAGE.name, *source.relative_to(PACKAGE).with_suffix("").parts)))
        for value in vars(module).values():
            if (isinstance(value, CPUDispatcher) and getattr(value, "aot_signature", None)
                    and value.py_func.__module__ == module.__name__):
                exported.append(export_name(value.py_func))
                cc.export(exported[-1], value.aot_signature)(value.py_func)
    cc.compile()
    return sorted(exported)

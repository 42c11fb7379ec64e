"""The compiled kernels: Cython modules of the ``fmus`` package, one way in every place they run.

A kernel module is a Cython source ``<name>.pyx`` beside the math module that uses it (e.g.
``fmus/robot_plant/six_axis_kernels.pyx``), loaded with :func:`load`
(``load("robot_plant.six_axis_kernels")``). Why Cython: ARCHITECTURE.md, "The kernel path".

* **In a built FMU** (a package with a ``BUNDLE_ID``) ``flexfusion build`` has compiled each
  kernel module beside its source (:func:`compiled`, the cache entry the working tree uses
  too, copied into the package): it is imported as any extension
  module, with no Cython and no compiler at run time. One that does not import there (an FMU
  built for another Python) is compiled as in the working tree, with one warning.
* **In the working tree** it is compiled on first use into the private cache
  (:mod:`fmus.common.native_cache`: ``<cache root>/kernels/<key>/``, verified before each load,
  set aside and compiled again if bad), ``key`` a hash of :func:`module_key`'s parts: the
  module's source, every ``.pxd``/``.pxi`` of the package (what it may cimport or include),
  Cython's version, the flags and this Python. Any of them changed: another entry, never a stale
  module. About 2-5 s of Cython and the C compiler, once per content.

Rules for kernel sources, so that a compiled module never depends on the package's name (in an
FMU the package is ``fmus_<hash>``): a callee shared between kernel modules is a ``cdef inline``
function in a ``.pxd`` (compiled into each user), never a cdef function cimported at run time
from another module; a ``.pxd`` is cimported by its path below the package
(``from common.gearbox cimport spring``), and a module is named by its file alone
(Cython's ``--module-name``), so the same source gives the same extension in every package.

Compiled with ``-O2 -ffp-contract=off`` and no ``-ffast-math``: floating point in source order,
no contraction into fused multiply-adds, so a kernel rounds as the same operations in Python
and numpy do (the tests hold each kernel to its readable numpy form).
"""
from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.machinery
import importlib.util
import logging
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path
from types import ModuleType
from typing import Callable

from fmus.common import native_cache

PACKAGE = Path(__file__).resolve().parent.parent      # ``fmus``, or ``fmus_<hash>`` in an FMU
BUNDLE_ID_FILE = "BUNDLE_ID"                          # marks a built FMU's package (orchestration/build.py)
CFLAGS = ["-O2", "-fPIC", "-shared", "-ffp-contract=off", "-fno-strict-aliasing"]
EXTENSION = importlib.machinery.EXTENSION_SUFFIXES[0]  # e.g. ``.cpython-311-x86_64-linux-gnu.so``


class KernelError(ImportError):
    """A kernel module could not be compiled or loaded (the message says which and why)."""


def sources(package: Path | None = None) -> list[Path]:
    """Every kernel module's source (``*.pyx``) below the package folder ``package`` (default:
    this package), sorted."""
    package = package or PACKAGE
    return sorted(p for p in package.rglob("*.pyx") if "__pycache__" not in p.parts)


def module_key(pyx: Path, package: Path | None = None) -> str:
    """The cache key (32 hex digits) of the kernel module ``pyx``: its text, every ``.pxd`` and
    ``.pxi`` of ``package`` (default: this package; path and text), Cython's version,
    :data:`CFLAGS` and this Python's extension suffix."""
    import Cython
    package = package or PACKAGE
    digest = hashlib.sha256(pyx.read_bytes())
    for f in sorted([*package.rglob("*.pxd"), *package.rglob("*.pxi")]):
        digest.update(f.relative_to(package).as_posix().encode() + b"\0" + f.read_bytes())
    digest.update("\0".join([Cython.__version__, *CFLAGS, EXTENSION, sys.platform]).encode())
    return digest.hexdigest()[:32]


def compile_module(pyx: Path, out: Path, package: Path | None = None) -> None:
    """Compile the kernel module ``pyx`` of the package folder ``package`` (default: this
    package) into the extension file ``out`` (Cython, then the system C compiler with
    :data:`CFLAGS`). A ``.pxd`` is cimported by its path below the package
    (``from common.gearbox cimport spring``); the module is named by its file alone, so that its
    code does not depend on the package's name (``fmus`` or ``fmus_<hash>``).

    Raises
    ------
    KernelError
        Cython or the C compiler is missing, or either failed (with its messages).
    """
    try:
        compiler = native_cache.c_compiler()
    except FileNotFoundError as exc:
        raise KernelError(f"{pyx.name}: {exc}") from None
    if importlib.util.find_spec("Cython") is None:
        raise KernelError(f"{pyx.name}: Cython is not installed (the kernels are compiled with it; "
                          "`make env` installs it)")
    with tempfile.TemporaryDirectory(prefix="ff_cython_") as tmp:
        c_file = Path(tmp) / (pyx.stem + ".c")
        steps = [[sys.executable, "-m", "cython", "-3", "--fast-fail", "-I", str(pyx.parent),
                  "-I", str(package or PACKAGE), "--module-name", pyx.stem, str(pyx), "-o", str(c_file)],
                 [*compiler, *CFLAGS, f"-I{sysconfig.get_paths()['include']}", str(c_file), "-o", str(out), "-lm"]]
        for command in steps:
            done = subprocess.run(command, capture_output=True, text=True)
            if done.returncode != 0:
                raise KernelError(f"compiling {pyx.name} failed ({' '.join(command[:3])} ...):\n"
                                  f"{done.stdout}{done.stderr}")


def _import_file(qualified: str, path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location(qualified, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    sys.modules[qualified] = module
    return module


def compiled(pyx: Path, package: Path | None = None, rebuild: bool = False,
             announce: Callable[[Path], None] | None = None) -> Path:
    """The extension file of the kernel module ``pyx`` of the package folder ``package``
    (default: this package): its entry in the private cache (``<cache root>/kernels/<key>/``,
    ``key`` :func:`module_key`), compiled now if it is not there or fails its check
    (:func:`fmus.common.native_cache.compiled`); ``announce(pyx)`` is called before it compiles.
    The working tree's :func:`load` and ``flexfusion build`` share the entries: a vendored copy of
    the same sources has the same key. ``rebuild``: compile it again whatever the entry is.

    Raises
    ------
    KernelError
        It could not be compiled (why).
    OSError
        No private, writable cache folder.
    """
    package = package or PACKAGE

    def make(out: Path) -> None:
        if announce is not None:
            announce(pyx)
        compile_module(pyx, out, package)
    return native_cache.compiled("kernels", module_key(pyx, package), pyx.stem + EXTENSION, make,
                                 f"kernel module {pyx.stem}", rebuild)


@functools.lru_cache(maxsize=None)
def load(name: str) -> ModuleType:
    """The compiled kernel module ``name`` (dotted, below the package: ``"robot_plant.six_axis_kernels"``),
    imported from a built FMU's package or compiled into the cache (module docstring).

    Raises
    ------
    KernelError
        It has no source, or could not be compiled or loaded (why).
    """
    qualified = f"{PACKAGE.name}.{name}"
    pyx = PACKAGE.joinpath(*name.split(".")).with_suffix(".pyx")
    if (PACKAGE / BUNDLE_ID_FILE).is_file():
        try:
            return importlib.import_module(qualified)
        except ImportError as exc:
            logging.getLogger(__name__).warning(
                "%s: its compiled kernels do not load in this Python (%s): compiled here", qualified, exc)
    if not pyx.is_file():
        raise KernelError(f"no kernel module {name}: {pyx} is not there")
    try:
        try:
            return _import_file(qualified, compiled(pyx))
        except ImportError:                          # checked, yet it does not load: once more
            return _import_file(qualified, compiled(pyx, rebuild=True))
    except KernelError:
        raise
    except (OSError, ImportError) as exc:
        raise KernelError(f"kernel module {name}: {exc}") from None


__all__ = ["KernelError", "compile_module", "compiled", "load", "module_key", "sources"]

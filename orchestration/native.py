"""Our native FMI layer: compile ``native/fmi2_python.c`` and put it into the FMUs.

pythonfmu 0.7 ships a prebuilt ``libpythonfmu-export.so`` with a use-after-free at interpreter
finalisation and a reference-count bug in every ``fmi2Instantiate`` (native/README.md). The
build step compiles our replacement with the system C compiler, once per content of its
sources (cached), and :func:`install_into` puts it into each FMU as
``binaries/linux64/<modelIdentifier>.so``.

The library is compiled against CPython's limited API (abi3) with this Python's headers and
does not link libpython: the host provides the interpreter (see native/README.md).
"""
from __future__ import annotations

import hashlib
import os
import shlex
import subprocess
import sys
import sysconfig
import tempfile
import zipfile
from pathlib import Path
from xml.etree import ElementTree

from fmus.common import native_cache
from orchestration.build import REPO, BuildError, rewritten

NATIVE = REPO / "native"
SOURCES = ("fmi2_python.c", "fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
LIBRARY_NAME = "libflexfusion_fmi2.so"
# the FMI 3.0 layer: fmi3_python.c includes the FMI 2.0 layer (native/README.md)
SOURCES3 = ("fmi3_python.c", "fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h", *SOURCES)
LIBRARY_NAME3 = "libflexfusion_fmi3.so"
# it exports the fmi3* functions only (the fmi2* ones it is built on stay internal)
VERSION_SCRIPT3 = "{ global: fmi3*; local: *; };\n"
DEFAULT_CACHE = REPO / "build" / "native"
PLATFORM = "linux64"
# (no -Werror: another compiler's new warnings must not stop a user's build; a test checks
# that this one gives none)
CFLAGS = ["-std=c11", "-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-Wall", "-Wextra"]


def c_compiler() -> list[str]:
    """The system C compiler as a command (:func:`fmus.common.native_cache.c_compiler`).

    Raises
    ------
    BuildError
        When none is installed.
    """
    try:
        return native_cache.c_compiler()
    except FileNotFoundError as exc:
        raise BuildError(f"{exc}: the native FMI layer needs one") from None


def python_include() -> Path:
    """The folder with this Python's ``Python.h``.

    Raises
    ------
    BuildError
        When the Python headers are not installed.
    """
    include = Path(sysconfig.get_paths()["include"])
    if not (include / "Python.h").is_file():
        version = f"{sys.version_info.major}.{sys.version_info.minor}"
        raise BuildError(f"Python headers not found ({include / 'Python.h'} is missing): the "
                         f"native FMI layer needs them (Debian/Ubuntu: apt-get install "
                         f"python{version}-dev)")
    return include


def build_library(cache: Path = DEFAULT_CACHE, fmi_version: str = "2") -> Path:
    """Compile the native FMI layer (``fmi_version`` "2": ``fmi2_python.c``; "3":
    ``fmi3_python.c``), or reuse the one compiled from the same sources.

    The cache key is the SHA-256 of the sources, the compiler command and flags and the
    Python headers' folder; a new library is compiled to a temporary name and renamed, so
    parallel builds never see half a file.

    Returns
    -------
    Path
        The shared library.

    Raises
    ------
    BuildError
        Not on Linux, no C compiler, no Python headers, or the compilation failed (with its
        output).
    """
    if not sys.platform.startswith("linux"):
        raise BuildError(f"the native FMI layer is built for Linux only (binaries/{PLATFORM}), "
                         f"not for {sys.platform}")
    if fmi_version not in ("2", "3"):
        raise BuildError(f"no native FMI layer for FMI {fmi_version} (2 or 3)")
    compiler = c_compiler()
    include = python_include()
    sources, name, main = ((SOURCES, LIBRARY_NAME, "fmi2_python.c") if fmi_version == "2"
                           else (SOURCES3, LIBRARY_NAME3, "fmi3_python.c"))
    digest = hashlib.sha256()
    for source in sources:
        digest.update(source.encode() + b"\0" + (NATIVE / source).read_bytes())
    command_key = [*compiler, *CFLAGS, str(include)]
    if fmi_version == "3":
        command_key.append(VERSION_SCRIPT3)
    digest.update("\0".join(command_key).encode())
    target = cache / digest.hexdigest()[:16] / name
    if target.is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp", suffix=".so", dir=target.parent)
    os.close(fd)
    command = [*compiler, *CFLAGS, f"-I{include}", f"-I{NATIVE}", str(NATIVE / main), "-o", tmp]
    script = None
    if fmi_version == "3":
        fd, script = tempfile.mkstemp(prefix=".tmp", suffix=".map", dir=target.parent)
        with os.fdopen(fd, "w") as f:
            f.write(VERSION_SCRIPT3)
        command.append(f"-Wl,--version-script={script}")
    result = subprocess.run(command, capture_output=True, text=True)
    if script:
        os.unlink(script)
    if result.returncode != 0:
        os.unlink(tmp)
        raise BuildError(f"compiling the native FMI layer failed ({shlex.join(command)}):\n"
                         f"{result.stdout}{result.stderr}")
    os.chmod(tmp, 0o755)
    os.replace(tmp, target)
    return target


def pythonfmu_library() -> Path:
    """pythonfmu's own prebuilt Linux library, which ours replaces (for comparisons)."""
    import pythonfmu
    return Path(pythonfmu.__file__).parent / "resources" / "binaries" / PLATFORM / "libpythonfmu-export.so"


def model_identifier(fmu: Path) -> str:
    """The co-simulation model identifier in an FMU's modelDescription.xml."""
    with zipfile.ZipFile(fmu) as z:
        root = ElementTree.fromstring(z.read("modelDescription.xml"))
    cs = root.find("CoSimulation")
    if cs is None:
        raise BuildError(f"{fmu.name}: no <CoSimulation> in its modelDescription.xml")
    return cs.get("modelIdentifier")


def install_into(fmu: Path, library: Path) -> None:
    """Replace the FMU's ``binaries/linux64/<modelIdentifier>.so`` with ``library`` (in place).

    Other platforms' binaries are left as they are.
    """
    member = f"binaries/{PLATFORM}/{model_identifier(fmu)}.so"
    with rewritten(fmu) as (src, dst):
        for info in src.infolist():
            if info.filename != member:
                dst.writestr(info, src.read(info))
        dst.write(library, member)


def compile_c_host(exe: Path, source: str = "fmi2_host.c") -> Path:
    """Compile ``native/<source>`` (by default ``fmi2_host.c``, the example C host; the tests
    also use ``fmi2_misuse_host.c``, a careless one) into ``exe``, linked to this Python's
    libpython so that an FMU's library finds the interpreter (native/README.md).

    Raises
    ------
    BuildError
        No C compiler, a Python without a shared libpython, or the compilation failed.
    """
    if not sysconfig.get_config_var("Py_ENABLE_SHARED"):
        raise BuildError("this Python has no shared libpython for a C host to link")
    libdir = sysconfig.get_config_var("LIBDIR")
    # --no-as-needed: the host calls no Python function itself, the FMU's library does
    command = [*c_compiler(), "-std=c11", "-O2", "-Wall", "-Wextra", "-Werror", f"-I{NATIVE}",
               str(NATIVE / source), "-o", str(exe), "-ldl", "-Wl,--no-as-needed",
               f"-L{libdir}", f"-lpython{sysconfig.get_config_var('LDVERSION')}",
               f"-Wl,-rpath,{libdir}"]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise BuildError(f"compiling the C host failed ({shlex.join(command)}):\n"
                         f"{result.stdout}{result.stderr}")
    return exe


def host_environment() -> dict[str, str]:
    """The environment of a C host whose embedded interpreter is this one: ``PYTHONHOME`` for
    the standard library, ``PYTHONPATH`` for this environment's site-packages (numpy, scipy)."""
    paths = sysconfig.get_paths()
    site = os.pathsep.join(dict.fromkeys([paths["purelib"], paths["platlib"]]))
    return dict(os.environ, PYTHONHOME=sys.base_prefix, PYTHONPATH=site)


__all__ = ["build_library", "c_compiler", "compile_c_host", "host_environment", "install_into",
           "model_identifier", "python_include", "pythonfmu_library"]

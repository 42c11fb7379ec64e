"""Build every FlexFusion FMU into ``dist/fmus`` and validate each with fmpy.

An FMU script is any ``fmus/<group>/*_fmu.py``; its model identifier is the name of its
FMU class. Each FMU carries ``resources/requirements.txt`` naming the third-party packages the
importer's Python must have, and ``resources/optional-requirements.txt`` those one feature needs
(the LogReplay FMU's HDF5 logs: h5py), imported only when used.

Self-contained FMUs in any Python host. A pythonfmu FMU runs in the host's interpreter, where a
package is imported once per process, from the first folder that provides it; hosts delete
extraction folders (fmpy's ``simulate_fmu`` does after each run), and two builds of our FMUs
may meet in one process (or the host has the working tree's ``fmus`` imported). So every FMU
bundles the ``fmus`` package vendored under a per-build name, ``fmus_<hash of its sources>``
(imports rewritten), and its script under ``<script>_<hash>``: FMUs of one build share one
identical copy, different builds never mix, and the host's own ``fmus`` is never used. The
script imports every module of its package when it loads, so nothing is imported later from a
folder that may be gone.

Start-up: every FMU carries its Python modules' bytecode for the building interpreter
(``__pycache__/<module>.<cache tag>.pyc``), hash-checked (PEP 552) so that it stays valid
whatever time the host's extraction gives the files: a fresh extraction folder needs no
compilation (about 0.1 s for the flagship's seven FMUs). Another Python version ignores it.

Compiled kernels: the package's numba kernels that Python calls (``@kernel(aot=...)``,
:mod:`fmus.common.jit`) are compiled ahead of time, once per build, into one extension module
of the vendored package (``fmus_<hash>/_compiled.<EXT_SUFFIX>``, the same file in every FMU), so
an FMU's process never imports numba nor compiles (:func:`compile_kernels`). It is kept in
``build/aot`` under a key of the sources and the toolchain and reused by the next build of the
same sources. If that compilation fails (or with ``FLEXFUSION_NO_AOT=1``) the build says why
and goes on: its FMUs compile their kernels with numba at run time, as the working tree does.
"""
from __future__ import annotations

import argparse
import hashlib
import importlib.metadata
import importlib.util
import marshal
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
import zipfile
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

from fmus.common.jit import BUNDLE_ID_FILE, COMPILED_MODULE, package_digest, package_sources

REPO = Path(__file__).resolve().parent.parent
FMU_SOURCES = REPO / "fmus"
DEFAULT_DEST = REPO / "dist" / "fmus"
AOT_CACHE = REPO / "build" / "aot"
# What the FMUs import besides the standard library and the bundled `fmus` package.
FMU_REQUIREMENTS = ["numpy>=1.26", "scipy>=1.11", "numba>=0.60"]
# What one feature imports when it is used (pyproject's optional dependencies).
FMU_OPTIONAL_REQUIREMENTS = ["h5py>=3.8"]


_CLASS = re.compile(r"^class (\w+)\(", re.M)
_STAGED_SCRIPT = re.compile(r"\w+_[0-9a-f]{12}")     # a script's module name (_stage_script)


class BuildError(RuntimeError):
    """An FMU failed to build or to validate."""


def fmu_scripts(root: Path = FMU_SOURCES) -> list[Path]:
    """Every FMU script below ``root``, sorted for a reproducible build order."""
    return sorted(p for p in root.glob("*/*_fmu.py"))


# `import fmus...` / `from fmus... import` statements, rewritten to the vendored name
_IMPORT = re.compile(r"^(\s*)(from|import)\s+fmus(?=[.\s])", re.M)


def _stage_package(stage: Path) -> Path:
    """Copy ``fmus`` into ``stage`` as ``fmus_<12 hex of its BUNDLE_ID>``, imports rewritten."""
    sources = package_sources(FMU_SOURCES)
    bundle_id = package_digest(FMU_SOURCES)       # also the key of the kernel cache (jit.py)
    target = stage / f"fmus_{bundle_id[:12]}"
    for f in sources:
        out = target / f.relative_to(FMU_SOURCES)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(_vendored(f.read_text(), target.name))
    (target / BUNDLE_ID_FILE).write_text(bundle_id + "\n")
    (stage / "requirements.txt").write_text("\n".join(FMU_REQUIREMENTS) + "\n")
    (stage / "optional-requirements.txt").write_text("\n".join(FMU_OPTIONAL_REQUIREMENTS) + "\n")
    return target


def compile_kernels(package: Path, cache: Path = AOT_CACHE, quiet: bool = False) -> Path | None:
    """Compile the staged ``package``'s kernels ahead of time into its folder (see the module
    docstring), or copy them from ``cache``; None, with the reason on stderr, when they cannot
    be compiled (then the FMUs compile them just in time).

    The compilation runs in a process of its own (the staged package in just-in-time mode:
    :func:`fmus.common.jit.compile_package`); the cache key is the package's bundle id, the
    numba and llvmlite versions, the Python ABI and the C compiler (``CC``).
    """
    module = COMPILED_MODULE + sysconfig.get_config_var("EXT_SUFFIX")
    if os.environ.get("FLEXFUSION_NO_AOT"):
        reason = "FLEXFUSION_NO_AOT is set"
    else:
        key = "\0".join([(package / BUNDLE_ID_FILE).read_text().strip(), package.name,
                         *(importlib.metadata.version(d) for d in ("numba", "llvmlite")),
                         sys.version, module, os.environ.get("CC", "")])
        target = cache / hashlib.sha256(key.encode()).hexdigest()[:16] / module
        t0 = time.perf_counter()
        if not target.is_file():
            target.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=target.parent) as out:
                code = (f"from pathlib import Path; from {package.name}.common import jit; "
                        f"jit.compile_package(Path({out!r}))")
                # a numba cache of its own: callees are linked in from their LLVM IR, never
                # from a JIT run's cached machine code
                env = {**os.environ, "PYTHONPATH": str(package.parent), "FLEXFUSION_CACHE_DIR": out}
                env.pop("NUMBA_DISABLE_JIT", None)
                done = subprocess.run([sys.executable, "-c", code], cwd=package.parent, env=env,
                                      capture_output=True, text=True)
                if done.returncode == 0:
                    os.replace(Path(out) / module, target)      # atomic: builds in parallel
        if target.is_file():
            shutil.copy2(target, package / module)
            if not quiet:
                print(f"  compiled kernels ({module}) {time.perf_counter() - t0:5.2f} s")
            return package / module
        lines = (done.stderr or done.stdout).strip().splitlines()
        reason = f"compilation failed: {lines[-1] if lines else f'exit status {done.returncode}'}"
    print(f"flexfusion build: no ahead-of-time kernels ({reason}); the FMUs compile their kernels "
          "with numba when they run", file=sys.stderr)
    return None


def _vendored(source: str, package: str) -> str:
    return _IMPORT.sub(rf"\1\2 {package}", source)


def _stage_script(script: Path, package: Path) -> Path:
    """The FMU script as it is bundled: imports rewritten, named after its content and package,
    and preceded by the import of every module of its package (see the module docstring)."""
    modules = sorted(".".join(f.relative_to(package.parent).with_suffix("").parts).removesuffix(".__init__")
                     for f in package.rglob("*.py"))
    preamble = ("# Added by orchestration/build.py: load this FMU's whole package now, so that no\n"
                "# module is imported later from an extraction folder the host may have deleted.\n"
                "import importlib as _importlib\n"
                f"for _module in {modules!r}:\n"
                "    _importlib.import_module(_module)\n")
    text = _vendored(script.read_text(), package.name)
    head, future, rest = text.partition("from __future__ import annotations\n")
    text = head + future + preamble + rest if future else preamble + text
    tag = hashlib.sha256((package.name + "\0" + text).encode()).hexdigest()[:12]
    staged = package.parent / f"{script.stem}_{tag}.py"
    staged.write_text(text)
    return staged


@contextmanager
def _installed_builder(package: str) -> Iterator[type]:
    """pythonfmu's ``FmuBuilder`` from the installed package, for the duration of a build.

    Once a pythonfmu FMU has run in this process, ``pythonfmu`` may be the copy bundled in that
    FMU's ``resources/`` (imported from there first), whose folder has no native binaries: its
    builder makes FMUs without them. Then the build imports the installed package afresh, and
    the vendored ``package`` and FMU scripts (``<script>_<hash>``) with it (an FMU of the same
    sources may have imported them on top of the bundled ``pythonfmu``); afterwards the modules
    the running FMUs use are put back.
    """
    import pythonfmu
    installed = Path(importlib.metadata.distribution("pythonfmu").locate_file("pythonfmu")).resolve()
    if Path(pythonfmu.__file__).resolve().parent == installed:
        from pythonfmu.builder import FmuBuilder
        yield FmuBuilder
        return

    def ours(name: str) -> bool:
        return (any(name == p or name.startswith(p + ".") for p in ("pythonfmu", package))
                or _STAGED_SCRIPT.fullmatch(name) is not None)
    saved = {n: sys.modules.pop(n) for n in [n for n in sys.modules if ours(n)]}
    sys.path.insert(0, str(installed.parent))        # ahead of any FMU's resources folder
    try:
        from pythonfmu.builder import FmuBuilder
        yield FmuBuilder
    finally:
        sys.path.remove(str(installed.parent))
        for n in [n for n in sys.modules if ours(n)]:
            del sys.modules[n]
        sys.modules.update(saved)


@contextmanager
def rewritten(fmu: Path) -> Iterator[tuple[zipfile.ZipFile, zipfile.ZipFile]]:
    """The FMU's archive to read and a new one to write, which replaces it (same permissions)
    when the block ends; on an error the FMU is left as it was."""
    fd, tmp = tempfile.mkstemp(prefix=".tmp", suffix=".fmu", dir=fmu.parent)
    os.close(fd)
    try:
        with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as dst:
            yield src, dst
        shutil.copymode(fmu, tmp)
        os.replace(tmp, fmu)
    except BaseException:
        os.unlink(tmp)
        raise


def add_bytecode(fmu: Path) -> None:
    """Add the hash-checked bytecode of every ``resources/**/*.py`` of ``fmu`` (in place), as
    the import system writes it: ``<folder>/__pycache__/<name>.<cache tag>.pyc``, PEP 552's
    header (magic number, flags 0b11 = checked hash, SipHash of the source) and the marshalled
    code. Python checks the hash at each import and compiles the source if it changed."""
    tag = sys.implementation.cache_tag
    with rewritten(fmu) as (src, dst):
        for info in src.infolist():
            data = src.read(info)
            dst.writestr(info, data)
            name = info.filename
            if name.startswith("resources/") and name.endswith(".py") and "/__pycache__/" not in name:
                folder, _, module = name.rpartition("/")
                code = compile(data, name, "exec", dont_inherit=True)
                pyc = (importlib.util.MAGIC_NUMBER + (0b11).to_bytes(4, "little")
                       + importlib.util.source_hash(data) + marshal.dumps(code))
                dst.writestr(f"{folder}/__pycache__/{module[:-3]}.{tag}.pyc", pyc)


def validate_fmu(path: Path) -> list[str]:
    """Problems fmpy finds in an FMU (empty when valid)."""
    from fmpy.validation import validate_fmu as fmpy_validate
    return list(fmpy_validate(str(path)))


def build_all(dest: Path = DEFAULT_DEST, only: list[str] | None = None, quiet: bool = False,
              scripts: list[Path] | None = None) -> list[Path]:
    """Build (and validate) every FMU, or those whose script stem or class is in ``only``
    (a name that is neither is an error, before anything is built).

    ``scripts`` replaces the FMU scripts found below ``fmus/`` (e.g. the test toys in
    ``tests/fmus``); they still bundle the ``fmus`` package.

    Raises
    ------
    BuildError
        Naming every FMU that failed to build or validate, with the reason.
    """
    from orchestration import native   # our FMI layer replaces pythonfmu's binary (native/README.md)
    scripts = fmu_scripts() if scripts is None else [Path(p) for p in scripts]
    classes = {p: _CLASS.findall(p.read_text()) for p in scripts}
    names = {p: {p.stem, *classes[p]} for p in scripts}
    unknown = sorted(set(only or ()) - set().union(*names.values()))
    if unknown:
        known = sorted(c for cs in classes.values() for c in cs)
        raise BuildError(f"no FMU named {', '.join(unknown)} (known: {', '.join(known)})")
    library = native.build_library()
    dest.mkdir(parents=True, exist_ok=True)
    built: list[Path] = []
    failures: list[str] = []
    with tempfile.TemporaryDirectory(prefix="flexfusion_stage_") as tmp, ExitStack() as stack:
        stage = Path(tmp)
        package = _stage_package(stage)
        compile_kernels(package, quiet=quiet)
        FmuBuilder = stack.enter_context(_installed_builder(package.name))  # noqa: N806 - a class
        for script in scripts:
            if only and not set(only) & names[script]:
                continue
            t0 = time.perf_counter()
            try:
                fmu = FmuBuilder.build_FMU(_stage_script(script, package), dest=dest,
                                           project_files=[package, stage / "requirements.txt",
                                                          stage / "optional-requirements.txt"])
            except Exception as exc:  # noqa: BLE001 - collect and report every failure at once
                failures.append(f"{_shown(script)}: build failed: {type(exc).__name__}: {exc}")
                continue
            native.install_into(Path(fmu), library)
            add_bytecode(Path(fmu))
            problems = validate_fmu(Path(fmu))
            if problems:
                failures.append(f"{Path(fmu).name}: fmpy validate: " + "; ".join(problems))
            built.append(Path(fmu))
            if not quiet:
                status = "INVALID" if problems else "ok"
                print(f"  {Path(fmu).name:<28} {status:<8} {time.perf_counter() - t0:5.2f} s")
    if failures:
        raise BuildError("FMU build failed:\n  " + "\n  ".join(failures))
    return built


def _shown(script: Path) -> str:
    try:
        return str(script.resolve().relative_to(REPO))
    except ValueError:
        return str(script)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="flexfusion build", description=__doc__.splitlines()[0])
    parser.add_argument("--dest", type=Path, default=DEFAULT_DEST, help="output folder (default dist/fmus)")
    parser.add_argument("only", nargs="*", help="build only these FMUs (class or script name)")
    args = parser.parse_args(argv)
    try:
        built = build_all(args.dest, args.only or None)
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"built and validated {len(built)} FMUs in {args.dest}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

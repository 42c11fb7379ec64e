"""Build every FlexFusion FMU into ``dist/fmus`` and validate each with fmpy (FMI 2.0, and 3.0 on request).

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
:mod:`fmus.common.jit`) are compiled ahead of time into one extension module of the vendored
package (``fmus_<hash>/_compiled.<EXT_SUFFIX>``, the same file in every FMU), so an FMU's
process never imports numba nor compiles (:func:`compile_kernels`). It is kept in ``build/aot``
under a key of the sources it is made of (:func:`kernel_sources`: the modules with kernels and
what they import from the package, not the whole package) and of the toolchain, and reused by
every build of the same kernels: the next ``flexfusion build``, the test suite's build
(tests/conftest.py), another package name. If that compilation fails (or with
``FLEXFUSION_NO_AOT=1``) the build says why and goes on: its FMUs compile their kernels with
numba at run time, as the working tree does.

FMI 3.0 (``--fmi 3`` or ``both``; :func:`build_all`'s ``fmi``): each FMU's FMI 2.0 FMU
translated by :mod:`orchestration.fmi3` into ``<dest>/fmi3/<model>.fmu`` (its modelDescription
in FMI 3.0, our FMI 3.0 layer as its binary, ``resources/`` as they are).

Cython kernels (:mod:`fmus.common.cython_kernels`; the kernels move there from numba, module by
module: ARCHITECTURE.md, "The kernel path"): every ``*.pyx`` of the package is compiled and its
extension put beside its source in the vendored package, where the FMU imports it
(:func:`compile_cython`). Each is the private cache's entry of its content, the one the working
tree's kernels use too, so it is compiled once per content for every build, the test suite's and
the working tree; the build says which it compiles. Both compiled forms coexist while numba
kernels remain.

Incremental: the destination folder keeps a manifest (:data:`MANIFEST`) of what each FMU was
made of (its script, the vendored package, the compiled kernels, the Cython kernels, the native
FMI layer, this build script and the tools' versions, each by content) and of the FMU file's own hash; an FMU
whose parts and file are unchanged is not built again, and the build says why it rebuilds the
others (:func:`build_all`). Nothing changed: one line, in about a second.
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

import ast
import json

from fmus.common import cython_kernels
from fmus.common.jit import BUNDLE_ID_FILE, COMPILED_MODULE, package_digest, package_sources

REPO = Path(__file__).resolve().parent.parent
FMU_SOURCES = REPO / "fmus"
DEFAULT_DEST = REPO / "dist" / "fmus"
AOT_CACHE = REPO / "build" / "aot"
MANIFEST = ".flexfusion-build.json"        # in the destination folder (build_all)
# the sources of the build itself: a change rebuilds every FMU
BUILD_SCRIPTS = [REPO / "orchestration" / "build.py", REPO / "orchestration" / "native.py"]
FMI3_SCRIPT = REPO / "orchestration" / "fmi3.py"     # the FMI 3.0 translation: its FMUs' part only
# What the FMUs import besides the standard library and the bundled `fmus` package.
FMU_REQUIREMENTS = ["numpy>=1.26", "scipy>=1.11", "numba>=0.60"]
# What one feature imports when it is used (pyproject's optional dependencies).
# Cython: only where an FMU's compiled kernels do not load (built for another Python), to compile them
FMU_OPTIONAL_REQUIREMENTS = ["h5py>=3.8", "cython>=3"]


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


def kernel_sources(package: Path) -> list[Path]:
    """The sources below the package folder ``package`` that its compiled kernels are made of:
    every module with a kernel (``@kernel``), each module of the package they import,
    transitively (``import``/``from ... import``, absolute or relative, at any depth of the
    code), and the ``__init__.py`` of every package on the way; sorted. A kernel's globals and
    callees come from these modules only (numba freezes them when it compiles); kernels raise
    only built-in exceptions (tests/test_aot.py), so nothing of the package's name is compiled
    in."""
    sources = {".".join(f.relative_to(package.parent).with_suffix("").parts).removesuffix(".__init__"): f
               for f in package_sources(package) if f.suffix == ".py"}
    todo = [m for m, f in sources.items() if "@kernel" in f.read_text()]
    seen: set[str] = set()
    while todo:
        module = todo.pop()
        if module in seen or module not in sources:
            continue
        seen.add(module)
        parts = module.split(".")
        todo.extend(".".join(parts[:i]) for i in range(1, len(parts)))      # its packages
        own = parts if sources[module].name == "__init__.py" else parts[:-1]
        for node in ast.walk(ast.parse(sources[module].read_text())):
            if isinstance(node, ast.Import):
                todo.extend(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = ".".join([*own[:len(own) - node.level + 1], *([node.module] if node.module else [])]
                                ) if node.level else node.module or ""
                todo.append(base)
                todo.extend(f"{base}.{a.name}" for a in node.names)
    return sorted(sources[m] for m in seen)


def kernel_digest(package: Path) -> str:
    """SHA-256 (hex) of :func:`kernel_sources` of ``package``: each one's path and text, the
    package's name read as ``fmus`` (the working tree and every vendored copy of the same
    sources have one digest)."""
    name = re.compile(rf"\b{re.escape(package.name)}\b")
    digest = hashlib.sha256()
    for f in kernel_sources(package):
        digest.update(f.relative_to(package).as_posix().encode() + b"\0"
                      + name.sub("fmus", f.read_text()).encode() + b"\0")
    return digest.hexdigest()


def kernels_key(package: Path) -> str | None:
    """The key of ``package``'s compiled kernels in the cache (:func:`kernel_digest`, the numba
    and llvmlite versions, the Python version, the extension suffix and ``$CC``), or None with
    ``FLEXFUSION_NO_AOT`` set."""
    if os.environ.get("FLEXFUSION_NO_AOT"):
        return None
    key = "\0".join([kernel_digest(package), *(importlib.metadata.version(d) for d in ("numba", "llvmlite")),
                     sys.version, sysconfig.get_config_var("EXT_SUFFIX"), os.environ.get("CC", "")])
    return hashlib.sha256(key.encode()).hexdigest()[:16]


_AOT_SIGNATURE = re.compile(r"@kernel\(\s*aot=")


def compile_kernels(package: Path, cache: Path = AOT_CACHE, quiet: bool = False) -> Path | None:
    """Compile the staged ``package``'s kernels ahead of time into its folder (see the module
    docstring), or copy them from ``cache``; None, with the reason on stderr, when they cannot
    be compiled (then the FMUs compile them just in time).

    The compilation runs in a process of its own (the staged package in just-in-time mode:
    :func:`fmus.common.jit.compile_package`); the cache key is :func:`kernels_key`. Unless
    ``quiet``, it says what it compiles and how long the last compilation took (kept in
    ``cache``), then how long this one took.
    """
    module = COMPILED_MODULE + sysconfig.get_config_var("EXT_SUFFIX")
    key = kernels_key(package)
    if key is None:
        reason = "FLEXFUSION_NO_AOT is set"
    else:
        target = cache / key / module
        t0 = time.perf_counter()
        if not target.is_file():
            if not quiet:
                n = sum(len(_AOT_SIGNATURE.findall(f.read_text())) for f in kernel_sources(package))
                last = cache / "last_compile_s"
                took = (f"the last compilation took {float(last.read_text()):.0f} s" if last.is_file()
                        else "about 1-2 min on an idle machine, several under load")
                print(f"  compiling {n} kernels ahead of time (numba.pycc; {took}) ...", flush=True)
            target.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=target.parent) as out:
                code = (f"from pathlib import Path; from {package.name}.common import jit; "
                        f"jit.compile_package(Path({out!r}))")
                # a numba cache of its own (numba's NUMBA_CACHE_DIR: nothing written into the
                # staged package): callees are linked in from their LLVM IR, never from a JIT
                # run's cached machine code
                env = {**os.environ, "PYTHONPATH": str(package.parent), "FLEXFUSION_CACHE_DIR": out,
                       "NUMBA_CACHE_DIR": out}
                env.pop("NUMBA_DISABLE_JIT", None)
                done = subprocess.run([sys.executable, "-c", code], cwd=package.parent, env=env,
                                      capture_output=True, text=True)
                if done.returncode == 0:
                    os.replace(Path(out) / module, target)      # atomic: builds in parallel
                    _write_atomically(cache / "last_compile_s", f"{time.perf_counter() - t0:.1f}\n")
            if not quiet and target.is_file():
                print(f"  compiled the kernels ({module}) in {time.perf_counter() - t0:.1f} s")
        elif not quiet:
            print(f"  kernels unchanged: {module} from {_shown(target.parent)}")
        if target.is_file():
            shutil.copy2(target, package / module)
            return package / module
        lines = (done.stderr or done.stdout).strip().splitlines()
        reason = f"compilation failed: {lines[-1] if lines else f'exit status {done.returncode}'}"
    print(f"flexfusion build: no ahead-of-time kernels ({reason}); the FMUs compile their kernels "
          "with numba when they run", file=sys.stderr)
    return None


def cython_key(package: Path) -> str:
    """The key of ``package``'s Cython kernel modules: each one's path and
    :func:`fmus.common.cython_kernels.module_key` (its source, every ``.pxd``/``.pxi``, Cython's
    version, the flags, the Python), hashed; the working tree and every vendored copy of the
    same sources have one key."""
    digest = hashlib.sha256()
    for pyx in cython_kernels.sources(package):
        digest.update(pyx.relative_to(package).as_posix().encode() + b"\0"
                      + cython_kernels.module_key(pyx, package).encode() + b"\0")
    return digest.hexdigest()[:16]


def compile_cython(package: Path, quiet: bool = False) -> list[Path]:
    """Compile every Cython kernel module of the staged ``package``
    (:func:`fmus.common.cython_kernels.sources`) and put its extension beside its source, where
    :func:`fmus.common.cython_kernels.load` imports it in the FMU. Each is the entry of the
    private cache that the working tree's kernels use too (keyed by its content:
    :func:`fmus.common.cython_kernels.compiled`), so a module is compiled once per content for
    every build, the test suite's and the working tree. Unless ``quiet``, says which it
    compiles and how long each took, or that none changed.

    Returns
    -------
    list of Path
        The extension files in ``package``, in the order of the sources.

    Raises
    ------
    BuildError
        A module could not be compiled (Cython's or the compiler's messages): its FMUs could
        not run it either.
    """
    extensions, made = [], []
    for pyx in cython_kernels.sources(package):
        name = pyx.relative_to(package).as_posix()
        t0 = time.perf_counter()

        def announce(_: Path, name: str = name) -> None:
            made.append(name)
            if not quiet:
                print(f"  compiling {name} (Cython and the C compiler; a few seconds idle, more "
                      "under load) ...", flush=True)
        try:
            entry = cython_kernels.compiled(pyx, package, announce=announce)
        except (cython_kernels.KernelError, OSError) as exc:
            raise BuildError(f"the kernel module {name}: {exc}") from None
        if not quiet and made and made[-1] == name:
            print(f"  compiled {name} in {time.perf_counter() - t0:.1f} s")
        extensions.append(pyx.with_name(entry.name))
        shutil.copy2(entry, extensions[-1])
    if not quiet and extensions and not made:
        print(f"  Cython kernels unchanged: {len(extensions)} modules from the cache")
    return extensions


def _write_atomically(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=".tmp", dir=path.parent)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)


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
              scripts: list[Path] | None = None, fmi: tuple[str, ...] = ("2",)) -> list[Path]:
    """Build (and validate) every FMU, or those whose script stem or class is in ``only``
    (a name that is neither is an error, before anything is built); an FMU whose parts are
    unchanged since it was built into ``dest`` is kept (the module docstring). Unless
    ``quiet``, says what it builds and why, or that nothing changed.

    ``scripts`` replaces the FMU scripts found below ``fmus/`` (e.g. the test toys in
    ``tests/fmus``); they still bundle the ``fmus`` package.

    ``fmi`` names the FMI versions to build: ``"2"`` (``dest/<model>.fmu``) and/or ``"3"``
    (``dest/fmi3/<model>.fmu``: the FMI 2.0 FMU translated, :mod:`orchestration.fmi3`).

    Returns
    -------
    list of Path
        Every selected FMU, built now or kept: for each version of ``fmi`` in turn, in the
        order of the scripts.

    Raises
    ------
    BuildError
        Naming every FMU that failed to build or validate, with the reason.
    """
    from orchestration import native   # our FMI layer replaces pythonfmu's binary (native/README.md)
    t_start = time.perf_counter()
    versions = tuple(dict.fromkeys(fmi))
    if not versions or set(versions) - {"2", "3"}:
        raise BuildError(f"FMI version {', '.join(versions) or '(none)'}: this build makes FMI 2 and/or 3")
    scripts = fmu_scripts() if scripts is None else [Path(p) for p in scripts]
    classes = {p: _CLASS.findall(p.read_text()) for p in scripts}
    names = {p: {p.stem, *classes[p]} for p in scripts}
    unknown = sorted(set(only or ()) - set().union(*names.values()))
    if unknown:
        known = sorted(c for cs in classes.values() for c in cs)
        raise BuildError(f"no FMU named {', '.join(unknown)} (known: {', '.join(known)})")
    selected = [p for p in scripts if not only or set(only) & names[p]]
    library = native.build_library()
    library3 = native.build_library(fmi_version="3") if "3" in versions else None
    dest.mkdir(parents=True, exist_ok=True)
    manifest = _read_manifest(dest)
    common = {"build": _digest(*BUILD_SCRIPTS), "tools": _tools(), "native": library.parent.name,
              "package": package_digest(FMU_SOURCES), "kernels": kernels_key(FMU_SOURCES) or "none",
              "cython": cython_key(FMU_SOURCES)}
    # what each (script, version) is made of; an FMI 3.0 FMU also of the FMI 3.0 layer and its
    # translation (orchestration/fmi3.py), which the FMI 2.0 ones are not rebuilt for
    jobs = [(p, v) for v in versions for p in selected]
    parts = {(p, v): {**common, "script": _digest(p)} if v == "2" else
             {**common, "script": _digest(p), "fmi3": library3.parent.name + ":" + _digest(FMI3_SCRIPT)}
             for p, v in jobs}
    kept: dict[tuple[Path, str], Path] = {}
    reasons: dict[tuple[Path, str], str] = {}
    for job in jobs:
        entry = manifest.get(_manifest_key(*job))
        reason = _stale(dest, entry, parts[job])
        if reason is None:
            kept[job] = dest / entry["fmu"]
        else:
            reasons[job] = reason
    if not reasons:
        if not quiet:
            print(f"nothing changed: {len(kept)} FMUs up to date in {dest} "
                  f"({time.perf_counter() - t_start:.1f} s)")
        return [kept[job] for job in jobs]
    if not quiet and kept:
        print(f"  {len(kept)} FMUs up to date, {len(reasons)} to build")
    built: dict[tuple[Path, str], Path] = {}
    failures: list[str] = []
    with tempfile.TemporaryDirectory(prefix="flexfusion_stage_") as tmp, ExitStack() as stack:
        stage = Path(tmp)
        package = _stage_package(stage)
        aot = compile_kernels(package, quiet=quiet) is not None
        compile_cython(package, quiet=quiet)
        FmuBuilder = stack.enter_context(_installed_builder(package.name))  # noqa: N806 - a class
        for script in selected:
            todo = [v for v in versions if (script, v) in reasons]
            if not todo:
                continue
            t0 = time.perf_counter()
            # the FMI 2.0 FMU: into dest if it is wanted, else (FMI 3.0 only) into the stage
            if "2" in todo:
                out = dest
            elif (script, "2") in kept:
                out = None
            else:
                out = stage / "fmi2"
                out.mkdir(exist_ok=True)
            if out is None:
                fmu2 = kept[(script, "2")]
            else:
                try:
                    fmu2 = Path(FmuBuilder.build_FMU(_stage_script(script, package), dest=out,
                                                     project_files=[package, stage / "requirements.txt",
                                                                    stage / "optional-requirements.txt"]))
                except Exception as exc:  # noqa: BLE001 - collect and report every failure at once
                    failures.append(f"{_shown(script)}: build failed: {type(exc).__name__}: {exc}")
                    continue
                native.install_into(fmu2, library)
                add_bytecode(fmu2)
            for version in todo:
                job = (script, version)
                if version == "2":
                    fmu = fmu2
                else:
                    from orchestration import fmi3
                    fmu = dest / "fmi3" / fmu2.name
                    try:
                        fmi3.convert(fmu2, fmu, library3)
                    except Exception as exc:  # noqa: BLE001
                        failures.append(f"{_shown(script)}: FMI 3.0: {type(exc).__name__}: {exc}")
                        continue
                problems = validate_fmu(fmu)
                if problems:
                    failures.append(f"{fmu.relative_to(dest)}: fmpy validate: " + "; ".join(problems))
                elif aot or common["kernels"] == "none":      # a failed compilation is tried again
                    manifest[_manifest_key(*job)] = {"fmu": fmu.relative_to(dest).as_posix(),
                                                     "sha256": _digest(fmu), "parts": parts[job]}
                built[job] = fmu
                if not quiet:
                    status = "INVALID" if problems else "ok"
                    print(f"  {str(fmu.relative_to(dest)):<28} {status:<8} {time.perf_counter() - t0:5.2f} s   "
                          f"({reasons[job]})")
    _write_atomically(dest / MANIFEST, json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    if not quiet and not failures:
        print(f"built and validated {len(built)} FMUs, {len(kept)} kept, in {dest} "
              f"({time.perf_counter() - t_start:.1f} s)")
    if failures:
        raise BuildError("FMU build failed:\n  " + "\n  ".join(failures))
    return [built.get(job) or kept[job] for job in jobs]


def _manifest_key(script: Path, version: str) -> str:
    """A (script, FMI version)'s key in the manifest: the FMI 2.0 FMU's is the script's path
    (as before FMI 3.0 was built), the FMI 3.0 one's the path and `` fmi3``."""
    return str(script.resolve()) + ("" if version == "2" else " fmi3")


_CHANGED = {"script": "its script changed", "package": "the fmus package changed",
            "kernels": "the compiled kernels changed", "cython": "the Cython kernels changed",
            "native": "the native FMI layer changed",
            "build": "the build script changed", "tools": "pythonfmu or Python changed",
            "fmi3": "the FMI 3.0 layer changed"}


def _stale(dest: Path, entry: dict | None, parts: dict[str, str]) -> str | None:
    """Why the FMU of the manifest's ``entry`` must be built again for ``parts``, or None."""
    if entry is None:
        return "new"
    for part, why in _CHANGED.items():
        if entry["parts"].get(part) != parts.get(part):
            return why
    try:
        if _digest(dest / entry["fmu"]) == entry["sha256"]:
            return None
    except OSError:
        return "its file is missing"
    return "its file was changed"


def _read_manifest(dest: Path) -> dict[str, dict]:
    """The build manifest of ``dest`` (script path -> FMU file, its hash, its parts); empty
    when there is none or it does not read (everything is built again)."""
    try:
        manifest = json.loads((dest / MANIFEST).read_text())
        return manifest if isinstance(manifest, dict) else {}
    except (OSError, ValueError):
        return {}


def _digest(*files: Path) -> str:
    digest = hashlib.sha256()
    for f in files:
        digest.update(f.read_bytes())
    return digest.hexdigest()


def _tools() -> str:
    """The versions of what makes an FMU besides our sources: pythonfmu's builder, the Python
    of the bytecode (:func:`add_bytecode`)."""
    return f"pythonfmu {importlib.metadata.version('pythonfmu')}; {sys.implementation.cache_tag}"


def _shown(script: Path) -> str:
    try:
        return str(script.resolve().relative_to(REPO))
    except ValueError:
        return str(script)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="flexfusion build", description=__doc__.splitlines()[0])
    parser.add_argument("--dest", type=Path, default=DEFAULT_DEST, help="output folder (default dist/fmus)")
    parser.add_argument("--fmi", choices=["2", "3", "both"], default="2",
                        help="FMI version: 2 (default: dest/<model>.fmu), 3 (dest/fmi3/<model>.fmu) or both")
    parser.add_argument("only", nargs="*", help="build only these FMUs (class or script name)")
    args = parser.parse_args(argv)
    try:
        build_all(args.dest, args.only or None,       # it says what it did
                  fmi=("2", "3") if args.fmi == "both" else (args.fmi,))
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The FMU build (orchestration/build.py)."""
from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import re
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

from orchestration.build import BUNDLE_ID_FILE, FMU_REQUIREMENTS, BuildError, build_all
from toys import TOYS

REPO = Path(__file__).resolve().parent.parent

AFTER_AN_FMU_RAN = """
import sys, zipfile
from pathlib import Path
from fmpy import simulate_fmu
simulate_fmu(sys.argv[1], stop_time=0.003, step_size=0.001)
import pythonfmu
bundled = 'resources' in Path(pythonfmu.__file__).parts
from orchestration.build import build_all
fmu, = build_all(Path(sys.argv[2]), only=["Encoder"], quiet=True)
binaries = [n for n in zipfile.ZipFile(fmu).namelist() if n.startswith("binaries/")]
print(bundled, len(binaries))
"""


def test_build_after_an_fmu_ran_in_the_process_has_binaries(tmp_path, every_fmu) -> None:
    """After an FMU ran, 'pythonfmu' resolves to its bundled copy (no binaries); the build must
    still use the installed package's builder (fresh process: pytest has imported the builder)."""
    encoder = every_fmu["Encoder"]
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", AFTER_AN_FMU_RAN, str(encoder), str(tmp_path)],
                         capture_output=True, text=True, timeout=120, cwd=REPO, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    bundled, n_binaries = out.stdout.split()
    assert bundled == "True"          # the situation under test did arise
    assert int(n_binaries) > 0


def test_an_unknown_fmu_name_is_refused_naming_the_known_ones(tmp_path, capsys) -> None:
    from orchestration import build
    assert build.main(["--dest", str(tmp_path), "Encoder", "NoSuchFmu"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: no FMU named NoSuchFmu (known: AccelerationObserver, ")
    assert "Encoder" in err and "FlexibleRobot2DOF" in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []                 # nothing built, not even the Encoder


def test_every_fmu_bundles_one_vendored_package_named_by_its_hash(every_fmu) -> None:
    """All FMUs of a build carry the same ``fmus_<12 hex>`` package (imports rewritten, the hash
    in BUNDLE_ID), their script under ``<script>_<12 hex>``, and the requirements."""
    bundles = set()
    for name, fmu in every_fmu.items():
        with zipfile.ZipFile(fmu) as z:
            files = z.namelist()
            packages = {f.split("/")[1] for f in files if re.fullmatch(r"resources/fmus_[0-9a-f]{12}/.*", f)}
            assert len(packages) == 1, name
            package = packages.pop()
            bundle_id = z.read(f"resources/{package}/{BUNDLE_ID_FILE}").decode().strip()
            assert re.fullmatch(r"[0-9a-f]{64}", bundle_id) and package == f"fmus_{bundle_id[:12]}", name
            sources = [f for f in files if f.startswith("resources/") and f.endswith(".py")]
            assert any(re.fullmatch(r"resources/\w+_fmu_[0-9a-f]{12}\.py", f) for f in sources), name
            for f in sources:
                assert not re.search(r"^\s*(from|import)\s+fmus[.\s]", z.read(f).decode(), re.M), f
            assert z.read("resources/requirements.txt").decode().split() == FMU_REQUIREMENTS
        bundles.add(package)
    assert len(bundles) == 1


def test_only_picks_by_script_or_class_name_and_a_broken_script_is_named(tmp_path) -> None:
    built = build_all(tmp_path / "a", quiet=True, scripts=sorted(TOYS.glob("*_fmu.py")),
                      only=["gain_fmu", "MassSpring"])
    assert sorted(p.name for p in built) == ["Gain.fmu", "MassSpring.fmu"]
    broken = tmp_path / "broken_fmu.py"
    broken.write_text("from fmus.common.fmi import FlexFusionSlave\n\n\n"
                      "class Broken(FlexFusionSlave):\n    description = (\n")
    with pytest.raises(BuildError, match=r"broken_fmu.py: build failed: .*SyntaxError"):
        build_all(tmp_path / "b", quiet=True, scripts=[broken, TOYS / "gain_fmu.py"])
    assert (tmp_path / "b" / "Gain.fmu").is_file()       # the others still build


def test_cli_build_reports_a_failure_in_one_line_with_exit_2(tmp_path, monkeypatch, capsys) -> None:
    import orchestration.build as build

    def failing(*args, **kwargs):
        raise BuildError("FMU build failed:\n  x_fmu.py: build failed: boom")
    monkeypatch.setattr(build, "build_all", failing)
    assert build.main(["--dest", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: FMU build failed:")


def test_every_python_file_of_an_fmu_comes_with_valid_hash_checked_bytecode(every_fmu, tmp_path) -> None:
    """A fresh extraction folder imports without compiling: each ``resources/**.py`` has its
    ``__pycache__`` file for this interpreter, which the import system loads as it is (its
    hash matches the source) and which holds the source's code."""
    fmu = every_fmu["Encoder"]
    with zipfile.ZipFile(fmu) as z:
        sources = [f for f in z.namelist() if f.startswith("resources/") and f.endswith(".py")]
        z.extractall(tmp_path)
    assert len(sources) > 40
    for name in sources:
        path = tmp_path / name
        cached = Path(importlib.util.cache_from_source(str(path)))
        data = cached.read_bytes()
        assert data[:4] == importlib.util.MAGIC_NUMBER and int.from_bytes(data[4:8], "little") == 0b11, name
        assert data[8:16] == importlib.util.source_hash(path.read_bytes()), name
        code = NotCompiling(path.stem, str(path)).get_code(path.stem)       # the bytecode's
        assert code == compile(path.read_bytes(), str(path), "exec", dont_inherit=True), name
    # a changed source is compiled again, not served from the stale bytecode
    script = next(tmp_path.glob("resources/encoder_fmu_*.py"))
    script.write_text(script.read_text() + "\nCHANGED = 1\n")
    with pytest.raises(AssertionError, match="compiles"):
        NotCompiling(script.stem, str(script)).get_code(script.stem)


class NotCompiling(importlib.machinery.SourceFileLoader):
    """The import system's loader of a source file, failing where it would compile it."""

    def source_to_code(self, data, path, *, _optimize=-1):
        raise AssertionError(f"{path}: the import compiles the source")


def test_a_second_build_in_a_row_keeps_every_fmu_says_so_and_is_quick(every_fmu, tmp_path, capsys) -> None:
    """``flexfusion build`` into the suite's own build folder (its manifest): nothing changed,
    one line, under 10 s (the 19 FMUs' packaging and validation is skipped, 12-88 s before);
    every FMU file untouched."""
    from orchestration import build
    dest = next(iter(every_fmu.values())).parent
    stamps = {p: p.stat().st_mtime_ns for p in dest.glob("*.fmu")}
    capsys.readouterr()
    t0 = time.perf_counter()
    assert build.main(["--dest", str(dest)]) == 0
    took = time.perf_counter() - t0
    out = capsys.readouterr().out
    assert out.startswith(f"nothing changed: {len(every_fmu)} FMUs up to date in {dest} (") and out.count("\n") == 1
    assert took < 10.0
    assert {p: p.stat().st_mtime_ns for p in dest.glob("*.fmu")} == stamps


def test_a_build_rebuilds_only_the_fmus_whose_parts_changed_and_says_why(every_fmu, tmp_path, capsys) -> None:
    """Toy scripts (copies): a changed script rebuilds its FMU only; an FMU file changed or
    removed in the folder is built again; the kernels are never compiled again: the suite's
    build compiled them (every_fmu), and every other build of the same sources reuses them."""
    scripts = []
    for name in ("gain_fmu.py", "mass_spring_fmu.py", "source_fmu.py"):
        scripts.append(tmp_path / name)
        scripts[-1].write_text((TOYS / name).read_text())
    dest = tmp_path / "fmus"
    first = build_all(dest, scripts=scripts)
    out = capsys.readouterr().out
    assert "(new)" in out and "compiling" not in out           # kernels: the suite's cache
    assert [p.name for p in first] == ["Gain.fmu", "MassSpring.fmu", "Source.fmu"]
    scripts[0].write_text(scripts[0].read_text() + "\n# changed\n")
    (dest / "Source.fmu").write_bytes((dest / "Source.fmu").read_bytes() + b"\0")
    (dest / "MassSpring.fmu").unlink()
    again = build_all(dest, scripts=scripts)
    out = capsys.readouterr().out
    assert again == first
    assert re.search(r"Gain\.fmu +ok .*\(its script changed\)", out)
    assert re.search(r"MassSpring\.fmu +ok .*\(its file is missing\)", out)
    assert re.search(r"Source\.fmu +ok .*\(its file was changed\)", out)
    assert "kernels unchanged" in out
    build_all(dest, scripts=scripts)
    assert capsys.readouterr().out.startswith("nothing changed: 3 FMUs up to date")


def test_kernel_sources_are_the_kernels_modules_and_what_they_import(tmp_path) -> None:
    """The compiled kernels' key covers the modules with kernels, their imports from the
    package (absolute, relative, inside functions; transitively) and the packages on the
    way; nothing else."""
    from orchestration.build import kernel_digest, kernel_sources
    pkg = tmp_path / "fmus_x"
    files = {"__init__.py": "", "a/__init__.py": "", "b/__init__.py": "",
             "a/kern.py": "from . import helper\nfrom fmus_x.a.consts import C\n@kernel\ndef k(): pass\n",
             "a/helper.py": "def f():\n    from ..b import deep\n",
             "a/consts.py": "C = 1\n", "b/deep.py": "X = 2\n", "b/other.py": "import fmus_x.a.kern\n",
             "a/unused.py": "Y = 3\n"}
    for name, text in files.items():
        (pkg / name).parent.mkdir(parents=True, exist_ok=True)
        (pkg / name).write_text(text)
    assert [p.relative_to(pkg).as_posix() for p in kernel_sources(pkg)] == [
        "__init__.py", "a/__init__.py", "a/consts.py", "a/helper.py", "a/kern.py", "b/__init__.py", "b/deep.py"]
    before = kernel_digest(pkg)
    (pkg / "a" / "unused.py").write_text("Y = 4\n")
    (pkg / "b" / "other.py").write_text("Z = 1\n")
    assert kernel_digest(pkg) == before
    (pkg / "b" / "deep.py").write_text("X = 3\n")
    assert kernel_digest(pkg) != before


def test_kernels_are_reused_when_only_other_modules_changed(every_fmu, tmp_path, monkeypatch, capsys) -> None:
    """A change of a module no kernel imports (henriksson2009_model): a new package name, the
    same compiled kernels (reused, not compiled), byte for byte."""
    import shutil

    from orchestration import build
    sources = tmp_path / "fmus"
    shutil.copytree(REPO / "fmus", sources, ignore=shutil.ignore_patterns("__pycache__"))
    changed = sources / "estimators" / "henriksson2009_model.py"
    changed.write_text(changed.read_text() + "# another build\n")
    monkeypatch.setattr(build, "FMU_SOURCES", sources)
    fmu, = build_all(tmp_path / "out", only=["Encoder"])
    out = capsys.readouterr().out
    assert "kernels unchanged" in out and "compiling" not in out

    def compiled(path: Path) -> tuple[str, bytes]:
        with zipfile.ZipFile(path) as z:
            name = next(n for n in z.namelist() if "/_compiled." in n)
            return name.split("/")[1], z.read(name)
    (new_package, new_module), (old_package, old_module) = compiled(fmu), compiled(every_fmu["Encoder"])
    assert new_package != old_package and new_module == old_module


def test_the_staged_package_and_the_working_tree_have_one_kernel_key(tmp_path) -> None:
    """The manifest records the working tree's kernel key; the staged package (imports
    rewritten to ``fmus_<hash>``) is compiled and cached under its own: they must be one."""
    from orchestration import build
    package = build._stage_package(tmp_path)
    assert package.name != "fmus"
    assert build.kernel_digest(package) == build.kernel_digest(build.FMU_SOURCES)
    assert ([p.relative_to(package) for p in build.kernel_sources(package)]
            == [p.relative_to(build.FMU_SOURCES) for p in build.kernel_sources(build.FMU_SOURCES)])


def test_every_fmu_carries_each_cython_kernel_module_compiled_beside_its_source(every_fmu) -> None:
    """Every ``.pyx`` of the package is in each FMU's vendored package with its extension for
    this Python beside it, the bytes of the working tree's cache entry (one compilation serves
    both)."""
    from fmus.common import cython_kernels
    pyx = [p.relative_to(REPO / "fmus").as_posix() for p in cython_kernels.sources()]
    assert "robot_plant/plant_kernels.pyx" in pyx
    for name, fmu in every_fmu.items():
        with zipfile.ZipFile(fmu) as z:
            package = next(f.split("/")[1] for f in z.namelist() if f.endswith("/" + BUNDLE_ID_FILE))
            for source in pyx:
                assert f"resources/{package}/{source}" in z.namelist(), (name, source)
                extension = f"resources/{package}/{source[:-4]}{cython_kernels.EXTENSION}"
                entry = cython_kernels.compiled(REPO / "fmus" / source)
                assert z.read(extension) == entry.read_bytes(), (name, source)


def test_a_changed_kernel_source_or_pxd_changes_the_builds_keys(tmp_path) -> None:
    """The manifest's keys cover the Cython kernels: a changed ``.pyx`` or ``.pxd`` changes the
    package's digest (the bundle id) and the Cython key, a changed other file neither of them
    alone (the numba kernels' key stays with both)."""
    import shutil

    from orchestration import build
    sources = tmp_path / "fmus"
    shutil.copytree(REPO / "fmus", sources, ignore=shutil.ignore_patterns("__pycache__"))

    def keys() -> tuple[str, str, str]:
        return build.package_digest(sources), build.cython_key(sources), build.kernel_digest(sources)
    first = keys()
    pxd = sources / "common" / "gearbox.pxd"
    pxd.write_text(pxd.read_text() + "# changed\n")
    second = keys()
    assert second[0] != first[0] and second[1] != first[1] and second[2] == first[2]
    pyx = sources / "robot_plant" / "sensor_kernels.pyx"
    pyx.write_text(pyx.read_text() + "# changed\n")
    third = keys()
    assert third[0] != second[0] and third[1] != second[1] and third[2] == first[2]


def test_compile_cython_says_what_it_compiles_once_per_content(tmp_path, monkeypatch, capsys) -> None:
    """A package's kernel module is compiled (the build says so and how long it took), put
    beside its source, and importable there; the next build of the same content takes it from
    the cache and says so; a failing one is a BuildError naming it."""
    from orchestration import build
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    package = tmp_path / "stage" / "fmus_toy"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "sub" / "__init__.py").write_text("")
    (package / "sub" / "toy_kernels.pyx").write_text("def twice(double x):\n    return 2.0 * x\n")
    made = build.compile_cython(package)
    out = capsys.readouterr().out
    assert "compiling sub/toy_kernels.pyx" in out and re.search(r"compiled sub/toy_kernels\.pyx in [0-9.]+ s", out)
    assert made == [package / "sub" / f"toy_kernels{importlib.machinery.EXTENSION_SUFFIXES[0]}"]
    monkeypatch.syspath_prepend(str(package.parent))
    assert importlib.import_module("fmus_toy.sub.toy_kernels").twice(1.5) == 3.0
    assert build.compile_cython(package) == made
    assert capsys.readouterr().out == "  Cython kernels unchanged: 1 modules from the cache\n"
    (package / "sub" / "toy_kernels.pyx").write_text("def twice(double x):\n    return y\n")
    with pytest.raises(BuildError, match="the kernel module sub/toy_kernels.pyx: compiling toy_kernels.pyx failed"):
        build.compile_cython(package, quiet=True)

"""Build every FlexFusion FMU into ``dist/fmus`` and validate each with fmpy.

An FMU script is any ``fmus/<group>/*_fmu.py``; its model identifier is the name of its
FMU class. All FMUs bundle the same copy of the whole ``fmus`` package, staged once per
build: a package bundled into several FMUs is imported only once per process (the first copy
wins), so the copies must be identical. Each FMU carries ``resources/requirements.txt`` naming
the third-party packages the importer's Python must have.
"""
from __future__ import annotations

import argparse
import hashlib
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
FMU_SOURCES = REPO / "fmus"
DEFAULT_DEST = REPO / "dist" / "fmus"
# What the FMUs import besides the standard library and the bundled `fmus` package.
FMU_REQUIREMENTS = ["numpy>=1.26", "scipy>=1.11"]


# Hash of the bundled package, in every FMU: FMUs with different ones must not run together.
BUNDLE_ID_FILE = "BUNDLE_ID"

_CLASS = re.compile(r"^class (\w+)\(", re.M)


class BuildError(RuntimeError):
    """An FMU failed to build or to validate."""


def fmu_scripts(root: Path = FMU_SOURCES) -> list[Path]:
    """Every FMU script below ``root``, sorted for a reproducible build order."""
    return sorted(p for p in root.glob("*/*_fmu.py"))


def _stage_package(stage: Path) -> Path:
    target = stage / "fmus"
    shutil.copytree(FMU_SOURCES, target,
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*_fmu.py"))
    digest = hashlib.sha256()
    for f in sorted(target.rglob("*.py")):
        digest.update(f.relative_to(target).as_posix().encode() + b"\0" + f.read_bytes())
    (target / BUNDLE_ID_FILE).write_text(digest.hexdigest() + "\n")
    (stage / "requirements.txt").write_text("\n".join(FMU_REQUIREMENTS) + "\n")
    return target


def validate_fmu(path: Path) -> list[str]:
    """Problems fmpy finds in an FMU (empty when valid)."""
    from fmpy.validation import validate_fmu as fmpy_validate
    return list(fmpy_validate(str(path)))


def build_all(dest: Path = DEFAULT_DEST, only: list[str] | None = None, quiet: bool = False,
              scripts: list[Path] | None = None) -> list[Path]:
    """Build (and validate) every FMU, or those whose script stem or class is in ``only``.

    ``scripts`` replaces the FMU scripts found below ``fmus/`` (e.g. the test toys in
    ``tests/fmus``); they still bundle the ``fmus`` package.

    Raises
    ------
    BuildError
        Naming every FMU that failed to build or validate, with the reason.
    """
    from pythonfmu.builder import FmuBuilder

    from orchestration import native   # our FMI layer replaces pythonfmu's binary (native/README.md)
    library = native.build_library()
    if str(REPO) not in sys.path:  # the builder imports the scripts, which import `fmus`
        sys.path.insert(0, str(REPO))
    dest.mkdir(parents=True, exist_ok=True)
    built: list[Path] = []
    failures: list[str] = []
    with tempfile.TemporaryDirectory(prefix="flexfusion_stage_") as tmp:
        stage = Path(tmp)
        package = _stage_package(stage)
        for script in (fmu_scripts() if scripts is None else [Path(p) for p in scripts]):
            if only and script.stem not in only and not set(only) & set(_CLASS.findall(script.read_text())):
                continue
            t0 = time.perf_counter()
            try:
                fmu = FmuBuilder.build_FMU(script, dest=dest,
                                           project_files=[package, stage / "requirements.txt"])
            except Exception as exc:  # noqa: BLE001 - collect and report every failure at once
                failures.append(f"{_shown(script)}: build failed: {type(exc).__name__}: {exc}")
                continue
            native.install_into(Path(fmu), library)
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

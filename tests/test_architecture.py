"""The import rules of ARCHITECTURE.md, read from the source with ast (every import, also those
inside functions): the FMU wings import only fmus.common and themselves (estimators never the
plant), fmus never imports orchestration or the tests, and fmus uses only the third-party
packages every FMU ships in its requirements or optional requirements (and pythonfmu)."""
from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

from orchestration.build import FMU_OPTIONAL_REQUIREMENTS, FMU_REQUIREMENTS

ROOT = Path(__file__).resolve().parent.parent
WINGS = ("robot_plant", "estimators", "force_observer")
THIRD_PARTY = {r.split(">")[0].split("=")[0].split("<")[0].strip().lower()
               for r in FMU_REQUIREMENTS + FMU_OPTIONAL_REQUIREMENTS} | {"pythonfmu"}   # import names, any case


def imports(path: Path) -> list[tuple[int, str]]:
    """``(line, module)`` of every absolute import in ``path``."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module))
    return out


def allowed(part: str, module: str) -> bool:
    top = module.split(".")[0]
    if top == "fmus":
        group = module.split(".")[1] if "." in module else ""
        return group == "common" or (part != "common" and group == part)
    return top in sys.stdlib_module_names or top.lower() in THIRD_PARTY


@pytest.mark.parametrize("part", ("common",) + WINGS)
def test_fmus_import_rules(part: str) -> None:
    bad = [f"{path.relative_to(ROOT)}:{line}: {module}"
           for path in sorted((ROOT / "fmus" / part).rglob("*.py"))
           for line, module in imports(path) if not allowed(part, module)]
    assert not bad, "imports against ARCHITECTURE.md:\n" + "\n".join(bad)


def test_orchestration_never_imports_test_code() -> None:
    tests = {p.stem for p in (ROOT / "tests").glob("*.py")} | {"tests"}
    bad = [f"{path.relative_to(ROOT)}:{line}: {module}"
           for path in sorted((ROOT / "orchestration").rglob("*.py"))
           for line, module in imports(path) if module.split(".")[0] in tests]
    assert not bad, "\n".join(bad)


def test_benchmarks_never_use_test_code() -> None:
    """Neither an import of a test module nor a test module's file name (a script run from
    tests/). The toy FMUs of tests/fmus they build are data, not test code."""
    tests = {p.stem for p in (ROOT / "tests").glob("*.py")} | {"tests"}
    bad = [f"{path.relative_to(ROOT)}:{line}: {module}"
           for path in sorted((ROOT / "benchmarks").glob("*.py"))
           for line, module in imports(path) if module.split(".")[0] in tests]
    bad += [f"{path.relative_to(ROOT)}:{node.lineno}: {node.value!r}"
            for path in sorted((ROOT / "benchmarks").glob("*.py"))
            for node in ast.walk(ast.parse(path.read_text(), str(path)))
            if isinstance(node, ast.Constant) and isinstance(node.value, str)
            and Path(node.value).suffix == ".py" and Path(node.value).stem in tests]
    assert not bad, "\n".join(bad)


def test_the_rules_catch_a_violation() -> None:
    """The checker itself: an estimator importing the plant or orchestration is refused, a
    shared piece or its own wing is fine."""
    assert not allowed("estimators", "fmus.robot_plant.sensor_model")
    assert not allowed("common", "fmus.estimators.kalman")
    assert not allowed("robot_plant", "orchestration.master")
    assert not allowed("force_observer", "matplotlib.pyplot")
    assert allowed("estimators", "fmus.common.frames") and allowed("estimators", "fmus.estimators.axelsson2012_model")
    assert allowed("common", "scipy.linalg") and allowed("common", "math")


def test_the_schedule_is_plain_and_the_engines_take_it_from_there() -> None:
    """orchestration/schedule.py decides the stepping for every engine (ARCHITECTURE.md, "One
    schedule"): it imports the standard library and the scenario only (no FMI, no engine), and
    no engine orders components or builds rates of its own (no topological sort, no lcm)."""
    path = ROOT / "orchestration" / "schedule.py"
    bad = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level:
            if node.module != "scenario":
                bad.append(f"{node.lineno}: .{node.module}")
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            bad += [f"{node.lineno}: {n}" for n in names if n.split(".")[0] not in sys.stdlib_module_names]
    assert not bad, "schedule.py imports beyond the standard library and the scenario:\n" + "\n".join(bad)
    engines = [ROOT / "orchestration" / f for f in ("master.py", "batched.py", "cloop.py")]
    own = [f"{p.name}: {word}" for p in engines for word in ("heapq", "lcm(", "_kahn", "def plan(", "def due(")
           if word in p.read_text()]
    assert not own, "an engine schedules by itself:\n" + "\n".join(own)


def _calls(path: Path, names: set[str]) -> list[int]:
    """The lines of ``path`` that call a function or method named one of ``names``."""
    tree = ast.parse(path.read_text(), str(path))
    return [node.lineno for node in ast.walk(tree) if isinstance(node, ast.Call)
            and (getattr(node.func, "attr", None) in names or getattr(node.func, "id", None) in names)]


def test_the_master_is_the_cosimulation_algorithm_and_the_store_extracts():
    """ARCHITECTURE.md "The FMU store": master.py holds the co-simulation algorithm (under 900
    lines) and extracts nothing; in orchestration, FMUs are extracted only by the FMU store (and
    the one-FMU driver of the tests and benchmarks, fmu_host) and SSP packages only by the SSP
    reader, each checked against the archive limits first."""
    master = ROOT / "orchestration" / "master.py"
    assert len(master.read_text().splitlines()) < 900
    extracting = {path.name for path in sorted((ROOT / "orchestration").glob("*.py"))
                  if _calls(path, {"extract", "extractall"})}
    assert extracting == {"fmu_store.py", "fmu_host.py", "ssp.py"}, extracting
    for name, check in (("fmu_store.py", "content_key"), ("fmu_host.py", "content_key"), ("ssp.py", "check_archive")):
        assert _calls(ROOT / "orchestration" / name, {check}), f"{name} extracts without the archive check"

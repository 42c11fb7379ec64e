"""What an FMU needs from the importer's Python: exactly its ``resources/requirements.txt``,
and for a feature imported only when used, its ``resources/optional-requirements.txt``.

Third-party packages are not bundled (numpy, scipy): an FMU must name every one it imports,
and nothing else. The LQR design no longer uses python-control (one Riccati solve in scipy).
"""
from __future__ import annotations

import ast
import re
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orchestration.build import fmu_scripts
from fmus.common.parameters import replace
from fmus.force_observer import impedance_math as imp


def _third_party_imports(fmu: Path) -> set[str]:
    """Top-level names of every absolute import in the FMU's bundled Python files, less the
    standard library and the modules bundled in ``resources/``."""
    with zipfile.ZipFile(fmu) as z:
        sources = {n: z.read(n).decode() for n in z.namelist()
                   if n.startswith("resources/") and n.endswith(".py")}
    bundled = {n.split("/")[1].removesuffix(".py") for n in sources}
    names = set()
    for name, text in sources.items():
        for node in ast.walk(ast.parse(text, name)):
            if isinstance(node, ast.Import):
                names |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names.add(node.module.split(".")[0])
    return {n.lower() for n in names - set(sys.stdlib_module_names) - bundled - {"__future__"}}   # as requirements name them


def _requirements(fmu: Path, name: str = "requirements.txt") -> set[str]:
    with zipfile.ZipFile(fmu) as z:
        lines = z.read(f"resources/{name}").decode().splitlines()
    return {re.split(r"[<>=!~;\[ ]", line.strip())[0].lower() for line in lines if line.strip()}


def test_every_fmu_requires_exactly_what_it_imports(every_fmu) -> None:
    assert len(every_fmu) == len(fmu_scripts())
    for fmu in every_fmu.values():
        imported = _third_party_imports(fmu)
        assert "numpy" in imported, fmu.name        # the scan sees through the bundle
        required, optional = _requirements(fmu), _requirements(fmu, "optional-requirements.txt")
        assert not required & optional, fmu.name
        assert required | optional == imported, fmu.name
        assert {"numpy", "scipy"} <= required, fmu.name


def test_lqr_gain_equals_python_control() -> None:
    control = pytest.importorskip("control")
    rng = np.random.default_rng(3)
    cases = []
    for d in (imp.ImpedanceControllerParameters(), replace(imp.ImpedanceControllerParameters(), r=1e-3)):
        A, B = imp.design_model(d)              # the controller's own design problem
        cases.append((A, B, np.diag([d.q_e, d.q_de, d.q_int]), np.array([[d.r]])))
    for n in (2, 3, 4):                         # and random stabilisable ones
        M = rng.standard_normal((n, n))
        cases.append((rng.standard_normal((n, n)), rng.standard_normal((n, 1)), M @ M.T + np.eye(n),
                      np.array([[0.5]])))
    for A, B, Q, R in cases:
        expected, _, _ = control.lqr(A, B, Q, R)
        assert_allclose(imp.lqr_gain(A, B, Q, R), expected, rtol=1e-9)

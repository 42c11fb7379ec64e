"""SSP export: the package is well formed and runs in another engine (libcosim, the Open
Simulation Platform's co-simulation library, through libcosimpy) with the results of our master.

libcosim's fixed-step master is Jacobi (every component reads the outputs of the previous
macro step), ours is Gauss–Seidel (a consumer reads its producer's output of the same step).
So the engines agree exactly where the coupling cannot make a difference (sources, standalone
and multi-rate components, and a feedthrough consumer shifted by one step), and on a coupled
system they differ by the first-order coupling error, which halves with the step while both
converge to the analytic solution.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from orchestration import CouplingWarning, load_scenario, run
from orchestration.cli import main
from orchestration.scenario import read_variables
from orchestration.ssp import NS
from toys import MASS_SPRING, analytic, write

pytest.importorskip("libcosimpy")

RUNNER = Path(__file__).parent / "cosim_runner.py"
REPO = Path(__file__).resolve().parent.parent


pytestmark = pytest.mark.usefixtures("toy_fmus")


def export(tmp_path: Path, scenario: Path, *overrides: str) -> Path:
    out = tmp_path / f"{scenario.stem}.ssp"
    args = ["export-ssp", str(scenario), "-o", str(out)]
    for o in overrides:
        args += ["--set", o]
    assert main(args) == 0
    return out


def cosim(ssp: Path, base_step: float, n_steps: int, columns: list[str]) -> dict[str, np.ndarray]:
    """Run ``ssp`` in libcosim (a subprocess, see ``cosim_runner.py``): the scalar columns
    after each of ``n_steps`` base steps, and ``time``."""
    out = ssp.with_suffix(".cosim.json")
    step_ns = int(round(base_step * 1e9))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, str(RUNNER), str(ssp), str(step_ns), str(n_steps), str(out),
                           *columns], capture_output=True, text=True, timeout=60, cwd=REPO, env=env)
    assert out.is_file(), f"libcosim runner wrote nothing (status {proc.returncode}): {proc.stderr[-2000:]}"
    data = json.loads(out.read_text())
    assert proc.returncode == 0 and "error" not in data, (
        f"libcosim failed: {data.get('error', '')}\nlibcosim log: {proc.stderr[-2000:]}")
    result = {c: np.array(v) for c, v in data["values"].items()}
    result["time"] = np.array(data["time"])
    return result


def ours(result, column: str) -> np.ndarray:
    """A scalar column ``comp.var`` or ``comp.var[i]`` of our master's result."""
    if column.endswith("]"):
        name, i = column[:-1].split("[")
        return result[name][:, int(i) - 1]
    return result[column]


# ---- a chain, a multi-rate component and seeded noise ------------------------------------
CHAIN = """
connections = ["src.ys -> g.uv", "src.y -> g.u"]
[scenario]
name = "chain"
stop_time = 0.1
base_step = 0.001
seed = 4
[components.src]
fmu = "Source"
parameters = { slope = 2.0, offset = [0.5, -1.0], label = "clock" }
[components.g]
fmu = "Gain"
parameters = { gain = 3.0, offset = 0.25 }
[components.m]
fmu = "MassSpring"
step = 0.004
parameters = { k = 4.0, kc = 2.0, x0 = 1.0, v0 = -0.5 }
[components.slow]
fmu = "Source"
step = 0.004
[record]
variables = ["src.y", "src.ys", "src.noise", "g.y", "g.yv", "m.x", "m.v", "slow.n", "slow.t_s"]
"""


def test_package_holds_the_ssd_and_fmus_and_the_ssd_is_consistent(tmp_path, toy_dir):
    path = write(tmp_path, CHAIN)
    ssp = export(tmp_path, path, "g.gain=-1.5", "scenario.seed=9")
    sc = load_scenario(path, ["g.gain=-1.5", "scenario.seed=9"])
    with zipfile.ZipFile(ssp) as z:
        assert set(z.namelist()) == {"SystemStructure.ssd", "resources/Source.fmu",
                                     "resources/Gain.fmu", "resources/MassSpring.fmu"}
        for name in ("Source", "Gain", "MassSpring"):     # the FMUs themselves, unchanged
            assert z.read(f"resources/{name}.fmu") == (toy_dir / f"{name}.fmu").read_bytes()
        root = ET.fromstring(z.read("SystemStructure.ssd"))

    def q(prefix: str, tag: str) -> str:
        return f"{{{NS[prefix]}}}{tag}"

    assert root.tag == q("ssd", "SystemStructureDescription") and root.get("version") == "1.0"
    system = root.find(q("ssd", "System"))
    comps = {c.get("name"): c for c in system.find(q("ssd", "Elements")).findall(q("ssd", "Component"))}
    assert list(comps) == ["src", "g", "m", "slow"]
    connectors: dict[tuple[str, str], str] = {}
    for name, el in comps.items():
        comp = sc.components[name]
        assert el.get("source") == f"resources/{comp.fmu.name}"
        variables = read_variables(comp.fmu)[2]
        for c in el.find(q("ssd", "Connectors")).findall(q("ssd", "Connector")):
            # every connector is a Real input/output of the FMU, with the FMU's causality
            info = variables[c.get("name")]
            assert (c.get("kind"), info.type) == (info.causality, "Real")
            assert c.find(q("ssc", "Real")) is not None
            connectors[(name, c.get("name"))] = c.get("kind")
        # parameter bindings: exactly the scenario's values (override and component seed included)
        bound = {}
        pset = el.find(f"{q('ssd', 'ParameterBindings')}/{q('ssd', 'ParameterBinding')}/"
                       f"{q('ssd', 'ParameterValues')}/{q('ssv', 'ParameterSet')}")
        for p in pset.find(q("ssv", "Parameters")).findall(q("ssv", "Parameter")):
            (value,) = list(p)
            kind = value.tag.split("}")[1]
            assert kind == {"Real": "Real", "Integer": "Integer", "Boolean": "Boolean",
                            "String": "String"}[variables[p.get("name")].type]
            raw = value.get("value")
            bound[p.get("name")] = {"Real": float, "Integer": int, "String": str,
                                    "Boolean": lambda s: s == "true"}[kind](raw)
        assert bound == comp.parameters
        # libcosim's step size hint where the component has its own step (else the base step)
        hint = el.find(f"{q('ssd', 'Annotations')}/{q('ssc', 'Annotation')}/{q('osp', 'StepSizeHint')}")
        assert (float(hint.get("value")) if hint is not None else sc.base_step) == comp.step
        assert (hint is None) == (name in ("src", "g"))
    assert comps["g"].find(".//" + q("ssv", "Parameter") + "[@name='gain']/" + q("ssv", "Real")).get("value") == "-1.5"
    assert sc.components["src"].parameters["seed"] != load_scenario(path).components["src"].parameters["seed"]

    # connections: scalar pairs of the scenario, each from an output connector to an input one
    conns = [(c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
             for c in system.find(q("ssd", "Connections")).findall(q("ssd", "Connection"))]
    assert conns == [("src", "ys[1]", "g", "uv[1]"), ("src", "ys[2]", "g", "uv[2]"), ("src", "y", "g", "u")]
    for a, av, b, bv in conns:
        assert connectors[(a, av)] == "output" and connectors[(b, bv)] == "input"
    algo = root.find(f"{q('ssd', 'DefaultExperiment')}/{q('ssd', 'Annotations')}/{q('ssc', 'Annotation')}/"
                     f"{q('osp', 'Algorithm')}/{q('osp', 'FixedStepAlgorithm')}")
    assert float(algo.get("baseStepSize")) == 0.001
    assert float(root.find(q("ssd", "DefaultExperiment")).get("stopTime")) == 0.1


def test_chain_and_multirate_run_in_libcosim_as_in_our_master(tmp_path):
    path = write(tmp_path, CHAIN)
    ssp = export(tmp_path, path)
    r = run(path, out_dir=tmp_path / "ours")
    sc = load_scenario(path)
    columns = sc.record_columns()
    lc = cosim(ssp, sc.base_step, sc.n_steps, columns)
    # our rows: t = 0, h, ..., T; libcosim's: after each step, t = h, ..., T
    assert_allclose(lc["time"], r.time[1:], rtol=0, atol=1e-12)
    # the source (no inputs): equal to rounding (libcosim's time is integer nanoseconds, ours
    # k * h), its seeded noise identical (the component seed is bound)
    for col in ("src.y", "src.ys[1]", "src.ys[2]"):
        assert_allclose(lc[col], ours(r, col)[1:], rtol=0, atol=1e-15, err_msg=col)
    assert_array_equal(lc["src.noise"], ours(r, "src.noise")[1:])
    assert np.std(lc["src.noise"]) > 0.5
    # the gain (direct feedthrough): Jacobi reads the source one step late, so libcosim's value
    # after step k is ours after step k - 1 (ours after step 0 is the initialisation's)
    for col in ("g.y", "g.yv[1]", "g.yv[2]"):
        assert_allclose(lc[col], ours(r, col)[:-1], rtol=0, atol=1e-14, err_msg=col)
    assert_allclose(lc["g.y"][:3], 3.0 * 2.0 * np.array([0.0, 0.001, 0.002]) + 0.25, rtol=0, atol=1e-14)
    # the components with their own step 0.004 (osp:StepSizeHint): equal at their step times;
    # between them libcosim shows the last completed step, ours already the next one
    k = np.round(lc["time"] / 0.001).astype(int)
    at = k % 4 == 0
    assert at.sum() == 25
    assert_array_equal(lc["slow.n"], np.floor(k / 4))
    assert_array_equal(ours(r, "slow.n")[1:], np.ceil(k / 4))
    for col in ("slow.t_s", "m.x", "m.v"):
        assert_allclose(lc[col][at], ours(r, col)[1:][at], rtol=0, atol=1e-14, err_msg=col)
    w = np.sqrt(6.0)                         # k + kc = 6, m = 1, x_other = 0: free oscillation
    assert_allclose(lc["m.x"][at], np.cos(w * lc["time"][at]) - 0.5 / w * np.sin(w * lc["time"][at]),
                    rtol=0, atol=1e-12)


# ---- two coupled mass-springs: the coupling error of two different masters ---------------


def test_coupled_mass_springs_agree_within_the_coupling_error_and_converge_together(tmp_path):
    path = write(tmp_path, MASS_SPRING)
    steps = (0.01, 0.005)
    x_lc, x_ours = [], []
    for h in steps:
        ssp = export(tmp_path, path, f"scenario.base_step={h}")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CouplingWarning)
            r = run(path, [f"scenario.base_step={h}"], out_dir=tmp_path / f"ours_{h}")
        lc = cosim(ssp, h, int(round(2.0 / h)), ["a.x", "b.x"])
        # on the grid of the coarse step, t = 0.01, 0.02, ..., 2
        every = int(round(steps[0] / h))
        x_lc.append(np.c_[lc["a.x"], lc["b.x"]][every - 1::every])
        x_ours.append(np.c_[r["a.x"], r["b.x"]][every::every])
    t = steps[0] * np.arange(1, len(x_lc[0]) + 1)
    exact = analytic(t)
    err_lc = [np.max(np.abs(x - exact)) for x in x_lc]
    err_ours = [np.max(np.abs(x - exact)) for x in x_ours]
    diff = [np.max(np.abs(a - b)) for a, b in zip(x_lc, x_ours)]
    # both masters are first order (halving the step halves the error, whose constant is of
    # order one here) and they differ by that coupling error: of the order of the step, halving
    # with it
    assert_allclose(np.divide(err_lc[0], err_lc[1]), 2.0, rtol=0.05)
    assert_allclose(np.divide(err_ours[0], err_ours[1]), 2.0, rtol=0.05)
    assert_allclose(np.divide(diff[0], diff[1]), 2.0, rtol=0.05)
    for d, h in zip(diff, steps):
        assert 0.5 * h < d < 2.0 * h
    # converging together: removing the first-order term (Richardson, 2 x(h/2) - x(h)) leaves
    # the engines second-order close, far closer than either run is to the other
    rich_lc = 2 * x_lc[1] - x_lc[0]
    rich_ours = 2 * x_ours[1] - x_ours[0]
    assert np.max(np.abs(rich_lc - rich_ours)) < 0.01 * diff[1]
    assert np.max(np.abs(rich_lc - exact)) < 0.02 * err_lc[1]
    assert np.max(np.abs(rich_ours - exact)) < 0.02 * err_ours[1]


def test_parameters_from_a_parameter_set_are_bound(tmp_path):
    """A named parameter set (orchestration/scenario.py) is resolved before the export: the
    package binds the values the components got from it."""
    text = CHAIN.replace('[components.src]', '[parameter_sets.model]\nslope = 3.5\ngain = 7.0\n\n[components.src]')
    text = text.replace('fmu = "Source"\nstep = 0.004', 'fmu = "Source"\nstep = 0.004\nparameter_sets = ["model"]')
    text = text.replace('fmu = "Gain"', 'fmu = "Gain"\nparameter_sets = ["model"]')
    path = write(tmp_path, text)
    with zipfile.ZipFile(export(tmp_path, path)) as z:
        root = ET.fromstring(z.read("SystemStructure.ssd"))
    bound = {(c.get("name"), p.get("name")): float(p[0].get("value"))
             for c in root.iter(f"{{{NS['ssd']}}}Component") for p in c.iter(f"{{{NS['ssv']}}}Parameter")
             if p[0].tag.endswith("Real")}
    assert bound[("slow", "slope")] == 3.5 and bound[("src", "slope")] == 2.0
    assert bound[("g", "gain")] == 3.0            # the component's own value wins over the set

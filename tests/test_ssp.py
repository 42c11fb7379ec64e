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
import re
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
from orchestration.cosim_runner import RUNNER
from orchestration.scenario import read_variables
from orchestration.ssp import NS
from toys import MASS_SPRING, analytic, write

pytest.importorskip("libcosimpy")

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
    """Run ``ssp`` in libcosim (a subprocess, see ``orchestration/cosim_runner.py``): the scalar columns
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


# ---- the SSP 1.0 schemas, OMSimulator's annotations -----------------------------------------
SCHEMAS = Path(__file__).parent / "data" / "ssp1"


def _schema(*names: str):
    """The SSP 1.0 schemas ``names`` in one validator (an inline ssv:ParameterSet, admitted by
    the SSD schema as lax content, is validated when the SSV schema is imported too)."""
    from lxml import etree
    ns = {"SystemStructureDescription": NS["ssd"], "SystemStructureParameterValues": NS["ssv"]}
    imports = "".join(f'<xs:import namespace="{ns[n]}" schemaLocation="{(SCHEMAS / n).as_uri()}.xsd"/>'
                      for n in names)
    return etree.XMLSchema(etree.fromstring(
        f'<xs:schema xmlns:xs="http://www.w3.org/2001/XMLSchema">{imports}</xs:schema>'.encode()))


def assert_valid_ssp(ssp: Path) -> None:
    """Every SSD and SSV of the package is valid against the SSP 1.0 schemas."""
    from lxml import etree
    ssd = _schema("SystemStructureDescription", "SystemStructureParameterValues")
    ssv = _schema("SystemStructureParameterValues")
    with zipfile.ZipFile(ssp) as z:
        for name in z.namelist():
            if name.endswith((".ssd", ".ssv")):
                doc = etree.fromstring(z.read(name))
                schema = ssd if name.endswith(".ssd") else ssv
                assert schema.validate(doc), f"{ssp.name}/{name}: {schema.error_log}"


def test_the_schemas_reject_a_broken_ssd_and_a_bad_inline_parameter_value(tmp_path):
    from lxml import etree
    ssp = export(tmp_path, write(tmp_path, CHAIN))
    assert_valid_ssp(ssp)
    text = zipfile.ZipFile(ssp).read("SystemStructure.ssd").decode()
    schema = _schema("SystemStructureDescription", "SystemStructureParameterValues")
    for broken in (text.replace('<ssd:Component name="g" ', '<ssd:Component '),        # name required
                   text.replace('<ssv:Real value="3.0" />', '<ssv:Real value="three" />'),   # inline ssv
                   text.replace('kind="input"', 'kind="sideways"', 1)):                    # enumeration
        assert broken != text
        assert not schema.validate(etree.fromstring(broken.encode()))


def test_omsimulator_export_has_its_annotations_first_and_no_component_annotations(tmp_path, capsys):
    path = write(tmp_path, CHAIN)
    out = tmp_path / "oms.ssp"
    assert main(["export-ssp", str(path), "-o", str(out), "--host", "omsimulator"]) == 0
    warned = capsys.readouterr().err
    assert "warning: OMSimulator takes no step size per component: m, slow" in warned
    assert "(ssv:String): src.label" in warned
    assert_valid_ssp(out)
    root = ET.fromstring(zipfile.ZipFile(out).read("SystemStructure.ssd"))

    def first_annotation(el):
        return el.find(f"{{{NS['ssd']}}}Annotations/{{{NS['ssc']}}}Annotation")

    system = root.find(f"{{{NS['ssd']}}}System")
    for el in (system, root.find(f"{{{NS['ssd']}}}DefaultExperiment")):
        assert first_annotation(el).get("type") == "org.openmodelica"
    master = first_annotation(system).find(
        f"{{{NS['oms']}}}Annotations/{{{NS['oms']}}}SimulationInformation/{{{NS['oms']}}}FixedStepMaster")
    assert float(master.get("stepSize")) == 0.001 and master.get("description") == "oms-ma"
    # OMSimulator's schema (schema/oms.xsd) types the step and the tolerances as xs:decimal:
    # no exponent, also for a small step
    small = tmp_path / "small.ssp"
    assert main(["export-ssp", str(path), "-o", str(small), "--host", "omsimulator",
                 "--set", "scenario.base_step=1e-5"]) == 0
    steps = [el.attrib for el in ET.fromstring(zipfile.ZipFile(small).read("SystemStructure.ssd")).iter()
             if el.tag in (f"{{{NS['oms']}}}FixedStepMaster", f"{{{NS['oms']}}}SimulationInformation")]
    values = [v for a in steps for k, v in a.items() if k in ("stepSize", "absoluteTolerance",
                                                              "relativeTolerance", "loggingInterval")]
    assert len(values) == 4 and "0.00001" in values
    assert all(re.fullmatch(r"\d+(\.\d+)?", v) for v in values), values
    assert not [c for c in root.iter(f"{{{NS['ssd']}}}Component") if c.find(f"{{{NS['ssd']}}}Annotations")]


# ---- archive names and packed files ----------------------------------------------------------
def test_two_different_fmus_with_one_file_name_get_unique_archive_names(tmp_path, toy_dir):
    other = tmp_path / "other"
    other.mkdir()
    (other / "Gain.fmu").write_bytes((toy_dir / "MassSpring.fmu").read_bytes())
    text = CHAIN.replace('[components.slow]\nfmu = "Source"', '[components.slow]\nfmu = "other/Gain.fmu"')
    text = text.replace('"slow.n", "slow.t_s"', '"slow.x"')
    path = write(tmp_path, text)
    ssp = export(tmp_path, path)
    assert_valid_ssp(ssp)
    with zipfile.ZipFile(ssp) as z:
        assert z.read("resources/Gain.fmu") == (toy_dir / "Gain.fmu").read_bytes()
        assert z.read("resources/Gain_2.fmu") == (other / "Gain.fmu").read_bytes()
        sources = {c.get("name"): c.get("source") for c in ET.fromstring(z.read("SystemStructure.ssd")).iter(
            f"{{{NS['ssd']}}}Component")}
    assert sources["g"] == "resources/Gain.fmu" and sources["slow"] == "resources/Gain_2.fmu"
    assert main(["run", str(ssp), "--out", str(tmp_path / "ssp"), "--no-progress"]) == 0
    assert main(["run", str(path), "--out", str(tmp_path / "toml"), "--no-progress"]) == 0
    assert (tmp_path / "ssp" / "results.csv").read_bytes() == (tmp_path / "toml" / "results.csv").read_bytes()


def _same_run(a: Path, b: Path) -> None:
    """Two run folders hold the same results, bit for bit, and the same metrics."""
    assert (a / "results.csv").read_bytes() == (b / "results.csv").read_bytes()
    assert json.loads((a / "metrics.json").read_text()) == json.loads((b / "metrics.json").read_text())
    assert json.loads((a / "run.json").read_text())["status"] == "ok"


def test_a_packed_csv_file_is_bound_by_a_relative_uri_and_the_package_runs_as_the_scenario(
        tmp_path, fmu_env):
    scenario = REPO / "orchestration" / "scenarios" / "contact_raw.toml"
    ssp = tmp_path / "contact.ssp"
    assert main(["export-ssp", str(scenario), "-o", str(ssp)]) == 0
    assert_valid_ssp(ssp)
    with zipfile.ZipFile(ssp) as z:
        assert z.read("resources/contact_wall.csv") == (scenario.parent / "paths" / "contact_wall.csv").read_bytes()
        root = ET.fromstring(z.read("SystemStructure.ssd"))
    bound = {(c.get("name"), p.get("name")): p[0].get("value") for c in root.iter(f"{{{NS['ssd']}}}Component")
             for p in c.iter(f"{{{NS['ssv']}}}Parameter")}
    assert bound[("path", "csv_file")] == bound[("controller", "csv_file")] == "resources/contact_wall.csv"
    short = ["--set", "scenario.stop_time=0.05", "--no-progress"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CouplingWarning)
        assert main(["run", str(ssp), "--out", str(tmp_path / "ssp"), *short]) == 0
        assert main(["run", str(scenario), "--out", str(tmp_path / "toml"), *short]) == 0
    _same_run(tmp_path / "ssp", tmp_path / "toml")


def test_a_file_parameter_naming_no_file_is_refused_with_one_error(tmp_path, fmu_env,
                                                                   capsys):
    scenario = REPO / "orchestration" / "scenarios" / "contact_raw.toml"
    out = tmp_path / "x.ssp"
    status = main(["export-ssp", str(scenario), "-o", str(out), "--set", 'path.csv_file="paths/nowhere.csv"'])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and not out.exists()
    assert err[0].startswith("error: component 'path': parameter 'csv_file' names") and "nowhere.csv" in err[0]


# ---- import: our own packages round-trip ---------------------------------------------------
def test_the_chain_round_trips_bit_for_bit_with_its_metrics_and_a_seed_override(tmp_path):
    text = CHAIN + """
[[metrics]]
kind = "rmse"
name = "gain_vs_source"
estimate = "g.yv"
truth = "src.ys"
after = 0.05
"""
    path = write(tmp_path, text)
    ssp = export(tmp_path, path)
    for tag, seed in (("", []), ("_5", ["--set", "scenario.seed=5"])):
        assert main(["run", str(ssp), "--out", str(tmp_path / f"ssp{tag}"), "--no-progress", *seed]) == 0
        assert main(["run", str(path), "--out", str(tmp_path / f"toml{tag}"), "--no-progress", *seed]) == 0
        _same_run(tmp_path / f"ssp{tag}", tmp_path / f"toml{tag}")
    assert json.loads((tmp_path / "ssp" / "metrics.json").read_text())["gain_vs_source"]["value"] > 0
    # the seed override reaches the components whose seed the package bound from the scenario seed
    assert (tmp_path / "ssp" / "results.csv").read_bytes() != (tmp_path / "ssp_5" / "results.csv").read_bytes()


def test_the_flagship_round_trips_bit_for_bit(tmp_path, fmu_env):
    scenario = REPO / "orchestration" / "scenarios" / "flagship.toml"
    ssp = tmp_path / "flagship.ssp"
    assert main(["export-ssp", str(scenario), "-o", str(ssp)]) == 0
    assert_valid_ssp(ssp)
    short = ["--set", "scenario.stop_time=0.6", "--no-progress"]     # the metrics start at 0.5 s
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CouplingWarning)
        assert main(["run", str(ssp), "--out", str(tmp_path / "ssp"), *short]) == 0
        assert main(["run", str(scenario), "--out", str(tmp_path / "toml"), *short]) == 0
    _same_run(tmp_path / "ssp", tmp_path / "toml")
    metrics = json.loads((tmp_path / "ssp" / "metrics.json").read_text())
    assert 0 < metrics["ekf_position_rmse"]["value"] < 1e-3


# ---- import: an SSP written by hand, in another tool's style ----------------------------------
# default namespace for ssd, other prefixes, a component without a type, parameters in .ssv files
# and on the system (names component.parameter), OMSimulator's step annotation, libcosim's hint
HANDMADE = """<?xml version="1.0" encoding="UTF-8"?>
<SystemStructureDescription xmlns="http://ssp-standard.org/SSP1/SystemStructureDescription"
    xmlns:c="http://ssp-standard.org/SSP1/SystemStructureCommon"
    xmlns:pv="http://ssp-standard.org/SSP1/SystemStructureParameterValues"
    xmlns:o="https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd"
    xmlns:a="https://opensimulationplatform.com/SSP/OSPAnnotations"
    name="handmade" version="1.0" generationTool="a text editor">
  <System name="root">
    <ParameterBindings>
      <ParameterBinding source="resources/root.ssv"/>
    </ParameterBindings>
    <Elements>
      <Component name="source" source="resources/Source.fmu">
        <Connectors>
          <Connector name="y" kind="output"><c:Real/></Connector>
          <Connector name="ys[1]" kind="output"><c:Real/></Connector>
          <Connector name="ys[2]" kind="output"><c:Real/></Connector>
        </Connectors>
        <ParameterBindings>
          <ParameterBinding source="resources/source.ssv"/>
        </ParameterBindings>
      </Component>
      <Component name="gain" type="application/x-fmu-sharedlibrary" source="resources/Gain.fmu">
        <Connectors>
          <Connector name="u" kind="input"><c:Real/></Connector>
          <Connector name="uv[1]" kind="input"><c:Real/></Connector>
          <Connector name="uv[2]" kind="input"><c:Real/></Connector>
          <Connector name="y" kind="output"><c:Real/></Connector>
        </Connectors>
        <ParameterBindings>
          <ParameterBinding>
            <ParameterValues>
              <pv:ParameterSet version="1.0" name="gain">
                <pv:Parameters>
                  <pv:Parameter name="gain"><pv:Real value="-1.5"/></pv:Parameter>
                  <pv:Parameter name="offset"><pv:Real value="9"/></pv:Parameter>
                </pv:Parameters>
              </pv:ParameterSet>
            </ParameterValues>
          </ParameterBinding>
        </ParameterBindings>
      </Component>
      <Component name="spring" source="resources/MassSpring.fmu">
        <ParameterBindings>
          <ParameterBinding>
            <ParameterValues>
              <pv:ParameterSet version="1.0" name="spring">
                <pv:Parameters>
                  <pv:Parameter name="k"><pv:Real value="4"/></pv:Parameter>
                  <pv:Parameter name="kc"><pv:Real value="2"/></pv:Parameter>
                </pv:Parameters>
              </pv:ParameterSet>
            </ParameterValues>
          </ParameterBinding>
        </ParameterBindings>
        <Annotations>
          <c:Annotation type="com.opensimulationplatform"><a:StepSizeHint value="0.004"/></c:Annotation>
        </Annotations>
      </Component>
      <Component name="sink" source="resources/Gain.fmu">
        <Connectors><Connector name="u" kind="input"><c:Real/></Connector></Connectors>
      </Component>
    </Elements>
    <Connections>
      <Connection startElement="source" startConnector="ys[1]" endElement="gain" endConnector="uv[1]"/>
      <Connection startElement="source" startConnector="ys[2]" endElement="gain" endConnector="uv[2]"/>
      <Connection startElement="source" startConnector="y" endElement="gain" endConnector="u"/>
      <Connection startElement="gain" startConnector="y" endElement="sink" endConnector="u"/>
    </Connections>
    <Annotations>
      <c:Annotation type="org.openmodelica">
        <o:Annotations><o:SimulationInformation>
          <o:FixedStepMaster description="oms-ma" stepSize="0.002" absoluteTolerance="0.0001" relativeTolerance="0.0001"/>
        </o:SimulationInformation></o:Annotations>
      </c:Annotation>
    </Annotations>
  </System>
  <DefaultExperiment startTime="0.0" stopTime="0.048"/>
</SystemStructureDescription>
"""
SSV = """<?xml version="1.0" encoding="UTF-8"?>
<p2:ParameterSet xmlns:p2="http://ssp-standard.org/SSP1/SystemStructureParameterValues" version="1.0" name="{name}">
  <p2:Parameters>{parameters}</p2:Parameters>
</p2:ParameterSet>
"""
SOURCE_SSV = SSV.format(name="source", parameters="""
    <p2:Parameter name="slope"><p2:Real value="2"/></p2:Parameter>
    <p2:Parameter name="seed"><p2:Integer value="7"/></p2:Parameter>
    <p2:Parameter name="enabled"><p2:Boolean value="false"/></p2:Parameter>
    <p2:Parameter name="label"><p2:String value="abc"/></p2:Parameter>""")
ROOT_SSV = SSV.format(name="root", parameters="""
    <p2:Parameter name="gain.offset"><p2:Real value="0.5"/></p2:Parameter>""")
# the same system as a scenario file
HANDMADE_TOML = """
connections = ["source.ys -> gain.uv", "source.y -> gain.u", "gain.y -> sink.u"]
[scenario]
name = "handmade"
stop_time = 0.048
base_step = 0.002
[components.source]
fmu = "Source"
parameters = { slope = 2.0, seed = 7, enabled = false, label = "abc" }
[components.gain]
fmu = "Gain"
parameters = { gain = -1.5, offset = 0.5 }
[components.spring]
fmu = "MassSpring"
step = 0.004
parameters = { k = 4.0, kc = 2.0 }
[components.sink]
fmu = "Gain"
"""


def handmade(tmp_path: Path, toy_dir: Path, edit=lambda text: text, name: str = "handmade.ssp",
             edit_ssv=lambda text: text) -> Path:
    """The hand-written package, its SSD changed by ``edit``, its SSVs by ``edit_ssv``."""
    out = tmp_path / name
    with zipfile.ZipFile(out, "w") as z:
        z.writestr("SystemStructure.ssd", edit(HANDMADE))
        z.writestr("resources/source.ssv", edit_ssv(SOURCE_SSV))
        z.writestr("resources/root.ssv", edit_ssv(ROOT_SSV))
        for fmu in ("Source", "Gain", "MassSpring"):
            z.write(toy_dir / f"{fmu}.fmu", f"resources/{fmu}.fmu")
    return out


def test_a_hand_written_ssp_in_another_tools_style_runs_as_its_scenario(tmp_path, toy_dir):
    from orchestration.ssp import load_ssp, opened
    ssp = handmade(tmp_path, toy_dir)
    assert_valid_ssp(ssp)        # the hand-written package is standard SSP 1.0
    with opened(ssp) as ssd:
        sc = load_ssp(ssp, ssd)
    assert sc.components["source"].parameters == {"slope": 2.0, "seed": 7, "enabled": False, "label": "abc"}
    assert sc.components["gain"].parameters == {"gain": -1.5, "offset": 0.5}   # the system's value wins
    assert (sc.base_step, sc.components["spring"].step, sc.stop_time) == (0.002, 0.004, 0.048)
    assert [str(c) for c in sc.connections] == ["source.ys -> gain.uv", "source.y -> gain.u",
                                                "gain.y -> sink.u"]
    with zipfile.ZipFile(ssp) as z:           # unpacked, as a .ssd beside its resources
        z.extractall(tmp_path / "unpacked")
    unpacked = tmp_path / "unpacked" / "SystemStructure.ssd"
    with opened(unpacked) as ssd:
        again = load_ssp(unpacked, ssd)
    assert ({n: (c.parameters, c.step) for n, c in again.components.items()}
            == {n: (c.parameters, c.step) for n, c in sc.components.items()})
    assert main(["run", str(ssp), "--out", str(tmp_path / "ssp"), "--no-progress"]) == 0
    assert main(["run", str(write(tmp_path, HANDMADE_TOML)), "--out", str(tmp_path / "toml"),
                 "--no-progress"]) == 0
    _same_run(tmp_path / "ssp", tmp_path / "toml")
    from orchestration.results import Result
    r = Result.load(tmp_path / "ssp")
    assert_allclose(r.time, 0.002 * np.arange(25), rtol=0, atol=1e-15)
    assert_allclose(r["gain.y"], -1.5 * 2.0 * r.time + 0.5, rtol=0, atol=1e-14)


def _usual_prefixes(ssd: str) -> str:
    """The hand-written SSD with the prefixes libcosim expects (ssd:, ssc:, ssv:, osp:) and
    without the system-level binding (libcosim does not apply it)."""
    ssd = re.sub(r"<ParameterBindings>\s*<ParameterBinding source=\"resources/root.ssv\"/>\s*</ParameterBindings>",
                 "", ssd, count=1)
    ssd = re.sub(r"<(/?)([A-Z]\w*)", r"<\1ssd:\2", ssd).replace('xmlns="', 'xmlns:ssd="')
    for theirs, usual in (("c", "ssc"), ("pv", "ssv"), ("a", "osp")):
        ssd = re.sub(rf"(</?|xmlns:){theirs}([:=])", rf"\g<1>{usual}\2", ssd)
    return ssd


def test_libcosim_reads_the_hand_written_package_as_we_do(tmp_path, toy_dir):
    """An independent reading of the same package: the .ssv and inline bindings give the same
    values in libcosim as in our import. (libcosim's parser matches the prefixes literally and
    skips system-level bindings: with other prefixes it cannot load the package at all.)"""
    ssp = handmade(tmp_path, toy_dir, _usual_prefixes,
                   edit_ssv=lambda t: re.sub(r"(</?|xmlns:)p2([:=])", r"\g<1>ssv\2", t))
    assert_valid_ssp(ssp)
    assert main(["run", str(ssp), "--out", str(tmp_path / "ours"), "--no-progress"]) == 0
    from orchestration.results import Result
    r = Result.load(tmp_path / "ours")
    lc = cosim(ssp, 0.002, 24, ["source.y", "gain.y"])
    assert_allclose(lc["source.y"], r["source.y"][1:], rtol=0, atol=1e-15)     # slope from the .ssv
    assert_allclose(lc["gain.y"], r["gain.y"][:-1], rtol=0, atol=1e-14)       # Jacobi: one step late
    assert_allclose(r["gain.y"], -1.5 * 2.0 * r.time + 9.0, rtol=0, atol=1e-14)   # inline gain, offset


def test_without_step_annotations_the_base_step_is_the_documented_default(tmp_path, toy_dir):
    from orchestration.ssp import DEFAULT_BASE_STEP, load_ssp, opened
    ssp = handmade(tmp_path, toy_dir, lambda t: re.sub(r"<Annotations>.*?</Annotations>", "", t, flags=re.S))
    with opened(ssp) as ssd:
        sc = load_ssp(ssp, ssd)
    assert DEFAULT_BASE_STEP == 0.001
    assert sc.base_step == DEFAULT_BASE_STEP and sc.components["spring"].step == DEFAULT_BASE_STEP


@pytest.mark.parametrize("edit, cause", [
    (lambda t: t.replace("resources/Gain.fmu", "resources/Nope.fmu"),
     "component 'gain': FMU 'resources/Nope.fmu' is not in the package"),
    (lambda t: t.replace('startElement="gain"', 'startElement="nobody"'),
     "connection nobody.y -> sink.u: no element 'nobody'"),
    (lambda t: t.replace('endConnector="u"', 'endConnector="w"'),
     "component 'gain' (Gain) has no variable 'w'"),
    (lambda t: t.replace('<Connector name="y" kind="output">', '<Connector name="why" kind="output">'),
     "component 'source': connector 'why' is not a variable of resources/Source.fmu"),
    (lambda t: t.replace('name="gain"><pv:Real', 'name="gian"><pv:Real'),
     "component 'gain' has no parameter 'gian'"),
    (lambda t: t.replace("<Elements>", "<Elements><Connector>"), "malformed XML"),
    (lambda t: t.replace('encoding="UTF-8"', 'encoding="U0TF-8"'), "malformed XML: unknown encoding: U0TF-8"),
    (lambda t: t.replace('startTime="0.0"', 'startTime="1.0"'), "startTime = 1: our master starts at 0"),
    (lambda t: t.replace('<Component name="sink"', '<Component name="gain"'),
     "two components are named 'gain'"),
])
def test_a_malformed_ssp_ends_in_one_error_line(tmp_path, toy_dir, capsys, edit, cause):
    ssp = handmade(tmp_path, toy_dir, edit)
    assert main(["run", str(ssp), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {ssp}: ") and cause in err[0], err
    assert not (tmp_path / "out").exists()


def test_a_file_that_is_no_package_ends_in_one_error_line(tmp_path, capsys):
    bad = tmp_path / "x.ssp"
    bad.write_text("not a zip")
    assert main(["run", str(bad)]) == 2
    assert capsys.readouterr().err.strip() == f"error: {bad}: not an SSP package (not a zip archive)"


def test_the_delays_declaration_round_trips(tmp_path):
    """A scenario's ``delays`` (the cycle edge meant to read the previous value) is exported and
    imported again: the same delays, and the package runs without a coupling warning, as the
    scenario does."""
    from orchestration.ssp import load_ssp, opened
    scenario = write(tmp_path, MASS_SPRING.replace("connections = [", 'delays = ["b.x -> a.x_other"]\nconnections = ['))
    sc = load_scenario(scenario)
    assert sc.delays == ["b.x -> a.x_other"]
    ssp = export(tmp_path, scenario)
    assert_valid_ssp(ssp)
    with opened(ssp) as ssd, warnings.catch_warnings():
        warnings.simplefilter("error", CouplingWarning)
        again = load_ssp(ssp, ssd)
        assert again.delays == sc.delays
        run(again, out_dir=tmp_path / "ssp")
        run(scenario, out_dir=tmp_path / "toml")
    _same_run(tmp_path / "ssp", tmp_path / "toml")


def bomb(path: Path, expanded: int) -> Path:
    """A package of about 9 MB (an SSD, 8 MB of random bytes and a zero-filled entry of
    ``expanded`` bytes, which deflates about 1000 to 1)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as z:
        z.writestr("SystemStructure.ssd", "<SystemStructureDescription/>")
        z.writestr("resources/noise.bin", np.random.default_rng(0).bytes(8 << 20), zipfile.ZIP_STORED)
        with z.open("resources/zeros.bin", "w", force_zip64=True) as f:
            chunk = bytes(1 << 24)
            for _ in range(expanded // len(chunk)):
                f.write(chunk)
    return path


def test_a_9_mb_ssp_that_would_expand_past_the_limit_is_refused_before_extraction(tmp_path, capsys, monkeypatch):
    """1 GiB of zeros in a 9 MB package: refused from the central directory (compression ratio),
    and with the ratio allowed, by the total size; nothing is extracted (no temporary folder
    is written to) and the run ends in one error line."""
    import tempfile
    ssp = bomb(tmp_path / "bomb.ssp", 1 << 30)
    assert 8e6 < ssp.stat().st_size < 10e6
    made = []
    mkdtemp = tempfile.mkdtemp
    monkeypatch.setattr(tempfile, "mkdtemp", lambda *a, **k: made.append(mkdtemp(*a, **k)) or made[-1])
    assert main(["run", str(ssp), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'resources/zeros.bin' expands" in err[0] and "FLEXFUSION_ARCHIVE_MAX_RATIO" in err[0], err
    monkeypatch.setenv("FLEXFUSION_ARCHIVE_MAX_RATIO", "2000")
    assert main(["run", str(ssp), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bytes uncompressed, more than the limit of 1073741824" in err[0], err
    assert all(not os.listdir(folder) for folder in made if os.path.isdir(folder)) and not (tmp_path / "out").exists()
    monkeypatch.setenv("FLEXFUSION_ARCHIVE_MAX_ENTRIES", "2")
    assert main(["run", str(ssp), "--out", str(tmp_path / "out")]) == 2
    assert "3 entries, more than the limit of 2" in capsys.readouterr().err


def test_archive_limits_refuse_escaping_names_and_bad_settings(tmp_path, monkeypatch):
    from orchestration import archive
    info = zipfile.ZipInfo("../outside.txt")
    with pytest.raises(archive.ArchiveError, match="unsafe entry name '../outside.txt'"):
        archive.check([info], "x.ssp")
    for name in ("/etc/passwd", "C:/x", "a/../../b"):
        with pytest.raises(archive.ArchiveError, match="unsafe entry name"):
            archive.check([zipfile.ZipInfo(name)], "x.ssp")
    archive.check([zipfile.ZipInfo("resources/a/b.fmu")], "x.ssp")
    monkeypatch.setenv("FLEXFUSION_ARCHIVE_MAX_BYTES", "lots")
    with pytest.raises(archive.ArchiveError, match="FLEXFUSION_ARCHIVE_MAX_BYTES='lots': not a positive number"):
        archive.limits()
    monkeypatch.setenv("FLEXFUSION_ARCHIVE_MAX_BYTES", "1e3")
    assert archive.limits().max_bytes == 1000

"""FMI 3.0 co-simulation FMUs from the same sources (orchestration/fmi3.py, native/fmi3_python.c).

Cheap: the FMI 3.0 FMUs here are translated from the session's FMI 2.0 build
(tests/conftest.py's ``every_fmu``: :func:`orchestration.fmi3.convert`, what ``flexfusion build
--fmi 3`` does after building the FMI 2.0 FMU), only those of the flagship scenario; one FMU
goes through ``build_all(..., fmi=...)`` itself. Checked against hosts nobody here wrote:
fmpy's validation and ``simulate_fmu`` (FMI 3.0), bit for bit against the FMI 2.0 build; and
our master (fmpy's FMU3Slave) on the flagship, equal to the FMI 2.0 run.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import fmpy
import numpy as np
import pytest
from fmpy.validation import validate_fmu
from numpy.testing import assert_array_equal

from orchestration import fmi3, fork, native, study
from orchestration.build import build_all
from orchestration.fmu_annotation import describe
from orchestration.scenario import fmi_version, read_variables

SCENARIOS = Path(__file__).resolve().parent.parent / "orchestration" / "scenarios"
FLAGSHIP = SCENARIOS / "flagship.toml"
FLAGSHIP_FMUS = ("MotionController", "FlexibleRobot2DOF", "Encoder", "Imu", "RigidKinematics",
                 "EkfAccelerometer", "Tracker")
# the fork test's scenario (tests/test_fork.py): controller, plant, sensors, 2012 EKF
REPLAY_RECORD = SCENARIOS / "replay_record.toml"
REPLAY_FMUS = ("MotionController", "FlexibleRobot2DOF", "Encoder", "Imu", "RigidKinematics",
               "EkfAccelerometer")
H = 1e-3


@pytest.fixture(scope="module")
def fmi3_dir(every_fmu: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The flagship's FMUs as FMI 3.0, translated from this session's FMI 2.0 build."""
    out = tmp_path_factory.mktemp("fmi3")
    library = native.build_library(fmi_version="3")
    for name in FLAGSHIP_FMUS:
        fmi3.convert(every_fmu[name], out / f"{name}.fmu", library)
    return out


@pytest.mark.parametrize("name", FLAGSHIP_FMUS)
def test_each_passes_fmpy_validate_and_declares_what_its_fmi2_build_does(
        every_fmu: dict[str, Path], fmi3_dir: Path, name: str) -> None:
    """fmpy validates it (schema and rules of FMI 3.0); the same variables as the FMI 2.0 FMU
    (name, value reference, type, causality, variability, unit, output dependencies), the same
    start values (the parameters' defaults), the same vendor annotation; only FMI 3.0's binary."""
    fmu = fmi3_dir / f"{name}.fmu"
    assert validate_fmu(str(fmu)) == []
    assert fmi_version(fmu) == "3.0" and fmi_version(every_fmu[name]) == "2.0"
    assert read_variables(fmu) == read_variables(every_fmu[name])
    assert describe(fmu) == describe(every_fmu[name])
    md2, md3 = (fmpy.read_model_description(str(p)) for p in (every_fmu[name], fmu))
    starts2 = {v.name: v.start for v in md2.modelVariables}
    starts3 = {v.name: v.start for v in md3.modelVariables if v.causality != "independent"}
    assert starts3 == starts2
    time, = [v for v in md3.modelVariables if v.causality == "independent"]
    assert (time.name, time.type, int(time.valueReference)) == ("time", "Float64", len(md2.modelVariables))
    assert md3.coSimulation.canGetAndSetFMUstate and md3.coSimulation.canSerializeFMUstate
    with zipfile.ZipFile(fmu) as z3, zipfile.ZipFile(every_fmu[name]) as z2:
        binaries = [n for n in z3.namelist() if n.startswith("binaries/")]
        assert binaries == [f"binaries/{fmi3.PLATFORM}/{name}.so"]
        resources = {i.filename: i.CRC for i in z2.infolist() if i.filename.startswith("resources/")}
        assert {i.filename: i.CRC for i in z3.infolist() if i.filename.startswith("resources/")} == resources
        units = {u.get("name") for u in ElementTree.fromstring(z3.read("modelDescription.xml")).iter("Unit")}
    assert {v.unit for v in md3.modelVariables if v.unit} <= units


@pytest.mark.parametrize("name", ["FlexibleRobot2DOF", "EkfAccelerometer"])
def test_one_second_under_fmpy_gives_the_fmi2_outputs_bit_for_bit(
        every_fmu: dict[str, Path], fmi3_dir: Path, name: str) -> None:
    """fmpy.simulate_fmu (its FMI 3.0 and FMI 2.0 code) from the start values: every output
    at every step equal (the same Python slave behind both; FMI 3.0 adds no arithmetic)."""
    runs = [fmpy.simulate_fmu(str(p), stop_time=1.0, step_size=H, output_interval=H)
            for p in (every_fmu[name], fmi3_dir / f"{name}.fmu")]
    assert runs[0].dtype.names == runs[1].dtype.names and len(runs[1]) == 1001
    for column in runs[0].dtype.names:
        assert_array_equal(runs[1][column], runs[0][column], err_msg=column)
    assert not np.all(runs[1][runs[1].dtype.names[1]] == runs[1][runs[1].dtype.names[1]][0])   # it moves


def test_flagship_with_fmi3_fmus_in_our_master_equals_the_fmi2_run(
        fmu_dir: Path, fmi3_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The master (FMU3Slave, the Python stepping loop) on the FMI 3.0 FMUs: every recorded
    value equal to the FMI 2.0 run's (the C loop), bit for bit, and the same metrics."""
    overrides = ["scenario.stop_time=0.5"]
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmu_dir))
    two = study.simulate(FLAGSHIP, overrides)
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmi3_dir))
    three = study.simulate(FLAGSHIP, overrides)
    assert two.status == three.status == "ok" and three.columns == two.columns
    assert_array_equal(three.time, two.time)
    assert_array_equal(three.data, two.data)
    assert three.metrics == two.metrics and len(three.time) == 501


def test_an_ssp_of_fmi3_fmus_runs_in_our_master_as_the_fmi2_scenario(
        fmu_dir: Path, fmi3_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``export-ssp`` packs the FMI 3.0 FMUs (the SSD is the same for either version) and the
    package runs in our master as the scenario does with the FMI 2.0 FMUs: results.csv equal."""
    from orchestration.cli import main
    short = ["--set", "scenario.stop_time=0.6", "--no-progress"]     # the metrics start at 0.5 s
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmu_dir))
    assert main(["run", str(FLAGSHIP), "--out", str(tmp_path / "fmi2"), *short]) == 0
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmi3_dir))
    assert main(["export-ssp", str(FLAGSHIP), "-o", str(tmp_path / "f.ssp")]) == 0
    with zipfile.ZipFile(tmp_path / "f.ssp") as z:
        assert {fmi3.PLATFORM in n for n in zipfile.ZipFile(z.open("resources/Encoder.fmu")).namelist()
                if n.startswith("binaries/")} == {True}
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(tmp_path / "none"))     # the package's own FMUs only
    assert main(["run", str(tmp_path / "f.ssp"), "--out", str(tmp_path / "ssp"), *short]) == 0
    assert (tmp_path / "ssp" / "results.csv").read_bytes() == (tmp_path / "fmi2" / "results.csv").read_bytes()


def test_a_fork_of_fmi3_fmus_equals_the_uninterrupted_run(
        fmi3_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """FMU state get/set/serialise through FMI 3.0 (fmi3GetFMUState, fmi3SerializeFMUState,
    ...): a run resumed from a state file saved at t = 0.2 s equals the uninterrupted run."""
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmi3_dir))
    stop = ["scenario.stop_time=0.3"]
    whole = fork.run_saving(REPLAY_RECORD, 0.2, tmp_path / "state.json", stop, out_dir=tmp_path / "whole")
    forked = fork.resume(REPLAY_RECORD, tmp_path / "state.json", stop, out_dir=tmp_path / "forked")
    first = np.searchsorted(whole.time, 0.2 - 1e-9)
    assert forked.columns == whole.columns and len(forked.time) == len(whole.time) - first > 50
    assert_array_equal(forked.time, whole.time[first:])
    assert_array_equal(forked.data, whole.data[first:])


def test_build_all_makes_fmi3_beside_fmi2_and_keeps_what_is_unchanged(tmp_path: Path, capsys) -> None:
    """``build_all(fmi=("2", "3"))``: ``<dest>/Encoder.fmu`` and ``<dest>/fmi3/Encoder.fmu``,
    both valid; a second build keeps both; ``fmi=("3",)`` alone keeps the FMI 3.0 FMU too."""
    two, three = build_all(tmp_path, only=["Encoder"], fmi=("2", "3"), quiet=True)
    assert two == tmp_path / "Encoder.fmu" and three == tmp_path / "fmi3" / "Encoder.fmu"
    assert (fmi_version(two), fmi_version(three)) == ("2.0", "3.0")
    assert validate_fmu(str(three)) == []
    digest = three.read_bytes()
    capsys.readouterr()
    assert build_all(tmp_path, only=["Encoder"], fmi=("3",)) == [three]
    assert capsys.readouterr().out.startswith("nothing changed: 1 FMUs")
    assert three.read_bytes() == digest


def test_fmi3_misuse_is_an_error_never_a_crash(fmi3_dir: Path, tmp_path: Path) -> None:
    """Through the FMI 3.0 entry points (the FMI 2.0 layer's handle table and time check): a
    doStep at the wrong time, fmi3FreeInstance twice, calls after free are fmi3Error (3), the
    independent variable reads the last successful time, and the process exits 0."""
    script = textwrap.dedent(f"""
        import ctypes
        from fmpy import extract, read_model_description
        from fmpy.fmi3 import FMU3Slave
        fmu = {str(fmi3_dir / "Encoder.fmu")!r}
        md = read_model_description(fmu)
        s = FMU3Slave(guid=md.guid, unzipDirectory=extract(fmu, {str(tmp_path / "x")!r}),
                      modelIdentifier="Encoder", instanceName="careless")
        s.instantiate(logMessage=lambda env, status, category, message: None)
        s.enterInitializationMode(startTime=0.0)
        s.exitInitializationMode()
        dll, h = s.dll, ctypes.c_void_p(s.component)
        flags = [ctypes.byref(ctypes.c_bool()) for _ in range(3)]
        last = ctypes.c_double()
        step = lambda t: dll.fmi3DoStep(h, ctypes.c_double(t), ctypes.c_double(0.001), ctypes.c_bool(True),
                                        *flags, ctypes.byref(last))
        time_vr = [v.valueReference for v in md.modelVariables if v.name == "time"]
        t = (ctypes.c_double * 1)()
        vr = (ctypes.c_uint32 * 1)(*time_vr)
        print("step", step(0.0), last.value)
        print("wrong_time", step(5.0))
        print("step", step(0.001), last.value)
        print("time", dll.fmi3GetFloat64(h, vr, ctypes.c_size_t(1), t, ctypes.c_size_t(1)), t[0])
        print("arrays", dll.fmi3GetFloat64(h, vr, ctypes.c_size_t(1), t, ctypes.c_size_t(2)))
        dll.fmi3FreeInstance(h)
        dll.fmi3FreeInstance(h)
        print("after_free", step(0.002), dll.fmi3Terminate(h))
        print("end")
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = r.stdout.splitlines()
    assert lines == ["step 0 0.001", "wrong_time 3", "step 0 0.002", "time 0 0.002", "arrays 3",
                     "after_free 3 3", "end"], r.stdout
    # the layer's messages name the FMI 3.0 functions called (fmi3_python.c's FMI3_NAME_*)
    assert "[careless] status 3 logStatusError: fmi3DoStep: this instance was freed by fmi3FreeInstance; " \
           "the call is refused" in r.stderr, r.stderr[-2000:]
    assert "fmi3FreeInstance: this instance was freed by fmi3FreeInstance" in r.stderr
    assert "fmi3Terminate: this instance was freed" in r.stderr and "fmi2" not in r.stderr


def test_fmi3_layer_compiles_without_warnings_and_exports_fmi3_only(tmp_path: Path) -> None:
    """As the FMI 2.0 layer (tests/test_native.py), with -Werror; every function of the FMI 3.0
    headers is exported (fmpy loads them all), nothing else."""
    library = tmp_path / "l.so"
    (tmp_path / "v.map").write_text(native.VERSION_SCRIPT3)
    command = [*native.c_compiler(), *native.CFLAGS, "-Werror", f"-I{native.python_include()}",
               f"-I{native.NATIVE}", str(native.NATIVE / "fmi3_python.c"), "-o", str(library),
               f"-Wl,--version-script={tmp_path / 'v.map'}"]
    result = subprocess.run(command, capture_output=True, text=True)
    assert result.returncode == 0 and result.stderr == "", result.stderr
    exported = subprocess.run(["nm", "-D", "--defined-only", str(library)], capture_output=True,
                              text=True).stdout.split()[2::3]
    declared = re.findall(r"FMI3_Export\s+fmi3\w+TYPE\s+(fmi3\w+);", (native.NATIVE / "fmi3Functions.h").read_text())
    assert len(declared) == 75 and sorted(exported) == sorted(declared)   # FMI 3.0: 75 functions


REFERENCE_FMUS = os.environ.get("FLEXFUSION_REFERENCE_FMUS")


@pytest.mark.skipif(not REFERENCE_FMUS, reason="FLEXFUSION_REFERENCE_FMUS (a folder of the Reference FMUs "
                    "built as FMI 3.0: BouncingBall.fmu, Dahlquist.fmu) is not set")
def test_reference_fmus_in_our_master_give_fmpys_answer() -> None:
    """FMUs nobody here wrote (modelica/Reference-FMUs, FMI 3.0, built from their sources with
    cmake -DFMI_VERSION=3): the bouncing ball at 10 ms and the Dahlquist test equation at
    100 ms in one scenario of our master give fmpy.simulate_fmu's outputs bit for bit (each
    alone in fmpy; unconnected, so the master's order changes nothing)."""
    folder = Path(REFERENCE_FMUS)
    doc = {"connections": [],
           "scenario": {"name": "reference_fmus", "stop_time": 3.0, "base_step": 0.01, "seed": 1},
           "components": {"ball": {"fmu": str(folder / "BouncingBall.fmu")},
                          "dahlquist": {"fmu": str(folder / "Dahlquist.fmu"), "step": 0.1}},
           "record": {"variables": ["ball.h", "ball.v", "dahlquist.x"]}}
    ours = study.simulate(doc)
    assert ours.status == "ok" and len(ours.time) == 301
    ball = fmpy.simulate_fmu(str(folder / "BouncingBall.fmu"), stop_time=3.0, step_size=0.01, output_interval=0.01)
    dahlquist = fmpy.simulate_fmu(str(folder / "Dahlquist.fmu"), stop_time=3.0, step_size=0.1, output_interval=0.1)
    assert_array_equal(ours["ball.h"], ball["h"])
    assert_array_equal(ours["ball.v"], ball["v"])
    assert_array_equal(ours["dahlquist.x"][::10], dahlquist["x"])
    assert ball["h"].min() < 0.5 < ball["h"].max() and np.ptp(dahlquist["x"]) > 0.5   # they bounce, decay

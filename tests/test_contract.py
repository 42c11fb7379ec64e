"""The estimator contract and its checker (orchestration/contract.py, flexfusion check-estimator)."""
from __future__ import annotations

import re
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orchestration import contract
from orchestration.build import _CLASS, build_all
from orchestration.cli import main
from orchestration.master import run
from orchestration.scenario import scenario_document

pytestmark = pytest.mark.usefixtures("fmu_env_module")      # scenarios find every FMU of this test run

REPO = Path(__file__).resolve().parent.parent
THIRD_PARTY = Path(__file__).parent / "fmus" / "third_party"


@pytest.fixture(scope="module")
def toys(tmp_path_factory) -> dict[str, Path]:
    """The third-party-style toys (plain pythonfmu, nothing of ours), built."""
    built = build_all(tmp_path_factory.mktemp("third_party"), quiet=True,
                      scripts=sorted(THIRD_PARTY.glob("*_fmu.py")))
    return {p.stem: p for p in built}


def _ours(every_fmu: dict[str, Path]) -> list[Path]:
    """Every estimator FMU of fmus/estimators (the tool-position estimators), of this test run's
    build."""
    names = [n for script in sorted((REPO / "fmus" / "estimators").glob("*_fmu.py"))
             for n in _CLASS.findall(script.read_text()) if n in every_fmu]
    return [every_fmu[n] for n in names]


def test_every_estimator_of_ours_meets_the_contract(every_fmu) -> None:
    fmus = _ours(every_fmu)
    assert {p.stem for p in fmus} >= {"RigidKinematics", "EkfAccelerometer", "ParticleFilter", "EkfComplete",
                                      "EkfMotor", "EkfIntegrated", "AccelerationObserver",
                                      "ComplementaryFilter", "ImuEkf"}
    for path in fmus:
        assert contract.check_estimator(path) == [], path.stem


def test_a_sensor_is_no_estimator(every_fmu) -> None:
    failures = contract.check_estimator(every_fmu["Encoder"])
    assert [f.split(":")[0] for f in failures] == ["required-outputs", "inputs"]
    assert "'q_m[1]' is not a contract input" in failures[1]


def test_a_third_party_estimator_passes(toys, capsys) -> None:
    assert contract.check_estimator(toys["ThirdPartyEstimator"]) == []
    assert main(["check-estimator", str(toys["ThirdPartyEstimator"])]) == 0
    assert capsys.readouterr().out.strip().endswith("meets the estimator contract (7 rules)")


def test_a_contract_breaking_estimator_fails_with_named_rules(toys, capsys) -> None:
    path = toys["LeakyEstimator"]
    assert main(["check-estimator", str(path)]) == 2
    lines = capsys.readouterr().out.strip().splitlines()
    rules = [re.match(rf"{re.escape(str(path))}: ([\w-]+): ", line).group(1) for line in lines]
    assert rules == ["required-outputs", "inputs", "outputs", "t_meas", "runs"]
    text = "\n".join(lines)
    assert "'p_tool[1]' is not a contract input" in text          # the plant's truth
    assert "'q_m_meas' has 1 of its 2 elements" in text
    assert "'q_a_hat' must be 2 Real output(s)" in text
    assert "FMU log: fmi2DoStep: RuntimeError: diverged" in text


def test_a_wrong_unit_fails_the_units_rule(toys, tmp_path: Path) -> None:
    """pythonfmu declares no units (none: SI assumed); one declared in mm is refused."""
    path = tmp_path / "InMillimetres.fmu"
    with zipfile.ZipFile(toys["ThirdPartyEstimator"]) as src, zipfile.ZipFile(path, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "modelDescription.xml":
                text = data.decode()
                head, tail = text.split('name="p_tool_hat[1]"', 1)
                data = (head + 'name="p_tool_hat[1]"' + tail.replace("<Real", '<Real unit="mm"', 1)).encode()
            dst.writestr(item, data)
    failures = contract.check_estimator(path)
    assert failures == ["units: 'p_tool_hat[1]' is in mm, the contract's unit is m"]


def test_not_an_fmu_is_one_line_and_exit_2(tmp_path: Path, capsys) -> None:
    (tmp_path / "x.fmu").write_text("not a zip")
    assert main(["check-estimator", str(tmp_path / "x.fmu"), str(tmp_path / "missing.fmu")]) == 2
    out, err = capsys.readouterr()
    assert out.count("\n") == 1 and "co-simulation: cannot read the modelDescription" in out
    assert err.strip() == f"error: {tmp_path / 'missing.fmu'}: no such file"


MISCHIEF = {      # a line of Python the stand-in runs first in each step, and the cause to report
    "abort": ("import os; os.abort()", "aborted (SIGABRT)"),
    "segfault": ("import ctypes; ctypes.string_at(0)", "segmentation fault (SIGSEGV)"),
    "hang": ("while True: pass", "within the time limit of 5 s"),
    "exit": ("import os; os._exit(3)", "exited with status 3 before it finished"),
}


def _misbehaving(good: Path, dest: Path, line: str) -> Path:
    """``good`` (the third-party toy) whose ``do_step`` runs ``line`` first: its script replaced
    in the archive (and its compiled copy left out, so the changed source is what runs)."""
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as dst:
        for item in src.infolist():
            name = item.filename
            if name.startswith("resources/__pycache__/third_party_estimator_fmu"):
                continue
            data = src.read(item)
            if re.fullmatch(r"resources/third_party_estimator_fmu_\w+\.py", name):
                head = "    def do_step(self, current_time, step_size):\n"
                assert data.decode().count(head) == 1
                data = data.decode().replace(head, head + f"        {line}\n").encode()
            dst.writestr(item, data)
    return dest


@pytest.mark.parametrize("how", sorted(MISCHIEF))
def test_an_estimator_that_crashes_or_hangs_fails_the_runs_rule_within_the_limit(
        how: str, toys, tmp_path: Path, capsys) -> None:
    """check-estimator runs the FMU's code in a child process: an abort, a segfault or an
    endless loop there is one ``runs:`` line naming the cause, exit 2, within the time limit
    (the checker itself survives to report it)."""
    line, cause = MISCHIEF[how]
    path = _misbehaving(toys["ThirdPartyEstimator"], tmp_path / f"{how}.fmu", line)
    # the hang: 5 s (the child's start-up takes 1-3 s under load); the crashes: the default
    limit = 5.0 if how == "hang" else contract.RUN_TIME_LIMIT
    t0 = time.monotonic()
    assert main(["check-estimator", "--time-limit", str(limit), str(path)]) == 2
    elapsed = time.monotonic() - t0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{path}: runs: "), lines
    assert cause in lines[0]
    assert elapsed < limit + 5.0          # the hang is killed at the limit (+5 s: extraction, cleanup)
    if how == "hang":
        assert elapsed >= limit and "killed after" in lines[0]


def test_an_fmi1_fmu_is_one_error_line(tmp_path: Path, capsys) -> None:
    """FMI 1.0 is another interface: no rule is checked (nor its code run), one error line."""
    md = ('<?xml version="1.0" encoding="UTF-8"?>\n<fmiModelDescription fmiVersion="1.0" '
          'modelName="Old" modelIdentifier="Old" guid="{8c4e810f-3df3-4a00-8276-176fa3c9f000}" '
          'numberOfContinuousStates="0" numberOfEventIndicators="0"><ModelVariables>'
          '<ScalarVariable name="p_tool_hat[1]" valueReference="0" causality="output"><Real/>'
          '</ScalarVariable></ModelVariables><Implementation><CoSimulation_StandAlone>'
          '<Capabilities/></CoSimulation_StandAlone></Implementation></fmiModelDescription>')
    with zipfile.ZipFile(tmp_path / "Old.fmu", "w") as z:
        z.writestr("modelDescription.xml", md)
    assert main(["check-estimator", str(tmp_path / "Old.fmu")]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err == (f"error: {tmp_path / 'Old.fmu'}: an FMI 1.0 FMU; the estimator contract is FMI "
                   "2.0 co-simulation (export it as FMI 2.0)\n")


def test_a_time_limit_must_be_positive(capsys) -> None:
    assert main(["check-estimator", "--time-limit", "0", "x.fmu"]) == 2
    assert capsys.readouterr().err == "error: --time-limit 0: a positive number of seconds\n"


def test_a_third_party_estimator_runs_on_a_replayed_log(toys, tmp_path: Path) -> None:
    """It takes the place of our rigid kinematics in the replay scenario and gets the log's
    motor angles at every step: its output is its own kinematics (tests/fmus/third_party) of
    the log's row of the same time (Gauss-Seidel: the log steps first)."""
    doc = scenario_document(REPO / "orchestration" / "scenarios" / "replay_log.toml")
    doc["components"]["rigid"] = {"fmu": str(toys["ThirdPartyEstimator"])}
    doc["connections"].remove("log.t_meas -> rigid.t_meas")
    doc["record"]["variables"].append("log.q_m_meas")
    r = run(doc, ["scenario.stop_time=0.6"], out_dir=tmp_path)
    q = r["log.q_m_meas"] / [200.0, 160.0]
    expected = np.c_[0.9 * np.cos(q[:, 0]) + 1.2 * np.cos(q.sum(axis=1)),
                     0.9 * np.sin(q[:, 0]) + 1.2 * np.sin(q.sum(axis=1))]
    assert_allclose(r["rigid.p_tool_hat"], expected, rtol=0, atol=1e-15)
    assert np.ptp(expected[:, 0]) > 1e-4                   # the robot moves in the log
    assert np.isfinite(r.metrics["rigid_position_rmse"])   # and the scenario's metrics work

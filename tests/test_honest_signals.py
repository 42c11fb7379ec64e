"""Honest signals: plant truth feeds only sensors, the environment and the reference system
(orchestration/roles.py, checked by the scenario loader), and metrics say what they compare with."""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import pythonfmu.builder  # noqa: F401 - at collection, before any FMU runs in this process: after
# a run, `pythonfmu` resolves to an FMU's bundled copy, and build_all would then make FMUs
# without binaries (the copy has no resources/binaries)

from orchestration import CouplingWarning, HonestSignalWarning, ScenarioError, load_scenario, run
from orchestration import roles
from orchestration.scenario import Component

SCENARIOS = Path(__file__).resolve().parent.parent / "orchestration" / "scenarios"
SHIPPED = sorted(p for p in SCENARIOS.glob("*.toml") if "connections" in p.read_text())


def arm(extra_connections=(), oracles=None, rigid_compensation=False) -> dict:
    """Plant under its motion controller, an encoder, rigid kinematics and a tracker."""
    doc = {
        "connections": ["controller.tau_m -> plant.tau_m", "plant.q_m -> controller.q_m",
                        "plant.q_m -> encoder.q_m",
                        "encoder.q_m_meas -> rigid.q_m_meas", "plant.p_tool -> tracker.p_tool",
                        *extra_connections],
        "scenario": {"name": "arm", "stop_time": 0.05, "base_step": 0.001, "seed": 1},
        "components": {"controller": {"fmu": "MotionController", "parameters": {"path": "square"}},
                       "plant": {"fmu": "FlexibleRobot2DOF", "parameters": {"p_tool0": [1.2, 0.9]}},
                       "encoder": {"fmu": "Encoder"},
                       "rigid": {"fmu": "RigidKinematics",
                                 "parameters": {"gravity_compensation": rigid_compensation}},
                       "tracker": {"fmu": "Tracker"}},
    }
    if oracles is not None:
        doc["oracles"] = oracles
    return doc


def honest_warnings(source) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_scenario(source)
    return [str(w.message) for w in caught if issubclass(w.category, HonestSignalWarning)]


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_every_shipped_scenario_is_honest(fmu_env, path):
    assert honest_warnings(path) == []


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_every_shipped_drive_reads_an_encoder(fmu_env, path):
    """Issue 24, "the drive uses its encoder": in every shipped scenario no plant or
    environment output feeds a controller (not even the drive feedback the rule allows), and
    every MotionController whose torque drives the plant reads its motor angle from an
    Encoder's q_m_meas (it forms its speed from it: the FMU has no speed input)."""
    sc = load_scenario(path)
    comps = sc.components
    into_controllers = [c for c in sc.connections if roles.role(comps[c.dst]) == "controller"]
    assert [str(c) for c in into_controllers if roles.role(comps[c.src]) in roles.TRUTH_ROLES] == []
    drives = {c.src for c in sc.connections if c.src_var == "tau_m"
              and comps[c.src].model_identifier == "MotionController" and roles.role(comps[c.dst]) == "plant"}
    if "controller" in comps and comps["controller"].model_identifier == "MotionController":
        assert "controller" in drives                 # the test sees the scenario's drive
    for drive in drives:
        feedback = [c for c in into_controllers if c.dst == drive and c.dst_var == "q_m"]
        assert [(comps[c.src].model_identifier, c.src_var) for c in feedback] == [("Encoder", "q_m_meas")]
    assert {n.split("[")[0] for c in comps.values() if c.model_identifier == "MotionController"
            for n in c.inputs} <= {"q_m", "dp_ref"}


def test_sensors_reference_and_drive_feedback_are_honest(fmu_env):
    """The arm reads the plant through the encoder and the tracker; the motion controller reads
    the drive's own q_m (an ideal encoder: allowed, though no shipped scenario does it, see
    test_every_shipped_drive_reads_an_encoder). Nothing to warn about."""
    assert honest_warnings(arm()) == []


@pytest.mark.parametrize("connection, role", [
    ("plant.q_m -> rigid.q_m_meas", "estimator"),     # motor angles without the encoder
    ("plant.p_tool -> controller.dp_ref", "controller"),   # any truth into a controller input
])
def test_a_truth_input_warns_in_one_line(fmu_env, connection, role):
    doc = arm()
    doc["connections"] = [c for c in doc["connections"] if not c.endswith("rigid.q_m_meas")] + [connection]
    msgs = honest_warnings(doc)
    assert len(msgs) == 1 and "\n" not in msgs[0]
    assert f"'{connection}'" in msgs[0] and role in msgs[0] and "oracles" in msgs[0]


def test_only_q_m_and_dq_m_are_the_drives_feedback(fmu_env):
    doc = arm()
    doc["connections"] = [c.replace("plant.q_m -> controller.q_m", "plant.q_a -> controller.q_m")
                          for c in doc["connections"]]
    assert [m.split("'")[1] for m in honest_warnings(doc)] == ["plant.q_a -> controller.q_m"]


def test_an_oracle_does_not_warn(fmu_env):
    doc = arm(["plant.p_tool -> controller.dp_ref"], oracles=["plant.p_tool->controller.dp_ref"])
    assert honest_warnings(doc) == []
    assert load_scenario(doc).oracles == ["plant.p_tool -> controller.dp_ref"]


@pytest.mark.parametrize("oracles, match", [
    (["plant.p_tool -> rigid.q_m_meas"], "oracle 'plant.p_tool -> rigid.q_m_meas' is not one of the connections"),
    (["plant.p_tool"], "is not one of the connections"),
    ("plant.p_tool -> controller.dp_ref", "must be a list"),
])
def test_an_oracle_that_is_not_a_connection_is_an_error(fmu_env, oracles, match):
    with pytest.raises(ScenarioError, match=match):
        load_scenario(arm(oracles=oracles))


def test_an_unknown_fmu_counts_as_an_estimator(fmu_env, third_party_fmus):
    """A component's role is its FMU's own declaration (its modelDescription's vendor
    annotation); an FMU without one (a third party's) is an estimator."""
    def comp(fmu):
        return Component("x", fmu, 1e-3, 1, {}, fmu.stem, "", {})
    assert roles.role(comp(third_party_fmus["ThirdPartyEstimator"])) == "estimator"
    assert [roles.against(comp(fmu_env / f"{i}.fmu")) for i in ("FlexibleRobot2DOF", "ContactEnvironment",
                                                                 "Tracker", "MotionController")] == \
        ["truth", "truth", "reference", "controller"]


def test_metrics_say_what_they_compare_with(fmu_env, tmp_path):
    """metrics.json: a metric against plant.p_tool is "against": "truth", one against the
    tracker's measurement "reference". With the tracker's noise and skew off, our Gauss-Seidel
    master hands it the plant's position of the same instant: it measures the truth exactly."""
    doc = arm()
    doc["components"]["tracker"]["parameters"] = {"noise": 0.0, "skew": 0.0}
    doc["metrics"] = [
        {"kind": "rmse", "name": "rigid_vs_truth", "estimate": "rigid.p_tool_hat", "truth": "plant.p_tool"},
        {"kind": "rmse", "name": "rigid_vs_tracker", "estimate": "rigid.p_tool_hat",
         "truth": "tracker.p_tool_meas"},
        {"kind": "max", "name": "tracker_error", "estimate": "tracker.p_tool_meas", "truth": "plant.p_tool"},
    ]
    with pytest.warns(CouplingWarning):       # the control loop's sampled-data edge
        result = run(doc, out_dir=tmp_path)
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert {k: e["against"] for k, e in m.items()} == {
        "rigid_vs_truth": "truth", "rigid_vs_tracker": "reference", "tracker_error": "truth"}
    assert m["rigid_vs_tracker"]["truth"] == "tracker.p_tool_meas"
    assert m["tracker_error"]["value"] == 0.0
    assert m["rigid_vs_tracker"]["value"] == pytest.approx(m["rigid_vs_truth"]["value"], rel=1e-12)
    assert m["rigid_vs_truth"]["value"] > 1e-4          # uncompensated gravity sag: something to see
    assert result.against == {k: e["against"] for k, e in m.items()}
    loaded = type(result).load(tmp_path)
    assert loaded.metrics == result.metrics and loaded.against == result.against
    assert np.isfinite(list(result.metrics.values())).all()


def test_the_tuning_study_prunes_oracles_with_their_connections(fmu_env):
    """study tune keeps only the components an estimate needs: an oracle of a dropped
    connection goes with it (else the pruned scenario would not load), a kept one stays."""
    from orchestration.study_tune import prune
    oracle = "plant.q_m -> rigid.q_m_meas"
    doc = arm(oracles=[oracle.replace(" ", "")])
    doc["connections"] = [oracle if c == "encoder.q_m_meas -> rigid.q_m_meas" else c for c in doc["connections"]]
    kept = prune(doc, ["rigid.p_tool_hat"])
    assert kept["oracles"] == [oracle.replace(" ", "")] and honest_warnings(kept) == []
    dropped = prune(doc, ["tracker.p_tool_meas"])
    assert "rigid" not in dropped["components"] and dropped["oracles"] == []
    assert honest_warnings(dropped) == []                 # and it loads


def test_a_run_folder_with_the_old_flat_metrics_still_loads(tmp_path):
    from orchestration import Result
    (tmp_path / "results.csv").write_text('"time","a.y"\n0.0,1.0\n0.1,2.0\n')
    (tmp_path / "metrics.json").write_text('{"e_rmse": 0.5}\n')
    r = Result.load(tmp_path)
    assert r.metrics == {"e_rmse": 0.5} and r.against == {}


def test_metrics_at_the_references_own_sample_times(fmu_env, tmp_path):
    """A 250 Hz tracker holds each sample for 4 ms: compared row by row the hold counts as an
    error; with truth_time = "tracker.t_meas" only fresh samples count, each at its stamp, and
    a noise- and skew-free tracker agrees with the truth exactly."""
    doc = arm()
    doc["components"]["tracker"]["parameters"] = {"noise": 0.0, "skew": 0.0, "sample_rate": 250.0}
    doc["scenario"]["stop_time"] = 0.7          # the square path starts moving at 0.5 s
    doc["metrics"] = [
        {"kind": "max", "name": "held", "estimate": "plant.p_tool", "truth": "tracker.p_tool_meas"},
        {"kind": "max", "name": "stamped", "estimate": "plant.p_tool", "truth": "tracker.p_tool_meas",
         "truth_time": "tracker.t_meas"},
    ]
    with pytest.warns(CouplingWarning):
        result = run(doc, out_dir=tmp_path)
    assert result.metrics["held"] > 1e-6
    assert result.metrics["stamped"] == 0.0
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["stamped"]["truth_time"] == "tracker.t_meas" and "truth_time" not in m["held"]
    bad = arm()
    bad["metrics"] = [{"kind": "max", "estimate": "plant.p_tool", "truth": "tracker.p_tool_meas",
                       "truth_time": "tracker.p_tool_meas"}]
    with pytest.raises(ScenarioError, match="truth_time"):
        load_scenario(bad)

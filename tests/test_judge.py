"""orchestration/judge.py: what a study judges an estimate against (the reference system by
default), on scenario documents (no run; the roles come from the built FMUs)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from orchestration.judge import Judge, JudgeError, aligned, judge, log_feeds, reference_components
from orchestration.scenario import copy_document, scenario_document

SCENARIOS = Path(__file__).resolve().parent.parent / "orchestration" / "scenarios"


def _doc(name: str) -> dict:
    return scenario_document(SCENARIOS / name)


def test_the_reference_is_the_default_judge_and_the_truth_on_request(fmu_env) -> None:
    for name in ("flagship.toml", "henriksson2009_p1.toml", "henriksson2009_p2.toml", "imu2019_iso.toml",
                 "imu2019_square.toml"):
        j = judge(_doc(name))
        assert j == Judge("reference", "tracker", "tracker.p_tool_meas", "tracker.t_meas", "Tracker"), name
        assert j.variables == ["tracker.p_tool_meas", "tracker.t_meas"]
        assert judge(_doc(name), "truth") == Judge("truth", "plant", "plant.p_tool", None, "FlexibleRobot2DOF")
    doc = _doc("flagship.toml")
    assert judge(doc, truth="tracker.p_tool_meas") == judge(doc)           # named: with its stamps
    assert judge(doc, "truth", truth="controller.p_ref").against == "controller"
    assert judge(doc, truth="plant.p_tool").to_json() == {"against": "truth", "component": "plant",
                                                          "fmu": "FlexibleRobot2DOF", "variable": "plant.p_tool",
                                                          "stamp": None}


def test_no_reference_two_references_or_an_unknown_judge_are_one_message(fmu_env) -> None:
    with pytest.raises(JudgeError, match="no reference measurement system.*--against truth"):
        judge(_doc("axelsson2012.toml"))
    doc = copy_document(_doc("flagship.toml"))
    doc["components"]["tracker2"] = {"fmu": "Tracker"}
    with pytest.raises(JudgeError, match="2 reference systems"):
        judge(doc)
    with pytest.raises(JudgeError, match="unknown judge 'oracle'"):
        judge(_doc("flagship.toml"), "oracle")
    with pytest.raises(JudgeError, match="no component 'nope'"):
        judge(_doc("flagship.toml"), truth="nope.p_tool")


def test_a_logs_tracker_columns_make_it_the_reference(fmu_env) -> None:
    doc = _doc("replay_log.toml")
    assert reference_components(doc) == []
    assert judge(doc, truth="log.p_tool").against == "log"
    cols = doc["components"]["log"]["parameters"]["columns"]
    doc["components"]["log"]["parameters"]["columns"] = cols + "\np_tool_meas = trk"
    assert judge(doc) == Judge("reference", "log", "log.p_tool_meas", None, "LogReplay")      # no stamps mapped
    doc["components"]["log"]["parameters"]["columns"] += "; t_tool_meas = trk_t [ms]"
    assert judge(doc).stamp == "log.t_tool_meas"
    assert log_feeds("a = x; p_tool_meas[1] = y [mm]", "p_tool_meas") and not log_feeds("p_tool = y", "p_tool_meas")


def test_aligned_takes_fresh_samples_at_their_stamps() -> None:
    t = np.arange(6) * 0.001
    est = np.column_stack([t, -t])
    ref = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 1.0], [1.0, 1.0], [2.0, 2.0], [2.0, 2.0]])
    stamp = np.array([0.0, 0.0, 0.0015, 0.0015, 0.0035, 0.0035])
    ts, e, r = aligned(t, est, ref, stamp)
    assert_array_equal(ts, [0.0, 0.0015, 0.0035])
    np.testing.assert_allclose(e, [[0.0, 0.0], [0.0015, -0.0015], [0.0035, -0.0035]], rtol=1e-12)
    assert_array_equal(r, [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])
    ts, e, r = aligned(t, est, ref, None)
    assert_array_equal(ts, t) and assert_array_equal(r, ref)

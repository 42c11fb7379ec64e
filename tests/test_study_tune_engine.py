"""study_tune's engines on the real FMUs (orchestration/study_tune.py): the batched engine (the
truth of a seed simulated once, every candidate replayed on it) against the FMUs, the check that
stops a tuning when they differ, the same tuned result on both engines, and a third party's
estimator tuned through the CLI (on the FMUs, saying why). Tiny sizes: 0.3 s of the 2009 path P1.
(The toy tuning cases are in test_study_tune.py, whose FMUs are the toys.)"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orchestration import study_tune as st
from orchestration.build import build_all
from orchestration.cli import main
from orchestration.scenario import scenario_document, toml_value
from orchestration.study import StudyError, StudyFolder, open_executor

pytestmark = pytest.mark.usefixtures("fmu_env_module")      # scenarios find every FMU of this test run

REPO = Path(__file__).resolve().parent.parent
P1 = REPO / "orchestration" / "scenarios" / "henriksson2009_p1.toml"
SHORT = ["scenario.stop_time=0.3"]
BOUNDS = {"pole_freq[1]": (5.0, 40.0), "pole_damping[1]": (0.3, 2.0)}
EST, TRUTH, AFTER, METRIC = "observer.p_tool_hat", "plant.p_tool", 0.1, "bandpass_mean"


def _objective(seeds=(2,)) -> st._Objective:
    doc = st.prune(st.load_document(P1), [EST, TRUTH])
    return st._Objective(doc, "observer", list(BOUNDS), [False, False], SHORT, st.Score(EST, TRUTH, None, METRIC, AFTER),
                         seeds)


def test_batched_candidates_equal_the_fmus():
    """Two candidates replayed on a seed's taped truth cost what their co-simulations of the
    FMUs cost (checked, and evaluated here independently); one the FMU refuses (a negative
    pole frequency) costs the penalty on both, without spoiling its group; the tape's own cost is
    the scenario's values through the FMUs."""
    objective = _objective()
    engine = st._BatchedEngine(objective, None, [2], check=2)
    candidates = [objective.overrides(x) for x in ([10.0, 0.5], [30.0, 1.5], [-5.0, 0.5])]
    costs = engine.costs(candidates, [2])
    assert [c["candidate"] for c in engine.checked] == [1, 2]
    assert all(c["max_relative_difference"] <= st.CHECK_RTOL for c in engine.checked)
    for cost, overrides in zip(costs, candidates):
        assert_allclose(cost, st.evaluate(objective.doc, overrides + ["scenario.seed=2"], EST, TRUTH, AFTER, METRIC),
                        rtol=1e-12)
    assert costs[0] != costs[1] and max(costs[:2]) < st.PENALTY == costs[2]
    assert_allclose(engine.own_cost([2]), st.evaluate(objective.doc, SHORT + ["scenario.seed=2"], EST, TRUTH,
                                                      AFTER, METRIC), rtol=1e-12)
    assert engine.costs(candidates[:1], [2])[0] == costs[0] and len(engine.checked) == 2   # checked once


def test_the_check_stops_the_tuning_on_a_difference(monkeypatch):
    """A batched estimate off by 1e-9 relative stops the study, naming the candidate, the
    seed, the quantity and the difference."""
    replayed = st._replayed

    def off(*args):
        out = replayed(*args)
        t, values = out[0]
        out[0] = (t, {**values, EST: values[EST] * (1 + 1e-9)})
        return out

    monkeypatch.setattr(st, "_replayed", off)
    with pytest.raises(StudyError, match=r"candidate 1 \(pole_freq\[1\]=.*\) on seed 2: 'observer.p_tool_hat' "
                                         r"differs by 1e-09 relative .*--engine fmu"):
        st.tune(P1, "observer", BOUNDS, after=AFTER, metric=METRIC, overrides=SHORT, maxiter=1, popsize=2,
                seeds=[2], check_candidates=1, progress=False)


def test_both_engines_tune_to_the_same_result(tmp_path):
    """Same optimiser seed: the same candidates, costs and tuned values on both engines (on the
    study executor: the tapes go to the workers), training and held-out seeds."""
    kw = dict(after=AFTER, metric=METRIC, overrides=SHORT, maxiter=1, popsize=3, seed=3, seeds=[1],
              holdout_seeds=[2], progress=False)
    with open_executor(workers=2) as ex:
        with StudyFolder(tmp_path / "folder"):
            fast = st.tune(P1, "observer", {"pole_freq[1]": BOUNDS["pole_freq[1]"]}, engine="batched", executor=ex,
                           **kw)
        ref = st.tune(P1, "observer", {"pole_freq[1]": BOUNDS["pole_freq[1]"]}, engine="fmu", executor=ex, **kw)
    assert fast.engine["used"] == "batched" and len(fast.engine["checked"]) == 2
    # the batched jobs went through map_jobs: each seed's tape and every population's jobs
    # (one per worker) kept in the study folder
    assert len(list((tmp_path / "folder" / "jobs").glob("*.pickle"))) >= 2 + 2 * 2
    assert ref.engine == {"used": "fmu"}
    assert fast.params == ref.params and fast.n_evals == ref.n_evals == 10      # scipy: 5 at least
    assert_allclose([h["cost"] for h in fast.history], [h["cost"] for h in ref.history], rtol=1e-12)
    for key in ("cost", "initial_cost", "holdout_cost", "initial_holdout_cost"):
        assert_allclose(getattr(fast, key), getattr(ref, key), rtol=1e-12, err_msg=key)
    assert np.isfinite(fast.holdout_cost) and fast.cost <= fast.initial_cost
    # judged by the reference system by default (the scenario's tracker, at its stamps)
    assert fast.against == ref.against == "reference"
    assert fast.judge == {"against": "reference", "component": "tracker", "fmu": "Tracker",
                          "variable": "tracker.p_tool_meas", "stamp": "tracker.t_meas"}


def test_tuning_is_judged_by_the_reference_by_default_and_the_truth_on_request(tmp_path):
    """The default cost is the error against the tracker's fresh samples at their stamps
    (evaluated here independently from a run), the JSON says "against": "reference" and names
    the component; --against truth judges against plant.p_tool, and says so."""
    kw = dict(after=AFTER, metric="rmse", overrides=SHORT, maxiter=1, popsize=2, seed=1, progress=False,
              engine="fmu")
    bounds = {"pole_freq[1]": BOUNDS["pole_freq[1]"]}
    res = st.tune(P1, "observer", bounds, **kw)
    data = res.to_json()
    assert data["against"] == "reference" and data["judge"]["component"] == "tracker"
    assert data["criterion"] == "error"
    doc = st.prune(st.load_document(P1), [EST, "tracker.p_tool_meas", "tracker.t_meas"])
    own = st.evaluate(doc, SHORT, EST, "tracker.p_tool_meas", AFTER, "rmse", stamp="tracker.t_meas")
    assert_allclose(res.initial_cost, own, rtol=1e-12)
    from orchestration.study import simulate
    from orchestration.metrics import at_sample_times, rmse
    run = simulate(doc, SHORT)
    t, est, ref = at_sample_times(run.time, run[EST], run["tracker.p_tool_meas"], run["tracker.t_meas"])
    assert len(t) == len(np.unique(run["tracker.t_meas"])) < len(run.time)   # 1 kHz samples, 2 kHz rows
    keep = t >= AFTER - 1e-12
    assert_allclose(own, rmse(est[keep], ref[keep]), rtol=1e-12)
    truth = st.tune(P1, "observer", bounds, against="truth", **kw)
    assert truth.to_json()["against"] == "truth" and truth.judge["variable"] == "plant.p_tool"
    assert_allclose(truth.initial_cost, st.evaluate(st.prune(st.load_document(P1), [EST, TRUTH]), SHORT, EST,
                                                    TRUTH, AFTER, "rmse"), rtol=1e-12)
    assert truth.initial_cost != res.initial_cost      # two judges (the tracker's noise and skew: either sign)
    with pytest.raises(StudyError, match="no reference measurement system"):
        st.tune(REPO / "orchestration" / "scenarios" / "axelsson2012.toml", "ekf_acc",
                {"q_jerk": (1.0, 10.0)}, **kw)


def test_the_nis_criterion_in_the_tuner():
    """--criterion nis: no judge; the cost of a candidate is the innovation criterion of its
    innovation_norm (EKF Motor: 2 motor angles, dof 2), evaluated here independently."""
    kw = dict(after=AFTER, overrides=SHORT, maxiter=1, popsize=2, seed=1, progress=False)
    res = st.tune(P1, "ekf_motor", {"lambda1": (0.1, 10.0)}, criterion="nis", nis_dof=2, **kw)
    assert res.against == "innovations" and res.judge == {"against": "innovations",
                                                          "estimate": "ekf_motor.innovation_norm", "dof": 2}
    assert res.engine["used"] == "batched" and len(res.engine["checked"]) == 2
    from orchestration.metrics import innovation_criterion
    from orchestration.study import simulate
    doc = st.prune(st.load_document(P1), ["ekf_motor.innovation_norm"])
    run = simulate(doc, SHORT + [f"ekf_motor.lambda1={res.params['lambda1']!r}"])
    keep = run.time >= AFTER - 1e-12
    expected = innovation_criterion(run["ekf_motor.innovation_norm"][keep], 2, squared=False)["cost"]
    assert_allclose(res.cost, expected, rtol=1e-9)
    with pytest.raises(StudyError, match="--nis-dof"):
        st.tune(P1, "ekf_motor", {"lambda1": (0.1, 10.0)}, criterion="nis", **kw)
    with pytest.raises(StudyError, match="no 'nis' or 'innovation_norm'"):
        st.tune(P1, "observer", {"pole_freq[1]": (5.0, 40.0)}, criterion="nis", nis_dof=2, **kw)


@pytest.fixture(scope="module")
def third_party(tmp_path_factory) -> dict[str, Path]:
    """The replay scenario (1 s) with a third-party estimator ``toy`` (tests/fmus/third_party)
    and one that breaks the contract, ``leaky``."""
    folder = tmp_path_factory.mktemp("tune_third_party")
    built = {p.stem: p for p in build_all(folder / "fmus", quiet=True,
                                          scripts=sorted((Path(__file__).parent / "fmus" / "third_party").glob("*_fmu.py")))}
    doc = scenario_document(REPO / "orchestration" / "scenarios" / "replay_log.toml", ["scenario.stop_time=1.0"])
    doc["components"]["toy"] = {"fmu": str(built["ThirdPartyEstimator"])}
    doc["components"]["leaky"] = {"fmu": str(built["LeakyEstimator"])}
    doc["connections"] += ["log.q_m_meas -> toy.q_m_meas"]
    path = folder / "replay_third_party.toml"
    path.write_text("".join(f"{k} = {toml_value(v)}\n" for k, v in doc.items()))
    return {"scenario": path, "out": folder}


def test_a_third_party_estimator_is_tuned(third_party, tmp_path, capsys):
    """``study tune --estimator`` on a user's FMU: tuned over its own parameter, on the FMUs
    (one line says why), the tuned value in the include file; one that breaks the contract is
    refused (exit 2, naming the rule)."""
    args = ["study", "tune", str(third_party["scenario"]), "--truth", "log.p_tool", "--param", "l1=0.5:1.5",
            "--maxiter", "1", "--popsize", "3", "--workers", "1", "--no-progress"]
    assert main(args + ["--estimator", "toy", "--out", str(tmp_path / "ok")]) == 0
    err = capsys.readouterr().err
    assert "tune toy: the batched engine cannot run this tuning" in err and "ThirdPartyEstimator" in err
    data = json.loads((tmp_path / "ok" / "tune_toy.json").read_text())
    assert data["engine"]["used"] == "fmu" and "fallback" in data["engine"]
    assert data["n_evals"] == 10 and data["failed"] == 0 and 0.5 <= data["params"]["l1"] <= 1.5
    assert data["cost"] <= data["initial_cost"] < st.PENALTY
    assert "l1 = " in (tmp_path / "ok" / "tuned_toy.toml").read_text()
    assert main(args + ["--estimator", "leaky", "--out", str(tmp_path / "leaky")]) == 2
    assert "--estimator leaky: LeakyEstimator.fmu does not meet the estimator contract" in capsys.readouterr().err

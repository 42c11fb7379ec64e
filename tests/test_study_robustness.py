"""study_robustness: Table I of Henriksson et al. (2009) on short runs (fast), and the paper's
findings on the full runs (slow)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from orchestration import study_robustness as sr
from orchestration.build import build_all
from orchestration.study_tune import load_document


def _fmu_types() -> list[str]:
    kinds = set()
    for _, _, fname, _ in sr.CASES:
        doc = load_document(sr.SCENARIOS / fname)
        kinds |= {Path(str(c["fmu"])).stem for c in doc["components"].values()}
    return sorted(kinds)


@pytest.fixture(scope="module")
def fmu_dir(tmp_path_factory):
    dest = tmp_path_factory.mktemp("robust_fmus")
    build_all(dest, only=_fmu_types(), quiet=True)
    return dest


@pytest.fixture
def fmus(fmu_dir, monkeypatch):
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmu_dir))


def test_jobs_give_only_the_observers_the_stiffness_error() -> None:
    jobs = sr.case_jobs(stop_time=1.0)
    assert len(jobs) == 3
    for (doc, overrides, variables), (key, _, _, scale) in zip(jobs, sr.CASES):
        est = sr.estimators(doc)
        assert "rigid" in est and "observer" in est
        assert variables == ["plant.p_tool"] + [f"{c}.p_tool_hat" for c in est]
        stiff = [o for o in overrides if "stiffness_scale" in o]
        if scale == 1.0:
            assert stiff == []
        else:
            assert sorted(stiff) == sorted(f"{c}.stiffness_scale=0.5" for c, k in est.items()
                                           if k in sr.STIFFNESS_TYPES)
            assert not any(o.startswith("rigid.") for o in overrides)


def test_error_stats_of_a_known_error() -> None:
    """A 10 Hz sine error of amplitude 1 mm on x plus a 5 mm offset: all frequencies max 6 mm,
    mean 5 mm; the band-pass removes the offset and passes the sine (mean 2/pi mm)."""
    t = np.arange(0.0, 4.0, 5e-4)
    truth = np.zeros((len(t), 2))
    est = np.column_stack([5e-3 + 1e-3 * np.sin(2 * np.pi * 10 * t), np.zeros_like(t)])
    s = sr.error_stats(t, est, truth, after=0.5)
    assert s["all_max"] == pytest.approx(6e-3, rel=1e-6)
    assert s["all_mean"] == pytest.approx(5e-3, rel=1e-3)
    assert s["band_max"] == pytest.approx(1e-3, rel=0.02)
    assert s["band_mean"] == pytest.approx(2e-3 / np.pi, rel=0.02)


def test_short_robustness_table(fmus, tmp_path) -> None:
    table = sr.robustness(stop_time=0.3, after=0.05, progress=False)
    cases = table["cases"]
    assert list(cases) == ["nominal", "tuning", "model_errors"]
    for case in cases.values():
        assert "Rigid kinematics" in case["columns"] and "Det. Observer" in case["columns"]
        for st in case["columns"].values():
            assert set(st) == set(sr.STATS) and all(np.isfinite(v) and v >= 0 for v in st.values())
    # rigid kinematics has no stiffness in it: the same numbers with the model error
    assert cases["model_errors"]["columns"]["Rigid kinematics"] == cases["nominal"]["columns"]["Rigid kinematics"]
    assert cases["model_errors"]["columns"]["Det. Observer"] != cases["nominal"]["columns"]["Det. Observer"]
    files = sr.write(table, tmp_path)
    names = {f.name for f in files}
    assert {"table.json", "table.md", "fig4_nominal.png", "fig5_tuning.png", "fig6_model_errors.png"} <= names
    js = json.loads((tmp_path / "table.json").read_text())
    assert js["paper"]["nominal"]["Rigid kinematics"] == [5.6, 2.7, 2.142, 0.221]
    md = (tmp_path / "table.md").read_text()
    assert "(0.221)" in md and "Model errors" in md


@pytest.mark.slow
def test_the_papers_findings(fmus, tmp_path) -> None:
    """Full P1/P2 runs (3-5 min on 2 cores): every accelerometer-based observer has at least 2x
    lower 3-30 Hz mean error than rigid kinematics on P1 and P2; with 50 % stiffness error the
    paper's observer changes its band-limited mean error by at most 10 %; the drift fix keeps
    the all-frequency error (max and mean) no worse than rigid kinematics on P1 and P2 and the
    band-limited mean error at least 2x lower than rigid kinematics in every case; EKF Integrated
    with the drift correction also with the stiffness error, changing its band error <= 10 %."""
    from orchestration.study import open_executor
    # these findings were made with a perfect IMU: set it explicitly (the Imu's default mounting
    # and scale errors cost the EKF Integrated its 2x: nominal 1.99x, with the drift correction
    # 1.73x; the observer's band error changes by 12.5 % with the stiffness error)
    ideal = tmp_path / "ideal_imu.toml"
    ideal.write_text("[components.imu.parameters]\n"
                     + "".join(f"{v} = [0.0, 0.0, 0.0]\n" for v in ("mount_rpy", "acc_scale", "gyro_scale")))
    with open_executor(workers=2) as ex:
        table = sr.robustness([ideal], executor=ex, progress=False)
    sr.write(table, tmp_path)
    cases = table["cases"]
    nom, err = cases["nominal"]["columns"], cases["model_errors"]["columns"]
    acc_based = [c for c in nom if c.startswith(("Det. Observer", "EKF Complete", "EKF Integrated"))]
    assert any(c.startswith("Det. Observer") for c in acc_based)
    for key in ("nominal", "tuning"):
        cols = cases[key]["columns"]
        for c in acc_based:
            assert cols[c]["band_mean"] <= cols["Rigid kinematics"]["band_mean"] / 2, (key, c)
    # the paper's observer (the EKFs' robustness is their own module's business)
    assert abs(err["Det. Observer"]["band_mean"] / nom["Det. Observer"]["band_mean"] - 1) <= 0.10
    for key in ("nominal", "tuning"):
        cols = cases[key]["columns"]
        for c in cols:
            if "FK fusion" in c or "drift correction" in c:
                assert cols[c]["all_mean"] <= cols["Rigid kinematics"]["all_mean"], (key, c)
                assert cols[c]["all_max"] <= cols["Rigid kinematics"]["all_max"], (key, c)
    for key, case in cases.items():
        for c, st in case["columns"].items():
            if "FK fusion" in c or "drift correction" in c:
                assert st["band_mean"] <= case["columns"]["Rigid kinematics"]["band_mean"] / 2, (key, c)
    # EKF Integrated with the drift correction: no worse than rigid kinematics at all frequencies
    # even with the stiffness error, and robust in the band as the paper claims for its EKF
    fixed = next(c for c in nom if "drift correction" in c)
    assert err[fixed]["all_mean"] <= err["Rigid kinematics"]["all_mean"]
    assert err[fixed]["all_max"] <= err["Rigid kinematics"]["all_max"]
    assert abs(err[fixed]["band_mean"] / nom[fixed]["band_mean"] - 1) <= 0.10

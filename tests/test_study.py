"""orchestration.study: in-memory runs, executors (local processes, Dask) and job mapping."""
from __future__ import annotations

import operator

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from orchestration import study
from orchestration.master import run
from orchestration.scenario import ScenarioError
from toys import FAILING, MASS_SPRING, analytic, write

pytestmark = pytest.mark.usefixtures("toy_fmus")

NOISY = """
connections = ["src.noise -> g.u"]
[scenario]
name = "noisy"
stop_time = 0.2
base_step = 0.01
seed = 3
[components.src]
fmu = "Source"
[components.g]
fmu = "Gain"
[record]
variables = ["src.noise", "g.y"]
"""


def _fail_on_odd(k: int) -> int:
    if k % 2:
        raise ValueError(f"odd {k}")
    return 10 * k


def test_simulate_equals_a_run_written_to_disk(tmp_path):
    path = write(tmp_path, MASS_SPRING)
    mem = study.simulate(path)
    disk = run(path, out_dir=tmp_path / "out")
    assert_array_equal(mem.time, disk.time)
    assert_array_equal(mem["a.x"], disk["a.x"])
    assert_allclose(mem["b.x"], analytic(mem.time)[:, 1], atol=0.05)
    assert mem.variables() == ["a.x", "b.x"]
    assert not (tmp_path / "results.csv").exists()


def test_simulate_keeps_the_variables_asked_for(tmp_path):
    path = write(tmp_path, MASS_SPRING)
    r = study.simulate(path, variables=["b.x"])
    assert r.variables() == ["b.x"]
    with pytest.raises(KeyError, match="'a.x' was not recorded"):
        r["a.x"]
    with pytest.raises(ScenarioError, match="not recorded: c.x"):
        study.simulate(path, variables=["c.x"])


def test_map_jobs_keeps_the_job_order_on_processes():
    with study.open_executor(workers=2) as ex:
        assert study.map_jobs(operator.neg, list(range(7)), ex, progress=False) == [-k for k in range(7)]
        assert study.map_jobs(operator.add, [(1, 2), (3, 4)], ex, progress=False, star=True) == [3, 7]


def test_failed_jobs_are_named_and_the_others_kept():
    with study.open_executor(workers=2) as ex:
        with pytest.raises(study.StudyError, match=r"2 of 4 jobs failed: job 1 \(1\): ValueError: odd 1") as info:
            study.map_jobs(_fail_on_odd, [0, 1, 2, 3], ex, progress=False)
    assert info.value.results == [0, None, 20, None]


def test_bad_worker_count_is_refused():
    with pytest.raises(study.StudyError, match="--workers must be at least 1"):
        with study.open_executor(workers=0):
            pass


def test_seeded_runs_are_identical_on_processes_and_on_a_dask_cluster(tmp_path):
    pytest.importorskip("distributed")
    path = write(tmp_path, NOISY)
    jobs = [(path, (f"scenario.seed={s}",)) for s in range(4)]
    with study.open_executor(workers=2) as ex:
        local = study.map_jobs(study.simulate, jobs, ex, progress=False, star=True)
    with study.open_executor(workers=2, scheduler="local") as ex:
        dask = study.map_jobs(study.simulate, jobs, ex, progress=False, star=True)
    for a, b in zip(local, dask):
        assert_array_equal(a.data, b.data)
    assert not np.array_equal(local[0]["src.noise"], local[1]["src.noise"])   # seeds do differ


def test_a_failing_run_in_a_worker_names_the_component(tmp_path):
    path = write(tmp_path, FAILING.format(mode="error"))
    with study.open_executor(workers=1) as ex:
        with pytest.raises(study.StudyError, match="1 of 1 jobs failed.*RunError.*bad"):
            study.map_jobs(study.simulate, [path], ex, progress=False)


def test_an_unreachable_scheduler_is_one_clear_error():
    pytest.importorskip("distributed")
    with pytest.raises(study.StudyError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:1"):
        with study.open_executor(scheduler="tcp://127.0.0.1:1", connect_timeout=1):
            pass

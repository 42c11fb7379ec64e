"""The co-simulation master on toy FMUs (tests/fmus): accuracy against an analytic solution,
Gauss–Seidel order, multi-rate, cycles, reproducibility, failures."""
from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from fmpy.util import read_csv
from numpy.testing import assert_allclose, assert_array_equal

from orchestration import CouplingWarning, Result, ResultWarning, RunError, ScenarioError, run
from orchestration.schedule import Schedule
from orchestration.scenario import load_scenario
from toys import FAILING, MASS_SPRING, analytic, write


pytestmark = pytest.mark.usefixtures("toy_fmus")


# ---- two coupled mass-springs against the analytic solution ---------------------------------


def coupled_error(tmp_path: Path, h: float) -> float:
    path = write(tmp_path, MASS_SPRING)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CouplingWarning)
        r = run(path, [f"scenario.base_step={h}"], out_dir=tmp_path / f"out_{h}")
    x = np.c_[r["a.x"], r["b.x"]]
    return float(np.max(np.abs(x - analytic(r.time))))


def test_coupled_mass_springs_converge_first_order(tmp_path):
    steps = [0.01, 0.005, 0.0025]
    errors = [coupled_error(tmp_path, h) for h in steps]
    # close to the analytic answer, and Gauss–Seidel coupling is first order: halving the
    # communication step halves the error
    assert errors[-1] < 2e-3
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert_allclose(ratios, 2.0, rtol=0.05)


def test_cycle_is_broken_with_one_warning_naming_the_edge(tmp_path):
    path = write(tmp_path, MASS_SPRING)
    with pytest.warns(CouplingWarning) as record:
        run(path, ["scenario.stop_time=0.05"], out_dir=tmp_path / "o")
    msgs = [str(w.message) for w in record if issubclass(w.category, CouplingWarning)]
    assert len(msgs) == 1
    assert "b.x -> a.x_other" in msgs[0] and "previous" in msgs[0]
    p = Schedule.of(load_scenario(path))
    assert p.order == ("a", "b") and p.broken == (("b", "a"),)


def test_a_cycle_is_found_when_a_component_behind_it_comes_first(tmp_path):
    """Kahn's sort leaves the cycle a <-> b and the mass g fed by it; g, listed first, only lies
    downstream of the cycle."""
    path = write(tmp_path, MASS_SPRING.replace('connections = [', 'connections = ["a.x -> g.x_other", ')
                 .replace("[components.a]", '[components.g]\nfmu = "MassSpring"\n[components.a]'))
    p = Schedule.of(load_scenario(path))
    assert p.broken == (("b", "a"),) and p.order == ("a", "g", "b")


def _kahn_reference(names, edges, rank):
    """The ordering as it was first written (quadratic: every edge scanned for every component):
    the independent reference of the linear one."""
    indeg = {n: 0 for n in names}
    for (_, d) in edges:
        indeg[d] += 1
    ready = sorted((n for n in names if indeg[n] == 0), key=rank.get)
    order = []
    while ready:
        n = ready.pop(0)
        order.append(n)
        for (s, d) in sorted(edges):
            if s == n:
                indeg[d] -= 1
                if indeg[d] == 0:
                    ready.append(d)
                    ready.sort(key=rank.get)
    return order


def test_the_linear_ordering_equals_the_reference_on_random_graphs():
    from orchestration.schedule import _find_cycle, _kahn
    rng = np.random.default_rng(7)
    for trial in range(200):
        n = int(rng.integers(1, 25))
        names = [f"c{k}" for k in rng.permutation(n)]
        rank = {name: i for i, name in enumerate(names)}
        edges = {(names[a], names[b]) for a, b in rng.integers(0, n, (int(rng.integers(0, 3 * n)), 2))}
        order = _kahn(names, edges, rank)
        assert order == _kahn_reference(names, edges, rank)
        rest = [m for m in names if m not in set(order)]
        if rest:          # what the sort left holds a cycle: a closed walk along the edges
            cycle = _find_cycle(rest, edges, rank)
            assert set(cycle) <= edges and cycle[-1][1] == cycle[0][0]
            assert all(a[1] == b[0] for a, b in zip(cycle, cycle[1:]))


def test_ten_thousand_connections_are_ordered_in_linear_time(tmp_path):
    """A ring of 10,000 masses (one cycle of 10,000 connections, broken once). The quadratic
    ordering took 128 s for a 10,000-connection chain; the bound is only a hang guard."""
    import time
    n = 10_000
    conns = ", ".join(f'"m{k}.x -> m{(k + 1) % n}.x_other"' for k in range(n))
    comps = "".join(f'[components.m{k}]\nfmu = "MassSpring"\n' for k in range(n))
    path = write(tmp_path, f"connections = [{conns}]\n[scenario]\nstop_time = 0.01\nbase_step = 0.01\n{comps}")
    sc = load_scenario(path)
    t0 = time.perf_counter()
    p = Schedule.of(sc)
    assert time.perf_counter() - t0 < 60              # hang guard (about 0.5 s here)
    assert p.broken == ((f"m{n - 1}", "m0"),)
    assert p.order == tuple(f"m{k}" for k in range(n))


# ---- multi-rate -----------------------------------------------------------------------------
def test_multirate_steps_every_k_base_steps_and_holds_outputs(tmp_path):
    path = write(tmp_path, """
connections = ["slow.y -> g.u"]
[scenario]
stop_time = 0.02
base_step = 0.001
[components.slow]
fmu = "Source"
step = 0.004
[components.fast]
fmu = "Source"
[components.g]
fmu = "Gain"
step = 0.002
[record]
variables = ["slow.n", "slow.t_s", "fast.n", "g.y"]
""")
    r = run(path, out_dir=tmp_path / "o")
    k = np.round(r.time / 0.001).astype(int)
    # slow is stepped at base steps 0, 4, 8, ... with its own step 0.004: after base step k-1
    # it has taken ceil(k / 4) steps and reached time 0.004 * ceil(k / 4)
    assert_array_equal(r["slow.n"], np.ceil(k / 4))
    assert_allclose(r["slow.t_s"], 0.004 * np.ceil(k / 4), rtol=0, atol=1e-15)
    assert_array_equal(r["fast.n"], k)
    # g (step 0.002) samples slow.y when it is stepped (base steps 0, 2, 4, ...) and holds it
    expected = np.where(k == 0, 0.0, 0.004 * np.ceil((2 * np.floor((k - 1) / 2) + 1) / 4))
    assert_allclose(r["g.y"], expected, rtol=0, atol=1e-15)
    # the schedule behind it (shared with the batched engine): one period of lcm(4, 1, 2) steps,
    # then the last 3 base steps, where slow (and g at 19) would step past the stop time
    p = Schedule.of(load_scenario(path))
    assert [p.names(row) for row in p.due] == [["slow", "fast", "g"], ["fast"], ["fast", "g"], ["fast"],
                                               ["fast"], ["fast", "g"], ["fast"]]
    assert (p.period, p.tail_start) == (4, 17)


def test_multirate_coupled_mass_springs_stay_accurate(tmp_path):
    """b stepped every 2 base steps with its own (double) step: still close to the analytic
    answer; stepping it with the wrong size or every base step would be far off."""
    path = write(tmp_path, MASS_SPRING.replace('fmu = "MassSpring"\nparameters = { m = 2.0',
                                               'fmu = "MassSpring"\nstep = 0.002\nparameters = { m = 2.0'))
    assert "step = 0.002" in path.read_text()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CouplingWarning)
        r = run(path, ["scenario.base_step=0.001"], out_dir=tmp_path / "o")
    err = np.max(np.abs(np.c_[r["a.x"], r["b.x"]] - analytic(r.time)))
    assert err < 2e-3


# ---- Gauss–Seidel order ---------------------------------------------------------------------
CHAIN = """
connections = ["g1.y -> g2.u", "src.y -> g1.u"]
[scenario]
stop_time = 0.01
base_step = 0.001
# listed against the data flow: the master must order src, g1, g2
[components.g2]
fmu = "Gain"
parameters = { gain = 2.0 }
[components.g1]
fmu = "Gain"
parameters = { offset = 1.0 }
[components.src]
fmu = "Source"
parameters = { slope = 3.0 }
[record]
variables = ["src.y", "g1.y", "g2.y"]
"""


def test_gauss_seidel_order_gives_same_step_values_through_a_feedthrough_chain(tmp_path):
    path = write(tmp_path, CHAIN)
    assert Schedule.of(load_scenario(path)).order == ("src", "g1", "g2")
    r = run(path, out_dir=tmp_path / "o")
    assert_allclose(r["src.y"], 3.0 * r.time, rtol=0, atol=1e-14)
    # the same step's value all along the chain (a wrong order would lag by one or two steps),
    # also at t = 0 (initialisation in dependency order)
    assert_allclose(r["g1.y"], r["src.y"] + 1.0, rtol=0, atol=1e-14)
    assert_allclose(r["g2.y"], 2.0 * (r["src.y"] + 1.0), rtol=0, atol=1e-14)


def test_vector_connection(tmp_path):
    path = write(tmp_path, """
connections = ["src.ys -> g.uv"]
[scenario]
stop_time = 0.005
base_step = 0.001
[components.src]
fmu = "Source"
parameters = { offset = [1.0, -1.0] }
[components.g]
fmu = "Gain"
parameters = { gain = -1.0 }
[record]
variables = ["src.ys", "g.yv"]
""")
    r = run(path, out_dir=tmp_path / "o")
    assert r["src.ys"].shape == (6, 2)
    assert_allclose(r["src.ys"][1:], np.c_[r.time + 1, 2 * r.time - 1][1:], atol=1e-14)
    assert_allclose(r["g.yv"], -r["src.ys"], atol=1e-14)


def test_algebraic_loop_is_rejected(tmp_path):
    path = write(tmp_path, """
connections = ["g1.y -> g2.u", "g2.y -> g1.u"]
[scenario]
stop_time = 0.01
base_step = 0.001
[components.g1]
fmu = "Gain"
[components.g2]
fmu = "Gain"
""")
    with pytest.raises(ScenarioError, match=r"s\.toml: algebraic loop of direct feedthrough: g1\.u -> g1\.y -> g2\.u -> g2\.y -> g1\.u"):
        run(path, out_dir=tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_a_run_computes_its_schedule_once(tmp_path, monkeypatch):
    """``run`` checks the scenario's schedule (an algebraic loop) before anything is written and
    steps with that same schedule: Schedule.of once per run."""
    made = []
    of = Schedule.of.__func__

    def counted(cls, scenario):
        made.append(scenario.name)
        return of(cls, scenario)

    monkeypatch.setattr(Schedule, "of", classmethod(counted))
    run(write(tmp_path, CHAIN), out_dir=tmp_path / "o")
    assert len(made) == 1


# ---- reproducibility ------------------------------------------------------------------------
NOISE = """
[scenario]
stop_time = 0.05
base_step = 0.001
seed = 1
[components.src]
fmu = "Source"
[components.other]
fmu = "Source"
[record]
variables = ["src.noise", "other.noise"]
"""


def test_same_seed_gives_byte_identical_results_other_seed_differs(tmp_path):
    path = write(tmp_path, NOISE)
    run(path, out_dir=tmp_path / "a")
    run(path, out_dir=tmp_path / "b")
    run(path, ["scenario.seed=2"], out_dir=tmp_path / "c")
    a = (tmp_path / "a" / "results.csv").read_bytes()
    assert a == (tmp_path / "b" / "results.csv").read_bytes()
    assert a != (tmp_path / "c" / "results.csv").read_bytes()
    ra, rc = Result.load(tmp_path / "a"), Result.load(tmp_path / "c")
    assert not np.allclose(ra["src.noise"][1:], rc["src.noise"][1:])
    # two components with the same FMU get different seeds (name in the hash)
    assert not np.allclose(ra["src.noise"][1:], ra["other.noise"][1:])


LAZY_RUN = """
import json, sys
from orchestration import cli, master
heavy = ("scipy.signal", "scipy.stats", "matplotlib")
first = []
simulate = master.simulate
def recording(sc, sink, *rest):
    def row(t, values):
        if not first:
            first.append(sorted(m for m in sys.modules if m.startswith(heavy)))
        sink(t, values)
    return simulate(sc, row, *rest)
master.simulate = recording
if sys.argv[1] == "--help":
    try:
        cli.main(["--help"])
    except SystemExit:
        pass
    print(json.dumps(sorted(m for m in sys.modules if m.startswith(heavy))))
else:
    status = cli.main(["run", sys.argv[1], "--out", sys.argv[2], "--no-progress"])
    print(json.dumps({"status": status, "at_first_step": first[0]}))
"""


def test_a_run_imports_what_its_metrics_need_after_the_run(tmp_path):
    """``flexfusion run`` steps without scipy.signal, scipy.stats or matplotlib loaded (the
    band-pass metric, computed after the run, imports scipy.signal at most to design its filter
    once: tests/test_metrics.py); ``flexfusion --help`` loads none."""
    import subprocess
    scenario = write(tmp_path, CHAIN.replace("stop_time = 0.01", "stop_time = 0.1") + """
[[metrics]]
kind = "bandpass"
name = "g2_3_30Hz"
estimate = "g2.y"
truth = "g1.y"
""")
    done = subprocess.run([sys.executable, "-c", LAZY_RUN, str(scenario), str(tmp_path / "o")],
                          capture_output=True, text=True, check=True)
    assert json.loads(done.stdout.splitlines()[-1]) == {"status": 0, "at_first_step": []}
    done = subprocess.run([sys.executable, "-c", LAZY_RUN, "--help"], capture_output=True, text=True, check=True)
    assert json.loads(done.stdout.splitlines()[-1]) == []


def test_results_csv_is_read_by_fmpy(tmp_path):
    path = write(tmp_path, CHAIN)
    r = run(path, out_dir=tmp_path / "o")
    traj = read_csv(tmp_path / "o" / "results.csv")
    assert traj.dtype.names == ("time", "src.y", "g1.y", "g2.y")
    assert_array_equal(traj["time"], r.time)
    assert_array_equal(traj["g2.y"], r["g2.y"])
    info = json.loads((tmp_path / "o" / "run.json").read_text())
    assert info["status"] == "ok" and info["error"] is None
    assert info["scenario"]["components"]["g2"]["parameters"] == {"gain": 2.0}
    assert "fmpy" in info["versions"]


# ---- failures -------------------------------------------------------------------------------

def test_fmu_error_in_do_step_stops_with_log_and_keeps_rows(tmp_path):
    path = write(tmp_path, FAILING.format(mode="error"))
    with pytest.raises(RunError) as info:
        run(path, out_dir=tmp_path / "o")
    msg = str(info.value)
    assert "component 'bad'" in msg and "t = 0.05 s" in msg
    assert "toy failure: the solver diverged at t = 0.051 s" in msg   # the FMU's own log
    assert "\n" not in msg
    assert info.value.time == pytest.approx(0.05) and info.value.component == "bad"
    with pytest.warns(ResultWarning, match=r"the run is failed \(component 'bad' failed.*results up to t = 0.05 s"):
        r = Result.load(tmp_path / "o")
    assert r.status == "failed" and "toy failure" in r.error
    assert_allclose(r.time, np.arange(51) * 0.001, atol=1e-12)        # rows 0 .. 0.05 s
    assert_allclose(r["bad.y"], r.time, atol=1e-12)
    run_info = json.loads((tmp_path / "o" / "run.json").read_text())
    assert run_info["status"] == "failed" and "toy failure" in run_info["error"]
    assert run_info["rows"] == 51 and run_info["time_reached"] == 0.05


def test_nan_on_a_connection_names_producer_variable_and_time(tmp_path):
    path = write(tmp_path, FAILING.format(mode="nan"))
    with pytest.raises(RunError, match=r"NaN on a connection: component 'bad' output 'y' is NaN "
                                       r"at t = 0\.051 s"):
        run(path, out_dir=tmp_path / "o")
    with pytest.warns(ResultWarning, match="the run is failed"):
        r = Result.load(tmp_path / "o")
    assert r.time[-1] == pytest.approx(0.05)
    assert np.all(np.isfinite(r["bad.y"]))


def test_nan_on_a_connection_is_caught_at_a_base_step_its_consumer_does_not_step(tmp_path):
    """The consumer (every 2 ms) does not see the NaN of t = 0.052 s: the once-per-step check
    still names the producer, at the time it produced it."""
    text = FAILING.format(mode="nan").replace("fail_at = 0.05", "fail_at = 0.0515") \
        .replace('fmu = "Gain"', 'fmu = "Gain"\nstep = 0.002')
    with pytest.raises(RunError, match=r"NaN on a connection: component 'bad' output 'y' is NaN "
                                       r"at t = 0\.052 s") as info:
        run(write(tmp_path, text), out_dir=tmp_path / "o")
    assert info.value.component == "bad" and info.value.time == pytest.approx(0.052)


def test_bad_parameter_value_fails_at_initialisation_with_the_fmu_message(tmp_path):
    path = write(tmp_path, FAILING.format(mode="oops"))
    with pytest.raises(RunError, match=r"component 'bad'.*mode"):
        run(path, out_dir=tmp_path / "o")


def test_result_access(tmp_path):
    path = write(tmp_path, NOISE.replace('variables = ["src.noise", "other.noise"]',
                                         'variables = ["src.ys", "src.y"]'))
    r = run(path, out_dir=tmp_path / "o")
    assert r["src.ys"].shape == (51, 2) and r["src.y"].shape == (51,)
    assert_array_equal(r["src.ys[2]"], r["src.ys"][:, 1])
    assert r.variables() == ["src.ys", "src.y"]
    with pytest.raises(KeyError, match="not recorded"):
        r["src.noise"]


# ---- instances freed, libraries unloaded ----------------------------------------------------


def loaded_from(folder: str) -> set[str]:
    """The shared libraries under ``folder`` mapped into this process (removed files too)."""
    with open("/proc/self/maps") as maps:
        paths = {line.split(maxsplit=5)[-1].strip().removesuffix(" (deleted)") for line in maps}
    return {p for p in paths if p.startswith(folder) and p.endswith(".so")}


@pytest.mark.parametrize("mode, fail_at", [("error", 0.05), ("oops", 0.05), ("error", 1.0)],
                         ids=["fails-stepping", "fails-initialising", "runs-to-the-end"])
def test_a_run_frees_its_instances_and_unloads_their_libraries(tmp_path, monkeypatch, mode, fail_at):
    from orchestration import fmu_store, master
    loaded_at_close: list[set[str]] = []
    close = master._Instance.close

    def recording_close(self):
        loaded_at_close.append(loaded_from(self.fmu.unzipDirectory))
        close(self)

    monkeypatch.setattr(master._Instance, "close", recording_close)
    scenario = write(tmp_path, FAILING.format(mode=mode).replace("fail_at = 0.05", f"fail_at = {fail_at}"))
    if fail_at < 0.1:     # the scenario's stop time
        with pytest.raises(RunError):
            run(scenario, out_dir=tmp_path / "o")
    else:
        run(scenario, out_dir=tmp_path / "o")
    assert {Path(p).name for p in set().union(*loaded_at_close)} == {"Failing.so", "Gain.so"}   # were loaded
    assert set().union(*map(loaded_from, fmu_store._EXTRACTED.values())) == set()


def test_the_recorder_keeps_rows_in_one_array_that_grows_past_its_capacity():
    """The run's rows go into one preallocated array (its memory is the columns' own size, the
    result a view, not a copy: benchmarks/memory.py); past the capacity it doubles, keeping
    every row; a run that recorded nothing gives an empty result of its columns."""
    from orchestration.master import _Recorder
    rec = _Recorder(capacity=2)
    rows = np.arange(15.0).reshape(5, 3)
    for k, row in enumerate(rows):
        rec(0.1 * k, row)
    rows[:] = -1.0                                # the recorder copied each row
    r = rec.result(["a", "b", "c"], wall=0.0)
    assert_array_equal(r.data, np.arange(15.0).reshape(5, 3))
    assert_array_equal(r.time, 0.1 * np.arange(5))
    assert len(rec._times) == 8                   # 2 -> 4 -> 8
    whole = _Recorder(capacity=5)
    for k, row in enumerate(np.arange(15.0).reshape(5, 3)):
        whole(0.1 * k, row)
    assert whole.result(["a", "b", "c"], 0.0).data.base is whole._data      # a view: no copy
    empty = _Recorder(capacity=4).result(["a", "b"], wall=0.0)
    assert empty.data.shape == (0, 2) and empty.time.shape == (0,)

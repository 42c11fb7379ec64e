"""orchestration.study: in-memory runs, executors (local processes, Dask) and job mapping."""
from __future__ import annotations

import json
import operator
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

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
    # the coupling note of the cycle: on both results and in run.json (printed for the run only)
    assert len(mem.warnings) == 1 and "b.x -> a.x_other" in mem.warnings[0]
    assert mem.warnings == disk.warnings == json.loads((tmp_path / "out" / "run.json").read_text())["warnings"]


def test_simulate_and_run_evaluate_the_same_metrics(tmp_path):
    """One metric evaluation for both run paths, a truthless one (NIS) too."""
    path = write(tmp_path, MASS_SPRING + """
[[metrics]]
kind = "rmse"
name = "gap"
estimate = "a.x"
truth = "b.x"
after = 0.5
[[metrics]]
kind = "nis"
name = "n"
estimate = "a.x"
dof = 1
""")
    mem = study.simulate(path)
    disk = run(path, out_dir=tmp_path / "out")
    assert set(mem.metrics) >= {"gap", "n"}
    assert (mem.metrics, mem.metric_units, mem.against) == (disk.metrics, disk.metric_units, disk.against)
    keep = mem.time >= 0.5 - 1e-12
    assert_allclose(mem.metrics["gap"], np.sqrt(np.mean((mem["a.x"][keep] - mem["b.x"][keep]) ** 2)))


def test_structured_overrides_run_like_strings_and_are_recorded_as_strings(tmp_path):
    path = write(tmp_path, MASS_SPRING)
    mem = study.simulate(path, {("a", "k"): 9.0, ("scenario", "stop_time"): 0.5})
    assert_array_equal(mem["a.x"], study.simulate(path, ["a.k=9.0", "scenario.stop_time=0.5"])["a.x"])
    disk = run(path, {("a", "k"): 9.0, ("scenario", "stop_time"): 0.5}, out_dir=tmp_path / "out")
    assert_array_equal(disk["a.x"], mem["a.x"])
    assert json.loads((tmp_path / "out" / "run.json").read_text())["overrides"] == ["a.k=9.0",
                                                                                "scenario.stop_time=0.5"]


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


# ---------------------------------------------------------------------------------------------
# the study folder: finished jobs kept, --resume, lost workers, interrupts
# ---------------------------------------------------------------------------------------------
def _square_logged(k: int, log: str) -> int:
    """A test job: notes that it ran (``log/<k>.<pid>``), ends its worker process when the file
    ``log/exit<k>`` exists (removing it first with ``once`` in its name: ``exit<k>.once``)."""
    folder = Path(log)
    (folder / f"ran.{k}.{os.getpid()}.{time.monotonic_ns()}").touch()
    once = folder / f"exit{k}.once"
    if once.exists():
        once.unlink()
        os.kill(os.getpid(), signal.SIGKILL)
    if (folder / f"exit{k}").exists():
        os._exit(3)
    time.sleep(float((folder / "sleep").read_text()) if (folder / "sleep").exists() else 0.0)
    return k * k


def _ran(log: Path) -> list[int]:
    """The jobs that ran (sorted), and forget them."""
    runs = sorted(p for p in log.glob("ran.*"))
    for p in runs:
        p.unlink()
    return sorted(int(p.name.split(".")[1]) for p in runs)


def test_a_lost_worker_fails_only_its_job_and_resume_computes_only_it(tmp_path):
    log, out = tmp_path / "log", tmp_path / "study"
    log.mkdir()
    (log / "exit3").touch()               # job 3 ends its worker, every time
    jobs = [(k, str(log)) for k in range(6)]
    with pytest.raises(study.StudyError, match=r"1 of 6 jobs failed: job 3 \(\(3, .*WorkerLost: its "
                       r"worker process died twice.* the 5 finished are kept in") as info:
        with study.StudyFolder(out), study.open_executor(workers=2) as ex:
            study.map_jobs(_square_logged, jobs, ex, star=True, progress=False)
    assert info.value.results == [0, 1, 4, None, 16, 25]
    status = json.loads((out / "status.json").read_text())
    assert (status["status"], status["jobs_stored"]) == ("failed", 5)
    assert "job 3" in status["cause"]
    assert _ran(log).count(3) == 2       # tried, then retried once (alone)

    (log / "exit3").unlink()
    with study.StudyFolder(out, resume=True), study.open_executor(workers=2) as ex:
        assert study.map_jobs(_square_logged, jobs, ex, star=True, progress=False) == [k * k for k in range(6)]
    assert _ran(log) == [3]               # the finished runs were not computed again
    assert json.loads((out / "status.json").read_text())["status"] == "ok"


def test_a_worker_killed_once_is_retried_and_nothing_is_lost(tmp_path):
    log = tmp_path / "log"
    log.mkdir()
    (log / "exit2.once").touch()          # job 2's worker is killed (SIGKILL) the first time
    with study.open_executor(workers=2) as ex:
        assert study.map_jobs(_square_logged, [(k, str(log)) for k in range(5)], ex, star=True,
                              progress=False) == [k * k for k in range(5)]
    ran = _ran(log)
    assert ran.count(2) == 2 and set(ran) == set(range(5))


def test_a_study_folder_is_checked_and_locked_before_any_job(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(study.StudyError, match="not a folder"):
        study.StudyFolder(tmp_path / "file").__enter__()
    with pytest.raises(study.StudyError, match=r"--out .*/file/sub: Not a directory"):
        study.StudyFolder(tmp_path / "file" / "sub").__enter__()
    with pytest.raises(study.StudyError, match="--resume: .* is not a study folder"):
        study.StudyFolder(tmp_path / "new", resume=True).__enter__()
    out = tmp_path / "out"
    with study.StudyFolder(out) as folder:
        with pytest.raises(study.StudyError, match="another study writes there"):
            study.StudyFolder(out, resume=True).__enter__()
    with study.StudyFolder(out) as folder:         # no run stored: a new study may start there
        folder.store("k", 1.0)
    with pytest.raises(study.StudyError, match=r"holds 1 finished runs of a study \(status 'ok'\): add --resume"):
        study.StudyFolder(out).__enter__()


def test_a_full_disk_at_the_start_of_a_study_is_one_error_and_frees_the_folder(tmp_path, monkeypatch):
    import errno

    def full(path, obj):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))
    monkeypatch.setattr(study, "atomic_write_json", full)
    with pytest.raises(study.StudyError, match=r"--out .*/out: cannot write: No space left on device"):
        study.StudyFolder(tmp_path / "out").__enter__()
    monkeypatch.undo()
    with study.StudyFolder(tmp_path / "out"):      # the lock was released
        pass


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_ends_a_study_with_one_message_and_resume_finishes_it(tmp_path, signum):
    """A study in a child process gets SIGTERM or SIGINT once a run is stored: one line, status
    'interrupted', the stored runs kept; --resume computes only the others, same numbers."""
    log, out = tmp_path / "log", tmp_path / "study"
    log.mkdir()
    (log / "sleep").write_text("0.5")
    script = textwrap.dedent(f"""
        import argparse, sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from orchestration import cli, study
        from test_study import _square_logged

        def toy_study(args):
            with study.open_executor(workers=1) as ex:
                study.map_jobs(_square_logged, [(k, {str(log)!r}) for k in range(20)], ex, star=True,
                               progress=False)
            return 0
        sys.exit(cli.cmd_study(argparse.Namespace(out={str(out)!r}, resume=False, func=toy_study)))
    """)
    child = subprocess.Popen([sys.executable, "-c", script], stderr=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    deadline = time.monotonic() + 60                 # a hang guard, not a timing
    while not list((out / "jobs").glob("*.pickle")) and time.monotonic() < deadline:
        time.sleep(0.05)
    child.send_signal(signum)
    _, err = child.communicate(timeout=60)
    status = json.loads((out / "status.json").read_text())
    assert (status["status"], status["cause"]) == ("interrupted", signum.name)
    assert child.returncode == 128 + signum
    assert err.strip().splitlines() == [f"error: interrupted by {signum.name}: {status['jobs_stored']} finished runs "
                                        f"are kept in {out}; add --resume to continue"]
    kept = status["jobs_stored"]
    assert 1 <= kept < 20
    (log / "sleep").unlink()
    _ran(log)
    with study.StudyFolder(out, resume=True), study.open_executor(workers=2) as ex:
        assert study.map_jobs(_square_logged, [(k, str(log)) for k in range(20)], ex, star=True,
                              progress=False) == [k * k for k in range(20)]
    assert len(_ran(log)) == 20 - kept


@pytest.mark.parametrize("reply, message", [
    (None, r"no Dask scheduler answered at tcp://127\.0\.0\.1:\d+ within 2 s"),
    (b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n",
     r"the service at tcp://127\.0\.0\.1:\d+ does not answer as a Dask scheduler"),
])
def test_a_service_that_is_not_a_scheduler_is_one_clear_error_not_a_hang(reply, message):
    pytest.importorskip("distributed")
    import socket
    import threading
    server = socket.create_server(("127.0.0.1", 0))
    accepted = []

    def serve():
        conn, _ = server.accept()
        accepted.append(conn)
        if reply:
            conn.sendall(reply)
    threading.Thread(target=serve, daemon=True).start()
    address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
    with pytest.raises(study.StudyError, match=message):
        with study.open_executor(scheduler=address, connect_timeout=1):
            pass
    server.close()


@pytest.mark.parametrize("address, message", [
    ("nonsense", "missing port number"), ("foo://bar", "unknown address scheme 'foo'"),
    ("tcp://host:notaport", "invalid literal"),
])
def test_a_malformed_scheduler_address_is_one_line(tmp_path, capsys, address, message):
    pytest.importorskip("distributed")
    from orchestration import cli
    code = cli.main(["study", "robustness", "--out", str(tmp_path / "out"), "--scheduler", address,
                     "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"error: cannot reach the Dask scheduler at {address}: ") and message in err


def test_a_dask_cluster_recovers_a_killed_worker_and_the_folder_keeps_every_run(tmp_path):
    pytest.importorskip("distributed")
    log, out = tmp_path / "log", tmp_path / "study"
    log.mkdir()
    (log / "exit1.once").touch()          # job 1's worker is killed (SIGKILL) the first time
    jobs = [(k, str(log)) for k in range(4)]
    with study.StudyFolder(out), study.open_executor(workers=2, scheduler="local") as ex:
        assert study.map_jobs(_square_logged, jobs, ex, star=True, progress=False) == [0, 1, 4, 9]
    assert _ran(log).count(1) == 2        # the killed run was rescheduled by Dask
    with study.StudyFolder(out, resume=True), study.open_executor(workers=1) as ex:
        assert study.map_jobs(_square_logged, jobs, ex, star=True, progress=False) == [0, 1, 4, 9]
    assert _ran(log) == []


def test_process_pool_terminate_ends_its_busy_workers_and_only_them():
    """``ProcessPool.terminate`` (public APIs: the children started since the pool was made)
    ends workers in the middle of a long job at once; a child this process started before the
    pool lives on."""
    import multiprocessing
    other = multiprocessing.get_context("spawn").Process(target=time.sleep, args=(60,))
    other.start()
    pool = study.ProcessPool(2)
    try:
        jobs = [pool.submit(time.sleep, 60) for _ in range(2)]
        deadline = time.monotonic() + 60
        while len(pool.workers()) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        workers = pool.workers()
        assert len(workers) == 2 and other.pid not in {w.pid for w in workers}
        t0 = time.monotonic()
        pool.terminate()
        assert time.monotonic() - t0 < 30               # not the 60 s of the jobs
        assert not any(w.is_alive() for w in workers)
        assert all(j.done() for j in jobs)
        assert other.is_alive()
    finally:
        other.terminate()
        other.join()


class _Payload:
    """Unpickling it creates the marker file: what a crafted job file would run."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def _double(k: int) -> int:
    """A test job."""
    return 2 * k


def test_a_job_file_this_user_did_not_sign_is_never_unpickled_and_runs_again(tmp_path, monkeypatch):
    """--resume over job files replaced by a pickle with a payload (unsigned, and signed with
    another user's key: another cache root), a damaged one and a good one: only the good one is
    taken; the others run again, with a warning each, and the payload never runs."""
    import hashlib
    import hmac
    import pickle
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    out, marker = tmp_path / "study", tmp_path / "ran"
    jobs = [1, 2, 3, 4]
    with study.StudyFolder(out), study.open_executor(workers=1) as ex:
        assert study.map_jobs(_double, jobs, ex, progress=False) == [2, 4, 6, 8]
    files = [out / "jobs" / f"{study.StudyFolder.key(_double, j)}.pickle" for j in jobs]
    assert all(f.read_bytes().startswith(study.StudyFolder.MAGIC) for f in files)
    payload = pickle.dumps(_Payload(str(marker)))
    files[0].write_bytes(payload)                                        # unsigned
    other = hashlib.sha256(b"another user's key").digest()
    files[1].write_bytes(study.StudyFolder.MAGIC + hmac.new(other, payload, "sha256").digest() + payload)
    files[2].write_bytes(files[2].read_bytes()[:-3])                     # damaged
    with pytest.warns(UserWarning) as caught, study.StudyFolder(out, resume=True) as folder:
        keys = [study.StudyFolder.key(_double, j) for j in jobs]
        got = [folder.load(k) for k in keys]
    assert not marker.exists()
    assert [found for found, _ in got] == [False, False, False, True] and got[3][1] == 8
    messages = " ".join(str(w.message) for w in caught)
    assert "an unsigned file" in messages and "not this user's key's" in messages
    assert "never unpickled" in messages
    with study.StudyFolder(out, resume=True) as folder, study.open_executor(workers=1) as ex:   # again, signed
        assert study.map_jobs(_double, jobs, ex, progress=False) == [2, 4, 6, 8]
        assert (folder.computed, folder.reused) == (3, 1)
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "another user"))
    with pytest.warns(UserWarning, match="not this user's key's"), study.StudyFolder(out, resume=True) as folder, \
            study.open_executor(workers=1) as ex:
        assert study.map_jobs(_double, jobs, ex, progress=False) == [2, 4, 6, 8]
        assert folder.reused == 0
    assert not marker.exists()

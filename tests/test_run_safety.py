"""Nothing lost, nothing silent (issue 14), the single run: a full disk, two runs on one folder,
SIGINT / SIGTERM / SIGKILL, torn files, and the run-level bad inputs. Each case: the message,
the exit status, and what was computed before intact and readable by ``fmpy.util.read_csv``."""
from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from fmpy.util import read_csv
from numpy.testing import assert_allclose, assert_array_equal

from orchestration import CouplingWarning, OutputError, Result, ResultWarning, ScenarioError, run
from orchestration.cli import console_main, main
from orchestration.results import CsvWriter, own_folder, read_results_csv
from toys import MASS_SPRING, write

pytestmark = pytest.mark.usefixtures("toy_fmus")
REPO = Path(__file__).resolve().parent.parent

# a source feeding a gain; stop_time and steps set per test
CHAIN = """
connections = ["src.y -> g.u"]
[scenario]
name = "chain"
stop_time = {stop}
base_step = 0.001
seed = 1
[components.src]
fmu = "Source"
parameters = {{ slope = 3.0 }}
[components.g]
fmu = "Gain"
[record]
variables = ["src.y", "g.y", "src.noise"]
"""


def one_error_line(err: str, *parts: str) -> None:
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    for part in parts:
        assert part in err, err


def whole_rows(folder: Path) -> np.ndarray:
    """results.csv as fmpy reads it, checked against our reader: every row whole."""
    traj = read_csv(str(folder / "results.csv"))
    names, data, torn = read_results_csv(folder / "results.csv")
    assert not torn and traj.dtype.names == ("time", *names)
    assert_array_equal(traj["time"], data[:, 0])
    return data


# ---- disk full --------------------------------------------------------------------------------

def test_disk_full_ends_in_one_error_line_and_keeps_the_whole_rows(tmp_path, capsys, monkeypatch):
    """The third block of rows meets a full disk after half of it was written: the file is cut
    back to the rows before it; run.json says failed, with the time reached."""
    real_write, blocks = os.write, []

    def full_disk(fd: int, data: bytes) -> int:
        if not os.readlink(f"/proc/self/fd/{fd}").endswith("results.csv"):
            return real_write(fd, data)
        blocks.append(len(data))
        if len(blocks) == 4:                         # header, two blocks, then half of the third
            return real_write(fd, bytes(data)[:len(data) // 2])
        if len(blocks) > 4:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", full_disk)
    out = tmp_path / "o"
    assert main(["run", str(write(tmp_path, CHAIN.format(stop=1.0))), "--out", str(out), "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "cannot write the results after t = 0.399 s: No space left on device",
                   "the rows written before are kept, whole", f"(results up to then in {out})")
    data = whole_rows(out)
    assert len(data) == 400 and data[-1, 0] == 0.399        # 2 blocks of 200 rows (t = 0 .. 0.399)
    assert_allclose(data[:, 1], 3.0 * data[:, 0], rtol=1e-12)
    info = json.loads((out / "run.json").read_text())
    assert info["status"] == "failed" and "No space left" in info["error"]
    assert info["rows"] == 400 and info["time_reached"] == 0.399
    with pytest.warns(ResultWarning, match="the run is failed"):
        assert Result.load(out).status == "failed"


def test_a_metric_that_fails_after_the_run_keeps_every_row_and_says_so(tmp_path, capsys):
    """A band-pass over too short a record passes the load but cannot be computed: one error
    line, run.json says failed "after the run" with every row counted, no metrics.json; a
    study's in-memory run of the same scenario ends in the same error (one run path)."""
    from orchestration import study
    path = write(tmp_path, CHAIN.format(stop=0.02) + '''
[[metrics]]
kind = "bandpass"
name = "band"
estimate = "g.y"
truth = "src.y"
''')
    out = tmp_path / "o"
    assert main(["run", str(path), "--out", str(out), "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "metric 'band': band-pass needs more than 27 samples, got 21")
    info = json.loads((out / "run.json").read_text())
    assert info["status"] == "failed" and info["error"].startswith("after the run: chain: metric 'band'")
    assert info["rows"] == 21 and len(whole_rows(out)) == 21 and not (out / "metrics.json").exists()
    with pytest.raises(ScenarioError, match="metric 'band': band-pass needs more than 27 samples, got 21"):
        study.simulate(path)


def test_a_real_full_disk(tmp_path, capsys):
    """The same on a 64 KiB tmpfs (needs root and mount: skipped otherwise)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)],
                                           capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        out = disk / "o"
        assert main(["run", str(write(tmp_path, CHAIN.format(stop=100.0))), "--out", str(out), "--no-progress"]) == 2
        one_error_line(capsys.readouterr().err, "No space left on device", "the rows written before are kept")
        data = whole_rows(out)
        info = json.loads((out / "run.json").read_text())
        assert info["status"] == "failed" and info["rows"] == len(data) > 200
        assert main(["plot", str(out)]) == 2                 # no room for the PNGs either: one line
        err = capsys.readouterr().err.splitlines()
        assert err[0].startswith("warning: ") and err[1].startswith(f"error: {out}: cannot plot: ")
        assert len(err) == 2 and "No space left on device" in err[1]
    finally:
        subprocess.run(["umount", str(disk)], check=True)


def test_writer_cuts_a_failed_block_back_to_whole_rows(tmp_path, monkeypatch):
    real_write = os.write
    w = CsvWriter(tmp_path / "results.csv", ["a"], flush_every=2)
    for t in (0.0, 0.1):
        w(t, np.array([t]))

    def filling(fd: int, data: bytes) -> int:       # 5 bytes a call while there is more, then full
        if len(data) <= 5:
            raise OSError(errno.ENOSPC, "full")
        return real_write(fd, bytes(data)[:5])

    monkeypatch.setattr(os, "write", filling)
    w(0.2, np.array([0.2]))
    with pytest.raises(OSError):
        w(0.3, np.array([0.3]))
    monkeypatch.undo()
    w.close()
    assert (tmp_path / "results.csv").read_text() == '"time","a"\n0.0,0.0\n0.1,0.1\n'
    assert w.rows == 2 and w.time_reached == 0.1


# ---- torn files, killed runs --------------------------------------------------------------------

def test_a_torn_last_row_is_left_out_with_a_warning_and_plot_says_so(tmp_path, capsys):
    (tmp_path / "results.csv").write_text('"time","x"\n0.0,1.0\n0.001,2.0\n0.002,3')
    (tmp_path / "run.json").write_text(json.dumps({"status": "ok", "error": None, "rows": 3}))
    names, data, torn = read_results_csv(tmp_path / "results.csv")
    assert torn and names == ["x"] and data.tolist() == [[0.0, 1.0], [0.001, 2.0]]
    with pytest.warns(ResultWarning, match=r"the run is failed \(results.csv holds 2 of the 3 rows.*"
                                           r"t = 0.001 s; a torn last row was left out"):
        r = Result.load(tmp_path)
    assert r.status == "failed" and r["x"].tolist() == [1.0, 2.0]
    assert main(["plot", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert err.startswith("warning: ") and err.count("\n") == 1 and "the run is failed" in err
    (tmp_path / "run.json").unlink()
    with pytest.warns(ResultWarning, match=r"the run is unknown \(no run.json\)"):
        assert Result.load(tmp_path).status == "unknown"


def child(args: list[str]) -> subprocess.Popen:
    """``flexfusion`` in a child process (the console script), the toy FMUs on its path."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    return subprocess.Popen([sys.executable, "-c", "from orchestration.cli import console_main; console_main()",
                             *args], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for_rows(folder: Path, proc: subprocess.Popen, rows: int = 400, timeout: float = 60.0) -> None:
    csv = folder / "results.csv"
    t0 = time.monotonic()
    while not (csv.is_file() and csv.read_text().count("\n") > rows):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < timeout, "the child wrote no rows"
        time.sleep(0.05)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_ends_a_run_cleanly(tmp_path, sig):
    """One line, exit 128 + signal, run.json interrupted, every row up to then whole."""
    out = tmp_path / "o"
    proc = child(["run", str(write(tmp_path, CHAIN.format(stop=1000.0))), "--out", str(out), "--no-progress"])
    wait_for_rows(out, proc)
    proc.send_signal(sig)
    stdout, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig, err
    one_error_line(err, f"interrupted by {sig.name} at t = ", f"(results up to then in {out})")
    info = json.loads((out / "run.json").read_text())
    data = whole_rows(out)
    assert info["status"] == "interrupted" and sig.name in info["error"]
    assert info["rows"] == len(data) > 400 and info["time_reached"] == data[-1, 0]
    assert_allclose(data[:, 0], np.arange(len(data)) * 1e-3, atol=1e-9)
    with pytest.warns(ResultWarning, match=f"the run is interrupted \\(interrupted by {sig.name}"):
        assert Result.load(out).status == "interrupted"


def test_two_runs_on_one_folder_the_second_is_refused(tmp_path, toy_dir):
    """While a run owns the folder a second one is refused (exit 2) and changes nothing; after it
    the old results are refused unless --force; a killed run is reported, never as ok."""
    out, scenario = tmp_path / "o", str(write(tmp_path, CHAIN.format(stop=1000.0)))
    first = child(["run", scenario, "--out", str(out), "--no-progress"])
    wait_for_rows(out, first)
    second = child(["run", scenario, "--out", str(out), "--no-progress", "--force"])
    _, err = second.communicate(timeout=60)
    assert second.returncode == 2
    one_error_line(err, f"another run is writing to {out}")
    assert first.poll() is None                       # the first run goes on, its folder untouched
    with pytest.warns(ResultWarning, match="the run is running"):
        assert Result.load(out).status == "running"
    first.kill()                                      # SIGKILL: no handler, no final status
    first.wait()
    kept = whole_rows(out)
    with pytest.warns(ResultWarning, match=r"the run is interrupted \(the run ended without a final status"):
        assert Result.load(out).status == "interrupted"
    before = (out / "results.csv").read_bytes()
    third = child(["run", scenario, "--out", str(out), "--no-progress", "--set", "scenario.stop_time=0.01"])
    _, err = third.communicate(timeout=60)
    assert third.returncode == 2
    one_error_line(err, f"{out} holds the results of an earlier run (results.csv, run.json)", "--force")
    # every row seen before the kill (more than 400 lines with the header) is kept
    assert (out / "results.csv").read_bytes() == before and len(kept) >= 400
    assert main(["run", scenario, "--out", str(out), "--no-progress", "--force",
                 "--set", "scenario.stop_time=0.01"]) == 0
    assert Result.load(out).status == "ok" and len(whole_rows(out)) == 11


def test_own_folder_refuses_a_file_and_old_results(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputError, match="cannot use the output folder .*/f: File exists"):
        with own_folder(tmp_path / "f"):
            pass
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "notes.txt").write_text("mine")
    with own_folder(tmp_path / "o"):                  # other files: not results, left alone
        (tmp_path / "o" / "metrics.json").write_text("{}")
    with pytest.raises(OutputError, match="earlier run"):
        with own_folder(tmp_path / "o"):
            pass
    with own_folder(tmp_path / "o", force=True):
        assert sorted(p.name for p in (tmp_path / "o").iterdir()) == [".lock", "notes.txt"]


def test_ctrl_c_outside_a_run_is_one_line(monkeypatch, capsys):
    def interrupted(argv=None):
        raise KeyboardInterrupt
    monkeypatch.setattr("orchestration.cli.main", interrupted)
    with pytest.raises(SystemExit) as exit_info:
        console_main()
    assert exit_info.value.code == 130
    one_error_line(capsys.readouterr().err, "interrupted")


def test_the_console_script_loads_its_ctrl_c_handler_before_the_heavy_modules():
    """A Ctrl-C during start-up: the console script imports ``orchestration.cli`` first, and
    that loads neither numpy nor fmpy nor the master (the package's names load on first use),
    so ``console_main``'s handler is in place for the 0.3-0.7 s they take; before, a Ctrl-C
    then was a traceback. What is left is Python's own start (site), before any of our code."""
    code = ("import sys; from orchestration.cli import console_main; "
            "print(sorted(m for m in ('numpy', 'fmpy', 'orchestration.master', 'orchestration.scenario') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
    import orchestration       # the package's names still import as before
    assert orchestration.run is run and orchestration.ScenarioError is ScenarioError


# ---- run-level bad inputs -----------------------------------------------------------------------

@pytest.mark.parametrize("old, new, message", [
    ('fmu = "Gain"', 'fmu = "Gain"\nstep = 0.004', "component 'g': step 0.004 s is longer than the stop time 0.003 s"),
    ("[record]", '[[metrics]]\nkind = "max"\nestimate = "g.y"\ntruth = "src.y"\nafter = 0.5\n[record]',
     "metric 'max_g.y': after = 0.5 s leaves no recorded sample (the last is at t = 0.003 s"),
    ("base_step = 0.001", "base_step = 1e-12", "3e+09 base steps, more than the limit 1e+08"),
    ('name = "chain"', 'name = "../escape"', "[scenario] name '../escape' must be a plain folder name"),
    ('name = "chain"', 'name = "/tmp/abs"', "[scenario] name '/tmp/abs' must be a plain folder name"),
    ("slope = 3.0", "slope = 3.0, seed = 4294967297",
     "parameter 'seed' = 4294967297 is out of the FMI Integer range [-2147483648, 2147483647]"),
    ("connections = [", 'delays = ["src.y -> g.u"]\nconnections = [',
     "delays: 'src.y -> g.u' is where no cycle is broken"),
    ("connections = [", 'delays = ["g.y -> src.u"]\nconnections = [', "delay 'g.y -> src.u' is not one of the connections"),
])
def test_run_level_bad_inputs_end_in_one_line_and_write_nothing(tmp_path, capsys, monkeypatch, old, new,
                                                                message):
    monkeypatch.chdir(tmp_path)                       # the default output folder: results/<name>
    path = write(tmp_path, CHAIN.format(stop=0.003).replace(old, new, 1))
    assert main(["run", str(path), "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, message)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]


def test_a_name_from_set_is_confined_too(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = write(tmp_path, CHAIN.format(stop=0.003))
    assert main(["run", str(path), "--no-progress", "--set", 'scenario.name="../../x"']) == 2
    one_error_line(capsys.readouterr().err, "name '../../x' must be a plain folder name")
    assert main(["run", str(path), "--no-progress", "--set", "scenario.name=fine"]) == 0
    assert (tmp_path / "results" / "fine" / "results.csv").is_file()


def test_no_component_steps_past_the_stop_time(tmp_path):
    """stop 0.01 s is no multiple of a slow source's 0.004 s step: it steps at 0 and 0.004 s and
    its clock ends at 0.008 s, its outputs held after (it once stepped on to 0.012 s)."""
    path = write(tmp_path, CHAIN.format(stop=0.01).replace("[record]", '[components.slow]\nfmu = "Source"\n'
                                                            'step = 0.004\n[record]')
                 .replace('"src.noise"', '"src.noise", "src.n", "slow.n", "slow.t_s"'))
    r = run(path, out_dir=tmp_path / "o")
    assert r.time[-1] == pytest.approx(0.01) and r["src.n"][-1] == 10
    assert r["slow.n"][-1] == 2
    assert_allclose(r["slow.t_s"][r.time >= 0.008], 0.008, rtol=1e-12)


def test_seeds_beyond_32_bits_differ(tmp_path):
    """A scenario seed is hashed with each component's name (any integer); a seed past 2**32
    gives other noise than the seed it would wrap to."""
    path = write(tmp_path, CHAIN.format(stop=0.01))
    a = run(path, ["scenario.seed=1"], out_dir=tmp_path / "a")
    b = run(path, [f"scenario.seed={2**32 + 1}"], out_dir=tmp_path / "b")
    assert not np.allclose(a["src.noise"][1:], b["src.noise"][1:])


def test_scenario_seeds_give_distinct_component_seeds():
    """Within the seeds studies use (0 .. 20,000 here; 0 .. 2,000,000 checked once by hand) no two
    scenario seeds give a component of the shipped scenarios the same seed."""
    import tomllib
    from orchestration.scenario import stable_seed
    names = {name for f in (REPO / "orchestration" / "scenarios").glob("*.toml")
             for name in tomllib.loads(f.read_text()).get("components", {})}
    assert "plant" in names
    for name in names:
        assert len({stable_seed(seed, name) for seed in range(20_000)}) == 20_000, name


def test_a_declared_delay_breaks_the_cycle_quietly_with_the_same_numbers(tmp_path, capsys):
    with pytest.warns(CouplingWarning):
        plain = run(write(tmp_path, MASS_SPRING, "plain.toml"), ["scenario.stop_time=0.2"], out_dir=tmp_path / "a")
    declared = MASS_SPRING.replace("connections = [", 'delays = ["b.x -> a.x_other"]\nconnections = [')
    declared += '[[metrics]]\nkind = "max"\nname = "gap"\nestimate = "a.x"\ntruth = "b.x"\n'
    path = write(tmp_path, declared, "declared.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("error", CouplingWarning)
        delayed = run(path, ["scenario.stop_time=0.2"], out_dir=tmp_path / "b")
    assert_array_equal(delayed["a.x"], plain["a.x"])
    assert main(["run", str(path), "--out", str(tmp_path / "c"), "--no-progress", "--set", "scenario.stop_time=0.2"]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""                            # no cycle warning
    assert f"  {'gap':<32} {delayed.metrics['gap']:.6g} m" in captured.out.splitlines()   # with its unit
    assert json.loads((tmp_path / "c" / "metrics.json").read_text())["gap"]["unit"] == "m"
    with pytest.raises(ScenarioError, match="delay 'a.x -> b.y' is not one of the connections"):
        run(write(tmp_path, declared.replace('["b.x -> a.x_other"]', '["a.x -> b.y"]'), "bad.toml"))

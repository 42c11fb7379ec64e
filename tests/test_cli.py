"""The flexfusion CLI: run, plot, export-ssp; every user error is one line and exit status 2."""
from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from orchestration.cli import main
from orchestration.results import CsvWriter
from toys import FAILING, write


pytestmark = pytest.mark.usefixtures("toy_fmus")


GOOD = """
connections = ["src.ys -> g.uv", "src.y -> g.u"]
[scenario]
name = "toy"
stop_time = 0.2
base_step = 0.001
seed = 4
[components.src]
fmu = "Source"
[components.g]
fmu = "Gain"
parameters = { gain = 1.0 }
[record]
variables = ["src.ys", "g.yv", "src.noise"]
[[metrics]]
kind = "max"
name = "gain_error"
estimate = "g.yv"
truth = "src.ys"
"""


def test_run_writes_results_and_prints_metrics(tmp_path, capsys):
    path = write(tmp_path, GOOD)
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--no-progress", "--set", "g.gain=2"]) == 0
    out = capsys.readouterr().out
    assert "toy: 201 rows" in out and "gain_error" in out
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert metrics["gain_error"]["value"] == pytest.approx(np.hypot(0.2, 0.4))     # |2 ys - ys| at t = 0.2
    assert metrics["gain_error"]["against"] == "estimator"     # a toy FMU: neither plant nor reference
    info = json.loads((tmp_path / "o" / "run.json").read_text())
    assert info["overrides"] == ["g.gain=2"] and info["status"] == "ok"


def test_run_with_progress_bar(tmp_path, capsys):
    assert main(["run", str(write(tmp_path, GOOD)), "--out", str(tmp_path / "o")]) == 0
    assert "step" in capsys.readouterr().err


def test_cycle_warning_is_one_line(tmp_path, capsys):
    text = GOOD.replace('connections = ["src.ys -> g.uv", "src.y -> g.u"]',
                        'connections = ["a.x -> b.x_other", "b.x -> a.x_other"]')
    text = text.replace("[record]", '[components.a]\nfmu = "MassSpring"\n[components.b]\nfmu = "MassSpring"\n[record]')
    assert main(["run", str(write(tmp_path, text)), "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("warning: toy: connection 'b.x -> a.x_other' is in a cycle")


BAD = [
    (('"src.y -> g.u"', '"src.y -> nope.u"'), "unknown component 'nope'"),
    (('"src.y -> g.u"', '"src.y -> g.v"'), "component 'g' (Gain) has no variable 'v'"),
    (('"src.y -> g.u"', '"src.y -> g.y"'), "output-to-output connection"),
    (('"src.y -> g.u"', '"g.u -> g.u"'), "input-to-input connection"),
    (('"src.y -> g.u"', '"src.t_s -> g.u"'), "unit mismatch: 'src.t_s' is in s, 'g.u' in 1"),
    (('fmu = "Gain"', 'fmu = "NoSuchFmu"'), "FMU file not found"),
    (("seed = 4", "seed = 4\n[components.src]\nstep = 0.0015"), "malformed TOML"),
    (('fmu = "Source"', 'fmu = "Source"\nstep = 0.0015'), "not an integer multiple of the base step"),
    (("stop_time = 0.2", "stop_time = = 0.2"), "line 5"),
    (("[components.g]", '[components."g,x"]'), "component name 'g,x' must be an identifier"),
    (("[components.g]", '[components."g\\nx"]'), "component name 'g\\nx' must be an identifier"),
    (('[components.g]\nfmu = "Gain"\nparameters = { gain = 1.0 }', "[components]\ng = 5"),
     "[components.g] must be a table, got an integer"),
    (('[components.g]\nfmu = "Gain"\nparameters = { gain = 1.0 }', '[components.g]\nfmu = "Gain"\nparameters = 2'),
     "[parameters] must be a table"),
    (("seed = 4", "seed = 4\ninclude = 5"), "include must be a file name or a list of file names, got 5"),
    (("seed = 4", "seed = 4\ninclude = [[1]]"), "include must be a file name or a list of file names"),
]


@pytest.mark.parametrize("change, message", BAD)
def test_user_errors_exit_2_with_one_line(tmp_path, capsys, change, message):
    path = write(tmp_path, GOOD.replace(*change, 1))
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert message in err and "Traceback" not in err
    assert str(path) in err


ZIP = b"PK\x03\x04"


def _zipped(*names: str) -> bytes:
    import io
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as z:
        for name in names:
            z.writestr(name, "")
    return buffer.getvalue()


@pytest.mark.parametrize("content, message", [
    (GOOD.encode("utf-16"), "the file is UTF-16; a TOML scenario must be UTF-8"),
    (GOOD.replace('"toy"', '"t\u00ff"').encode("latin-1"),
     "not UTF-8 text (Latin-1?): a TOML scenario must be UTF-8; the first byte that is not is at line 4, column 10"),
    (b"\x7fELF\x02\x01\x00\x00\xff\xfe", "a binary file: a TOML scenario must be UTF-8"),
    (ZIP + b"\x14\x00 a torn zip", "this is a zip archive, not a TOML scenario"),
    (_zipped("SystemStructure.ssd", "resources/Gain.fmu"), "this is an SSP package (flexfusion runs one whose "
     "name ends in .ssp), not a TOML scenario"),
    (_zipped("modelDescription.xml", "binaries/linux64/Gain.so"), "this is an FMU (name it in a scenario"),
])
@pytest.mark.parametrize("command", ["run", "export-ssp"])
def test_a_scenario_that_is_not_utf8_text_is_one_error_line(tmp_path, capsys, content, message, command):
    path = tmp_path / "scenario.toml"          # a .ssp name is read as an SSP package
    path.write_bytes(content)
    argv = [command, str(path)] + (["-o", str(tmp_path / "x.ssp")] if command == "export-ssp" else ["--no-progress"])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {path}: {message}") and err.count("\n") == 1, err


def test_os_errors_on_the_output_folder_are_one_line(tmp_path, capsys, monkeypatch):
    import errno

    from orchestration import master
    path = write(tmp_path, GOOD)
    (tmp_path / "file").write_text("")
    for out, reason in ((tmp_path / "file", "File exists"), (tmp_path / "file" / "sub", "Not a directory")):
        assert main(["run", str(path), "--out", str(out), "--no-progress"]) == 2
        assert capsys.readouterr().err == f"error: cannot use the output folder {out}: {reason}\n"

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "o" / "results.csv"))
    monkeypatch.setattr(master, "run", full)
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    assert capsys.readouterr().err == (f"error: cannot use the output folder {tmp_path / 'o' / 'results.csv'}: "
                                       "No space left on device\n")


@pytest.mark.parametrize("mode, message", [
    ("error", "component 'bad' failed at t = 0.05 s: fmi2DoStep returned discard; FMU log: "
              "[error] bad: step at t = 0.05 s: toy failure"),
    ("nan", "NaN on a connection: component 'bad' output 'y' is NaN at t = 0.051 s"),
])
def test_run_failures_exit_2_keep_results(tmp_path, capsys, mode, message):
    path = write(tmp_path, FAILING.format(mode=mode))
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err
    assert message in err and str(tmp_path / "o") in err
    rows = (tmp_path / "o" / "results.csv").read_text().splitlines()
    assert rows[0] == '"time","bad.y"' and rows[-1].startswith("0.05,")


@pytest.mark.parametrize("argv, message", [
    (["run", "missing.toml", "--no-progress"], "scenario file not found"),
    (["run", "{s}", "--set", "g.gain", "--no-progress"], "expected comp.param=value"),
    (["run", "{s}", "--set", "nope.gain=1", "--no-progress"], "unknown component 'nope'"),
    (["plot", "{tmp}/nothing"], "no such run folder"),
    (["plot", "{tmp}"], "not a run folder"),
    (["export-ssp", "missing.toml", "-o", "{tmp}/x.ssp"], "scenario file not found"),
])
def test_other_user_errors(tmp_path, capsys, argv, message):
    s = write(tmp_path, GOOD)
    argv = [a.format(s=s, tmp=tmp_path) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err


def test_plot_writes_pngs(tmp_path, capsys):
    path = write(tmp_path, GOOD)
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    assert main(["plot", str(tmp_path / "o")]) == 0
    png = tmp_path / "o" / "variables.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (tmp_path / "o" / "tool_path.png").exists()


def test_plot_tool_path_when_truth_and_estimates_are_recorded(tmp_path):
    cols = ["plant.p_tool[1]", "plant.p_tool[2]", "rigid.p_tool_hat[1]", "rigid.p_tool_hat[2]",
            "ekf.p_tool_hat[1]", "ekf.p_tool_hat[2]"]
    with CsvWriter(tmp_path / "results.csv", cols) as w:
        for t in np.arange(0, 1, 0.01):
            p = np.array([1.2 + 0.1 * np.cos(t), 0.9 + 0.1 * np.sin(t)])
            w(t, np.r_[p, p + 1e-3, p - 1e-4])
    assert main(["plot", str(tmp_path)]) == 0
    assert (tmp_path / "tool_path.png").read_bytes()[:4] == b"\x89PNG"


def test_export_ssp(tmp_path, capsys, toy_dir):
    path = write(tmp_path, GOOD)
    out = tmp_path / "toy.ssp"
    assert main(["export-ssp", str(path), "-o", str(out), "--set", "g.gain=3"]) == 0
    with zipfile.ZipFile(out) as z:
        names = set(z.namelist())
        ssd = z.read("SystemStructure.ssd").decode()
    assert names == {"SystemStructure.ssd", "resources/Source.fmu", "resources/Gain.fmu"}
    assert 'startElement="src" startConnector="ys[2]" endElement="g" endConnector="uv[2]"' in ssd
    assert 'name="gain"' in ssd and 'value="3.0"' in ssd
    assert 'baseStepSize="0.001"' in ssd


def _commands() -> list[list[str]]:
    import argparse

    from orchestration.cli import study_modules
    kinds = argparse.ArgumentParser().add_subparsers()
    for module in study_modules():
        module.register(kinds)
    return [[], ["build"], ["run"], ["plot"], ["export-ssp"], ["study"]] + [["study", k] for k in kinds.choices]


@pytest.mark.parametrize("command", _commands(), ids=" ".join)
def test_every_help_exits_0_and_reads_as_text(capsys, command):
    """An unescaped % in a help string made argparse print a Python dict."""
    import re
    with pytest.raises(SystemExit) as exit_:
        main(command + ["--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: flexfusion")
    assert "{'" not in out and "Traceback" not in out
    assert not re.search(r"issue\s*#?\d", out, re.I)


def test_version_is_the_distributions(capsys):
    from importlib import metadata
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out == f"flexfusion {metadata.version('flexfusion')}\n"


def test_stop_time_is_scenario_stop_time_after_every_set(tmp_path, capsys):
    path = write(tmp_path, GOOD)
    assert main(["run", str(path), "--out", str(tmp_path / "a"), "--no-progress", "--stop-time", "0.05"]) == 0
    assert main(["run", str(path), "--out", str(tmp_path / "b"), "--no-progress",
                 "--set", "scenario.stop_time=0.05"]) == 0
    assert main(["run", str(path), "--out", str(tmp_path / "c"), "--no-progress",
                 "--set", "scenario.stop_time=0.1", "--stop-time", "0.05"]) == 0
    a = (tmp_path / "a" / "results.csv").read_bytes()
    assert a == (tmp_path / "b" / "results.csv").read_bytes() == (tmp_path / "c" / "results.csv").read_bytes()
    assert a.count(b"\n") == 1 + 51                      # header, t = 0 .. 0.05 at 1 ms
    assert json.loads((tmp_path / "c" / "run.json").read_text())["overrides"][-1] == "scenario.stop_time=0.05"
    capsys.readouterr()
    assert main(["run", str(path), "--out", str(tmp_path / "d"), "--no-progress", "--stop-time", "-1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "stop_time" in err and "> 0" in err, err


@pytest.mark.parametrize("override, message", [
    ("scr.gain=1", "unknown component 'scr' (components: src, g) (did you mean 'src'?)"),
    ("g.gian=1", "component 'g' has no parameter 'gian' (did you mean 'gain'?)"),
    ("scenario.stop_tim=1", "unknown scenario key 'stop_tim' (allowed: seed, stop_time, base_step, "
     "name, description) (did you mean 'stop_time'?)"),
    ("g.xyzzy=1", "component 'g' has no parameter 'xyzzy'\n"),       # nothing close: no guess
])
def test_did_you_mean_for_a_misspelt_override(tmp_path, capsys, override, message):
    path = write(tmp_path, GOOD)
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--no-progress", "--set", override]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("change, message", [
    (('variables = ["src.ys"', 'variables = ["src.yss"'),
     "component 'src' (Source) has no variable 'yss' (did you mean 'ys'"),
    (('estimate = "g.yv"', 'estimate = "gg.yv"'), "unknown component 'gg' (components: src, g) (did you mean 'g'?)"),
    (("seed = 4", "seed = 4\nstop_tme = 1"), "(did you mean 'stop_time'?)"),
])
def test_did_you_mean_in_a_scenario_file(tmp_path, capsys, change, message):
    path = write(tmp_path, GOOD.replace(*change, 1))
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err


@pytest.mark.parametrize("workers", ["0", "-3"])
@pytest.mark.parametrize("command", [
    ["run", "{s}", "--save-state-at", "0.1", "--forks", "2", "--out", "{tmp}/o"],
    ["study", "montecarlo", "{s}", "--runs", "2", "--out", "{tmp}/o"],
])
def test_workers_below_one_is_refused_before_anything_runs(tmp_path, capsys, workers, command):
    s = write(tmp_path, GOOD)
    argv = [a.format(s=s, tmp=tmp_path) for a in command] + ["--workers", workers]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err == f"error: --workers must be at least 1, not {workers}\n"
    assert not (tmp_path / "o").exists()


def test_verbosity_flags_set_the_log_level_and_quiet_drops_the_progress_bar(tmp_path, capsys):
    import logging
    path = write(tmp_path, GOOD)
    package = logging.getLogger("orchestration")
    try:
        assert main(["-v", "run", str(path), "--out", str(tmp_path / "v"), "--no-progress"]) == 0
        assert package.level == logging.INFO
        err = capsys.readouterr().err
        assert "INFO: scenario toy from" in err and "stop_time 0.2 s" in err, err
        assert main(["run", str(path), "--out", str(tmp_path / "q"), "-q"]) == 0
        assert package.level == logging.ERROR
        captured = capsys.readouterr()
        assert captured.err == "" and "toy: 201 rows" in captured.out     # no bar, no log line
        assert main(["run", str(path), "--out", str(tmp_path / "w"), "--no-progress"]) == 0
        assert package.level == logging.WARNING and capsys.readouterr().err == ""
        assert main(["--log-level", "debug", "run", str(path), "--out", str(tmp_path / "d"),
                     "--no-progress", "-q"]) == 0                      # --log-level wins over -q
        assert package.level == logging.DEBUG and "INFO: scenario toy" in capsys.readouterr().err
        assert main(["-vv", "plot", str(tmp_path / "v")]) == 0
        assert package.level == logging.DEBUG
        capsys.readouterr()
        assert main(["study", "montecarlo", str(path), "--runs", "2", "--out", str(tmp_path / "m"),
                     "--workers", "0", "-q"]) == 2                     # after `study KIND` too
        assert package.level == logging.ERROR and "--workers" in capsys.readouterr().err
    finally:
        package.setLevel(logging.NOTSET)


def test_help_has_examples(capsys):
    for command in ([], ["run"]):
        with pytest.raises(SystemExit):
            main(command + ["--help"])
        out = capsys.readouterr().out
        assert "examples:\n  flexfusion " in out and "--stop-time" in out

"""The master's stepping loop in C (orchestration/cosim_loop.c, orchestration/cloop.py) against
its reference, the Python loop: the same bytes on disk, the same errors with the same rows kept,
the same interruption, the same forks."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import warnings
from pathlib import Path

import pytest

from fmus.common import native_cache
from orchestration import CouplingWarning, RunError, cloop, fork, master, run
from orchestration.build import BuildError
from orchestration.native import c_compiler
from toys import FAILING, MASS_SPRING, write

SCENARIOS = Path(__file__).resolve().parent.parent / "orchestration" / "scenarios"
WHY_NOT = cloop.unavailable()
needs_c = pytest.mark.skipif(WHY_NOT is not None, reason=f"no C loop: {WHY_NOT}")


def _compiler() -> list[str] | None:
    try:
        return c_compiler()
    except BuildError:
        return None


needs_cc = pytest.mark.skipif(_compiler() is None, reason="no C compiler")


def both(tmp_path: Path, go) -> dict[str, object]:
    """``go(out_dir)`` with the C loop and with the Python loop: ``{"c": ..., "python": ...}``,
    each its return value or the exception it raised."""
    got: dict[str, object] = {}
    for mode in ("c", "python"):
        with pytest.MonkeyPatch.context() as mp:
            if mode == "python":
                mp.setattr(cloop, "library", lambda: None)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", CouplingWarning)
                try:
                    got[mode] = go(tmp_path / mode)
                except (RunError, KeyboardInterrupt) as exc:
                    got[mode] = exc
    return got


def same_files(tmp_path: Path, *names: str) -> None:
    for name in names:
        c, py = ((tmp_path / mode / name).read_bytes() for mode in ("c", "python"))
        assert c == py, name


@needs_c
@pytest.mark.usefixtures("toy_fmus")
def test_the_c_loop_is_the_one_that_runs(tmp_path, monkeypatch):
    """The comparisons below mean something only if the C loop runs by default."""
    def no_python_loop(*args):
        raise AssertionError("the Python loop ran")
    monkeypatch.setattr(master, "_python_steps", no_python_loop)
    r = run(write(tmp_path, FAILING.format(mode="error").replace("fail_at = 0.05", "fail_at = 1.0")),
            out_dir=tmp_path / "o")
    assert r.time[-1] == pytest.approx(0.1)


# ---- the same results -----------------------------------------------------------------------

@needs_c
@pytest.mark.usefixtures("fmu_env")
def test_flagship_is_byte_identical_in_both_loops(tmp_path):
    """Seven FMUs at 1 kHz, a declared delay on the control loop (a broken cycle)."""
    both(tmp_path, lambda out: run(SCENARIOS / "flagship.toml", ["scenario.stop_time=1.0"], out_dir=out))
    same_files(tmp_path, "results.csv", "metrics.json")


@needs_c
@pytest.mark.usefixtures("toy_fmus")
def test_multirate_with_a_broken_cycle_and_sparse_records_is_byte_identical(tmp_path):
    """Mass-springs coupled through a cycle broken with a warning (Jacobi edge), one of them at
    three base steps, a source at two, a gain at five (the pattern's period 30), every third
    base step recorded, and a stop time that no step but the base divides."""
    text = (MASS_SPRING.replace('connections = [', 'connections = ["src.y -> g.u", ')
            .replace("stop_time = 2.0", "stop_time = 0.97")
            .replace("[components.b]", '[components.src]\nfmu = "Source"\nstep = 0.02\n'
                     '[components.g]\nfmu = "Gain"\nstep = 0.05\n[components.b]\nstep = 0.03')
            .replace('variables = ["a.x", "b.x"]', 'variables = ["a.x", "b.x", "g.y", "src.n"]\ninterval = 0.03'))
    got = both(tmp_path, lambda out: run(write(tmp_path, text), out_dir=out))
    same_files(tmp_path, "results.csv")
    r = got["c"]
    assert len(r.time) == 33 and r.time[-1] == pytest.approx(0.96)       # 0, 0.03, ... 0.96


# ---- failures: the same message, the same rows kept ----------------------------------------

@needs_c
@pytest.mark.usefixtures("toy_fmus")
@pytest.mark.parametrize("text, rows, message", [
    (FAILING.format(mode="error"), 51, "component 'bad' failed at t = 0.05 s: fmi2DoStep returned discard; FMU log: [error] bad: step at t = 0.05 s: toy failure"),
    (FAILING.format(mode="nan"), 51, "NaN on a connection: component 'bad' output 'y' is NaN at t = 0.051 s"),
    # the consumer (every 2 ms) does not step at the NaN's base step: the per-step check names it
    (FAILING.format(mode="nan").replace("fail_at = 0.05", "fail_at = 0.0515")
     .replace('fmu = "Gain"', 'fmu = "Gain"\nstep = 0.002'), 52,
     "NaN on a connection: component 'bad' output 'y' is NaN at t = 0.052 s"),
], ids=["fmu-error", "nan", "nan-between-consumer-steps"])
def test_a_failure_mid_run_gives_the_same_error_and_keeps_every_row(tmp_path, text, rows, message):
    got = both(tmp_path, lambda out: run(write(tmp_path, text), out_dir=out))
    assert isinstance(got["c"], RunError) and str(got["c"]) == str(got["python"])
    assert message in str(got["c"])
    assert (got["c"].time, got["c"].component) == (got["python"].time, got["python"].component)
    same_files(tmp_path, "results.csv")
    info = json.loads((tmp_path / "c" / "run.json").read_text())
    assert info["status"] == "failed" and info["rows"] == rows


# ---- a signal stops between chunks, every row kept ------------------------------------------

@needs_c
@pytest.mark.usefixtures("toy_fmus")
def test_a_signal_stops_the_run_at_the_end_of_its_chunk_with_the_same_rows(tmp_path):
    """SIGINT sent while the rows of t = 0.05 s are sunk: the run stops at the next check, the
    end of the chunk of 100 base steps (t = 0.1 s), in both loops, with rows 0 .. 0.1 s."""
    text = FAILING.format(mode="error").replace("stop_time = 0.1", "stop_time = 1000.0") \
        .replace("fail_at = 0.05", "fail_at = 1e9")
    path = write(tmp_path, text)

    def go(out):
        simulate = master.simulate

        def signalled(sc, sink, *rest):
            def row(t, values):
                sink(t, values)
                if t == 0.05:
                    os.kill(os.getpid(), signal.SIGINT)
            return simulate(sc, row, *rest)

        with pytest.MonkeyPatch.context() as mp, master.stop_on_signals():
            mp.setattr(master, "simulate", signalled)
            return run(path, out_dir=out)

    got = both(tmp_path, go)
    for exc in got.values():
        assert isinstance(exc, master.Interrupted) and exc.time == 0.1 and exc.signum == signal.SIGINT
    same_files(tmp_path, "results.csv")
    assert json.loads((tmp_path / "c" / "run.json").read_text())["rows"] == 101


# ---- forks: a state saved by one loop, resumed by the other ---------------------------------

@needs_c
@pytest.mark.usefixtures("fmu_env")
def test_states_saved_and_resumed_by_either_loop_give_the_same_results(tmp_path):
    """The fork hooks (save at a base step inside a chunk, start from it) in both loops: both
    saves are the same file, and each loop's fork from it equals the other's."""
    scenario, stop, t = SCENARIOS / "replay_record.toml", ["scenario.stop_time=0.4"], 0.137
    both(tmp_path, lambda out: fork.run_saving(scenario, t, out / "state.json", stop, out_dir=out / "run"))
    same_files(tmp_path, "state.json", "run/results.csv")
    got = both(tmp_path / "fork", lambda out: fork.resume(scenario, tmp_path / "c" / "state.json", stop,
                                                          out_dir=out))
    same_files(tmp_path / "fork", "results.csv")
    assert got["c"].time[0] == pytest.approx(t)


# ---- the library --------------------------------------------------------------------------

@needs_cc
def test_the_loop_compiles_without_warnings(tmp_path):
    result = subprocess.run([*c_compiler(), *cloop.CFLAGS, "-Werror", str(cloop.SOURCE), "-o",
                             str(tmp_path / "loop.so")], capture_output=True, text=True)
    assert result.returncode == 0 and not result.stderr, result.stderr


@needs_cc
def test_compiled_once_into_the_cache_then_reused(tmp_path, monkeypatch):
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path))
    first = cloop._compiled()
    assert first.is_relative_to(tmp_path / "loop") and first.name == cloop.LIBRARY_NAME
    stamp = first.stat().st_mtime_ns
    assert cloop._compiled() == first and first.stat().st_mtime_ns == stamp


def test_without_a_compiler_or_when_asked_the_python_loop_runs(tmp_path, monkeypatch):
    def no_compiler():
        raise FileNotFoundError("no C compiler found (tried ...)")
    monkeypatch.delenv("FLEXFUSION_PYTHON_LOOP", raising=False)
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr("fmus.common.native_cache.c_compiler", no_compiler)
    try:
        cloop.library.cache_clear()
        assert cloop.library() is None and "no C compiler" in cloop.unavailable()
        cloop.library.cache_clear()
        monkeypatch.setenv("FLEXFUSION_PYTHON_LOOP", "1")
        assert cloop.library() is None and "FLEXFUSION_PYTHON_LOOP" in cloop.unavailable()
    finally:
        cloop.library.cache_clear()


PLANTED = r"""
#include <stdio.h>
__attribute__((constructor)) static void planted(void) { FILE *f = fopen(MARKER, "w"); if (f) fclose(f); }
long cosim_steps(void) { return 0; }
"""


def _plant(folder: Path, marker: Path, mode: int = 0o755, record: bool = True) -> Path:
    """A library that creates ``marker`` as soon as it is loaded, at the C loop's place in
    ``folder`` (with its hash recorded, as a compiled one has, if ``record``)."""
    folder.mkdir(parents=True, exist_ok=True)
    source = folder.parent / "planted.c"
    source.write_text(PLANTED)
    lib = folder / cloop.LIBRARY_NAME
    subprocess.run([*c_compiler(), "-shared", "-fPIC", f'-DMARKER="{marker}"', str(source), "-o", str(lib)],
                   check=True)
    if record:
        lib.with_name(lib.name + ".sha256").write_text(native_cache.sha256(lib) + "\n")
    lib.chmod(mode)
    return lib


@pytest.fixture
def cache_dirs(tmp_path, monkeypatch):
    """A cache root and a temporary directory of the test's own; ``cloop.library`` recomputed."""
    monkeypatch.delenv("FLEXFUSION_PYTHON_LOOP", raising=False)
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    cloop.library.cache_clear()
    yield tmp_path / "cache", tmp_path / "tmp" / f"flexfusion-{os.getuid()}"
    cloop.library.cache_clear()


@needs_cc
def test_a_library_planted_in_a_folder_others_can_write_is_not_loaded(cache_dirs, tmp_path):
    """The cache root cannot be written (a file stands there): the fallback folder in the
    temporary directory, made by someone else with mode 0777 and holding a library (with its
    hash), is not used at all: no C loop, the Python loop runs, and the library never loaded."""
    root, fallback = cache_dirs
    root.write_text("not a folder")
    marker = tmp_path / "loaded"
    _plant(fallback / "loop" / cloop._key(), marker)
    for folder in (fallback, fallback / "loop", fallback / "loop" / cloop._key()):
        folder.chmod(0o777)
    assert cloop.library() is None
    assert "writable by group or others (mode 777)" in cloop.unavailable()
    assert not marker.exists()
    fallback.chmod(0o700)                 # only the top was open: the next one below is refused too
    cloop.library.cache_clear()
    assert cloop.library() is None and f"{fallback / 'loop'}: writable by group" in cloop.unavailable()
    assert not marker.exists()


@needs_cc
@pytest.mark.parametrize("case", ["world-writable", "other owner", "no hash recorded", "truncated"])
def test_a_library_that_fails_its_check_is_set_aside_and_compiled_again(cache_dirs, tmp_path, case):
    """In a private cache folder, a library writable by others, owned by another user (where
    the test may chown), with no hash recorded at compile time, or truncated after it (a disk
    that filled up) is not loaded: it is set aside (``.bad-*``) and the loop compiled again."""
    root, _ = cache_dirs
    folder = root / "loop" / cloop._key()
    marker = tmp_path / "loaded"
    if case == "truncated":
        lib = cloop._compiled()
        lib.write_bytes(lib.read_bytes()[:4096])
    else:
        lib = _plant(folder, marker, mode=0o666 if case == "world-writable" else 0o755,
                     record=case != "no hash recorded")
        root.chmod(0o700)
        (root / "loop").chmod(0o700)
        folder.chmod(0o700)
    if case == "other owner":
        if os.geteuid() != 0:
            pytest.skip("changing a file's owner needs root")
        os.chown(lib, 4242, 4242)
    why = {"world-writable": "writable by group or others", "other owner": "owned by user 4242",
           "no hash recorded": "no hash recorded", "truncated": "not what was compiled"}[case]
    with pytest.warns(UserWarning, match=f"cached C loop was not loaded .*{why}.*compiled again"):
        assert cloop.library() is not None
    assert not marker.exists()
    assert native_cache.verified(lib) and len(list(folder.glob(f".bad-*-{cloop.LIBRARY_NAME}"))) == 1
    assert cloop._compiled() == lib                                     # and now it is reused

"""``flexfusion cache info|clear`` (orchestration/caches.py) and the one self-repair of a cached
FMU folder whose library does not load, on toy FMUs (tests/fmus)."""
from __future__ import annotations

import os
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

from orchestration import caches, cli, fmu_store
from test_fmu_store import HOLD, variant
from toys import write

pytestmark = pytest.mark.usefixtures("toy_fmus")

ONE_GAIN = """
[scenario]
stop_time = 0.01
base_step = 0.001
[components.g]
fmu = "{fmu}"
[record]
variables = ["g.y"]
"""


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    root = tmp_path / "cache"
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(root))
    return root


def test_info_lists_each_cache_with_its_size_and_entries(cache, toy_dir, capsys):
    fmu_store.cached_folder(toy_dir / "Gain.fmu")
    fmu_store.cached_folder(toy_dir / "Source.fmu")
    (cache / "loop" / "abc").mkdir(parents=True)
    (cache / "loop" / "abc" / "libcosim_loop.so").write_bytes(b"x" * 1000)
    (cache / "mine").mkdir()
    by_name = {e.name: e for e in caches.info()}
    assert by_name["fmus"].entries == 2 and by_name["fmus"].size > 10_000
    assert by_name["loop"].entries == 1 and by_name["loop"].size == 1000
    assert by_name["mine"].what.startswith("unknown")
    assert cli.main(["cache", "info"]) == 0
    out = capsys.readouterr().out
    assert str(cache) in out and "FMU store" in out and "total" in out


def test_clear_removes_what_no_running_process_uses_and_says_what_it_kept(cache, toy_dir, tmp_path, capsys):
    """A folder another process holds, a compiled loop changed just now, the job-signing key and
    a folder not ours are kept and named; everything else goes."""
    fmu_store.cached_folder(toy_dir / "Gain.fmu")
    for folder in (cache / "fmus").iterdir():     # this process lets go: only the other one holds
        fmu_store._release(folder)
    used = variant(toy_dir, tmp_path / "fmus", "used")
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(used)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, env=dict(os.environ))
    try:
        held = Path(holder.stdout.readline().strip())
        for name in ("old", "new"):
            (cache / "loop" / name).mkdir(parents=True)
            (cache / "loop" / name / "libcosim_loop.so").write_bytes(b"\0")
        hours_ago = time.time() - 7200
        os.utime(cache / "loop" / "old" / "libcosim_loop.so", (hours_ago, hours_ago))
        os.utime(cache / "loop" / "old", (hours_ago, hours_ago))
        (cache / "keys").mkdir()
        (cache / "keys" / "study-jobs.key").write_bytes(b"k" * 32)
        (cache / "model_descriptions").mkdir(exist_ok=True)
        (cache / "model_descriptions" / "x.json").write_text("[]")
        assert cli.main(["cache", "clear"]) == 0
        out = capsys.readouterr().out
        assert list((cache / "fmus").iterdir()) == [held]
        assert f"kept fmus/{held.name}: in use by a running process" in out
        assert [p.name for p in (cache / "loop").iterdir()] == ["new"] and "kept loop/new" in out
        assert (cache / "keys" / "study-jobs.key").is_file() and "kept keys" in out
        assert list((cache / "model_descriptions").iterdir()) == []
    finally:
        holder.communicate("", timeout=60)
    caches.clear()
    assert list((cache / "fmus").iterdir()) == []


def broken_library(fmu: Path) -> None:
    """Overwrite this platform's library inside the folder or FMU ``fmu`` with bytes that do not
    load, of the same size (so the size check of the store's repair does not see it)."""
    from fmpy import platform
    if fmu.is_dir():
        (lib,) = (fmu / "binaries" / platform).glob("*.so")
        lib.write_bytes(b"\0" * lib.stat().st_size)
        return
    with zipfile.ZipFile(fmu) as z:
        members = {m.filename: z.read(m) for m in z.infolist()}
    with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in members.items():
            broken = name.startswith(f"binaries/{platform}/") and name.endswith(".so")
            z.writestr(name, b"\0" * len(data) if broken else data)


def flexfusion(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", "import sys; from orchestration.cli import main; sys.exit(main())",
                           *argv], capture_output=True, text=True, env=dict(os.environ))


def test_a_cached_folder_whose_library_does_not_load_is_extracted_again_and_the_run_goes_on(cache, toy_dir, tmp_path):
    scenario = write(tmp_path, ONE_GAIN.format(fmu="Gain"))
    assert flexfusion("run", str(scenario), "--out", str(tmp_path / "a"), "-q").returncode == 0
    (entry,) = (cache / "fmus").iterdir()
    broken_library(entry)
    done = flexfusion("run", str(scenario), "--out", str(tmp_path / "b"), "-q")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "a" / "results.csv").read_bytes() == (tmp_path / "b" / "results.csv").read_bytes()
    assert len(list((cache / "fmus").glob(".bad-*"))) == 1


def test_an_entry_that_fails_after_its_repair_ends_in_one_error_line_naming_it(cache, toy_dir, tmp_path):
    """The FMU's own library does not load: extracted again, it fails again; the run ends in one
    ``error:`` line naming the cache entry and ``flexfusion cache clear``, exit 2."""
    import shutil
    fmu = tmp_path / "Broken.fmu"
    shutil.copy(toy_dir / "Gain.fmu", fmu)
    broken_library(fmu)
    scenario = write(tmp_path, ONE_GAIN.format(fmu=fmu))
    done = flexfusion("run", str(scenario), "--out", str(tmp_path / "o"), "-q")
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: component 'g' (Broken.fmu): cannot load the FMU")
    (entry,) = (p for p in (cache / "fmus").iterdir() if not p.name.startswith("."))
    assert str(entry) in lines[0] and "flexfusion cache clear" in lines[0]
    assert len(list((cache / "fmus").glob(".bad-*"))) == 1          # repaired once, not more

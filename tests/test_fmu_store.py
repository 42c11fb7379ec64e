"""The FMU store (orchestration/fmu_store.py) on toy FMUs (tests/fmus): extraction into the cache
by content, temporary folders without a cache, pruning that never removes what another process
uses, repair of a truncated library."""
from __future__ import annotations

import json
import re
import sys
import zipfile
from pathlib import Path

import pytest

from orchestration import RunError, run
from test_master import CHAIN, NOISE
from toys import FAILING, write


pytestmark = pytest.mark.usefixtures("toy_fmus")


@pytest.fixture
def no_cache(tmp_path, monkeypatch):
    """No writable cache (its root is a file), and a process that has extracted nothing yet."""
    from orchestration import fmu_store
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("")
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(blocker))
    for name, empty in (("_EXTRACTED", {}), ("_EXTRACT_ROOT", [])):
        monkeypatch.setattr(fmu_store, name, empty)
    return {"FLEXFUSION_CACHE_DIR": str(blocker)}


def test_fmu_extraction_folders_are_removed_when_a_run_ends(tmp_path, no_cache):
    """Without a cache, study workers end without Python's exit handlers: a run must not leave
    its FMU folders behind (after a failed run neither), and the next run in the process
    extracts them again to the same paths (the loaded libraries are reused)."""
    from orchestration import fmu_store
    path = write(tmp_path, NOISE)
    run(path, out_dir=tmp_path / "a")
    root = Path(fmu_store._EXTRACT_ROOT[0])
    folders = set(fmu_store._EXTRACTED.values())
    assert not root.exists()
    run(path, out_dir=tmp_path / "b")
    assert not root.exists() and set(fmu_store._EXTRACTED.values()) == folders
    with pytest.raises(RunError):
        run(write(tmp_path, FAILING.format(mode="error"), "failing.toml"), out_dir=tmp_path / "c")
    assert not root.exists()


FOLDERS_OF_A_RUN = """
import json, sys
from pathlib import Path
from orchestration import master, run
seen = {}
close = master._Instance.close
def recording_close(self):
    folder = Path(self.fmu.unzipDirectory)
    seen[self.name] = {"folder": str(folder),
                       "resources": sorted(p.name for p in (folder / "resources").iterdir()),
                       "binaries": sorted(p.name for p in (folder / "binaries").iterdir())}
    close(self)
master._Instance.close = recording_close
run(sys.argv[1], out_dir=sys.argv[2])
print(json.dumps(seen))
"""


def folders_of_a_run(scenario: Path, out: Path, env: dict[str, str]) -> dict[str, dict]:
    """Each component's FMU folder and what it holds, in a fresh process (closed last first)."""
    import os
    import subprocess
    done = subprocess.run([sys.executable, "-c", FOLDERS_OF_A_RUN, str(scenario), str(out)],
                          capture_output=True, text=True, check=True, env={**os.environ, **env})
    return json.loads(done.stdout.splitlines()[-1])


def test_only_the_first_fmu_of_a_process_gets_the_bundled_packages_extracted(tmp_path, no_cache):
    """Without a cache, in a fresh process (a run's) the first FMU loads the bundled
    ``fmus_<hash>`` and ``pythonfmu`` packages from its folder; the other FMUs' folders need
    no copy (Python never reads one) and get none, and the run works."""
    seen = folders_of_a_run(write(tmp_path, CHAIN), tmp_path / "o", no_cache)
    seen = {name: folder["resources"] for name, folder in seen.items()}
    assert list(seen) == ["g2", "g1", "src"]        # closed in reverse order: src loaded first
    first, gain = seen["src"], seen["g1"]           # Source.fmu, Gain.fmu (g1 and g2 share it)
    assert "pythonfmu" in first and any(re.fullmatch(r"fmus_[0-9a-f]{12}", n) for n in first)
    assert "pythonfmu" not in gain and not any(n.startswith("fmus_") for n in gain)
    assert "slavemodule.txt" in gain and any(n.startswith("gain_fmu_") for n in gain)


def test_fmus_are_extracted_once_into_the_cache_by_content(tmp_path, toy_dir):
    """With a cache every process uses one folder per FMU content (this platform's binaries
    only), extracted by the first and kept; a copy of an FMU shares its folder, a changed FMU
    gets its own."""
    import shutil
    env = {"FLEXFUSION_CACHE_DIR": str(tmp_path / "cache")}
    scenario = write(tmp_path, CHAIN)
    first = folders_of_a_run(scenario, tmp_path / "a", env)
    folders = {name: Path(f["folder"]) for name, f in first.items()}
    assert all(f.parent == tmp_path / "cache" / "fmus" for f in folders.values())
    assert folders["g1"] == folders["g2"] != folders["src"]
    assert all(f["binaries"] == ["linux64"] for f in first.values())
    assert all("pythonfmu" in f["resources"] for f in first.values())         # each one whole
    stamp = {f: f.stat().st_ino for f in folders.values()}

    again = folders_of_a_run(scenario, tmp_path / "b", env)                     # not extracted again
    assert {name: Path(f["folder"]) for name, f in again.items()} == folders
    assert {f: f.stat().st_ino for f in folders.values()} == stamp
    assert (tmp_path / "a" / "results.csv").read_bytes() == (tmp_path / "b" / "results.csv").read_bytes()

    copies = tmp_path / "copies"
    copies.mkdir()
    shutil.copy(toy_dir / "Source.fmu", copies / "Source.fmu")
    shutil.copy(toy_dir / "Gain.fmu", copies / "Gain.fmu")
    with zipfile.ZipFile(copies / "Gain.fmu", "a") as z:                        # one more file
        z.writestr("documentation/notes.txt", "changed")
    moved = folders_of_a_run(scenario, tmp_path / "c", {**env, "FLEXFUSION_FMU_DIR": str(copies)})
    assert Path(moved["src"]["folder"]) == folders["src"]
    assert Path(moved["g1"]["folder"]) not in folders.values()


def files_below(folder: Path) -> set[str]:
    """Every file below ``folder``, relative, without the bytecode Python wrote."""
    import os
    return {Path(d, f).relative_to(folder).as_posix() for d, _, names in os.walk(folder)
            for f in names if not f.endswith(".pyc") and f != ".complete"}


def test_a_cached_folder_holds_the_whole_fmu_and_runs_as_without_a_cache(tmp_path, toy_dir, no_cache):
    """Each cached FMU folder holds all of its FMU (this platform's binaries; no links), and the
    run's results are those of a run without a cache."""
    cache = tmp_path / "cache"
    scenario = write(tmp_path, CHAIN)
    seen = folders_of_a_run(scenario, tmp_path / "a", {"FLEXFUSION_CACHE_DIR": str(cache)})
    source = next(Path(f["folder"]) for f in seen.values() if "source_fmu" in str(f["resources"]))
    with zipfile.ZipFile(toy_dir / "Source.fmu") as z:
        whole = {m for m in z.namelist() if not m.endswith(("/", ".pyc"))
                 and (not m.startswith("binaries/") or m.startswith("binaries/linux64/"))}
    assert files_below(source) == whole
    assert not any(p.is_symlink() for p in source.rglob("*"))
    folders_of_a_run(scenario, tmp_path / "b", no_cache)
    assert (tmp_path / "a" / "results.csv").read_bytes() == (tmp_path / "b" / "results.csv").read_bytes()


def test_processes_extracting_the_same_fmus_at_once_all_succeed(tmp_path, toy_dir):
    """Three fresh processes fill one empty cache at the same time: each run works with the
    same results, and the cache ends with one folder per FMU and no temporary folder."""
    import os
    import subprocess
    env = {**os.environ, "FLEXFUSION_CACHE_DIR": str(tmp_path / "cache")}
    scenario = write(tmp_path, CHAIN)
    runs = [subprocess.Popen([sys.executable, "-c", FOLDERS_OF_A_RUN, str(scenario), str(tmp_path / str(i))],
                             env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE) for i in range(3)]
    for process in runs:
        out, err = process.communicate(timeout=120)
        assert process.returncode == 0, err.decode()
    results = {(tmp_path / str(i) / "results.csv").read_bytes() for i in range(3)}
    assert len(results) == 1
    assert len(os.listdir(tmp_path / "cache" / "fmus")) == 2


def variant(toy_dir: Path, folder: Path, tag: str) -> Path:
    """A copy of the toy Gain FMU with one more file: another FMU content (as another
    checkout's build of it)."""
    import shutil
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"Gain-{tag}.fmu"
    shutil.copy(toy_dir / "Gain.fmu", path)
    with zipfile.ZipFile(path, "a") as z:
        z.writestr("documentation/tag.txt", tag)
    return path


HOLD = """
import sys, time
from pathlib import Path
from orchestration import fmu_store
print(fmu_store.cached_folder(Path(sys.argv[1])), flush=True)
sys.stdin.read()                      # holds the folder until the test closes stdin
"""


def test_pruning_never_removes_a_folder_another_process_uses(tmp_path, toy_dir, monkeypatch):
    """A folder another process uses (holds), and one this process holds, survive pruning down
    to nothing; the others go; once they are let go (the other process ended), they go too."""
    import os
    import subprocess
    from orchestration import fmu_store
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    root = tmp_path / "cache" / "fmus"
    used = variant(toy_dir, tmp_path / "fmus", "used")
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(used)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, env=dict(os.environ))
    try:
        held = Path(holder.stdout.readline().strip())
        assert held.parent == root
        for i in range(3):
            fmu_store.cached_folder(variant(toy_dir, tmp_path / "fmus", str(i)))
        kept, *mine = sorted(p for p in root.iterdir() if p != held)
        assert len(mine) == 2
        for folder in mine:                        # this process lets go of two it holds
            fmu_store._release(folder)
        fmu_store.prune(root, 0)
        assert sorted(root.iterdir()) == sorted([held, kept]) and (held / "modelDescription.xml").is_file()
    finally:
        holder.communicate("", timeout=60)
    fmu_store._release(kept)
    fmu_store.prune(root, 0)
    assert list(root.iterdir()) == []


PRUNING_USER = """
import sys, warnings, zipfile, shutil
from pathlib import Path
from orchestration import fmu_store, run
fmu_store.KEEP = 1                   # every new folder prunes all it can
scenario, out, toys, tag = sys.argv[1:]
for i in range(6):
    fmu = Path(out) / f"Gain-{tag}-{i}.fmu"
    Path(out).mkdir(parents=True, exist_ok=True)
    shutil.copy(Path(toys) / "Gain.fmu", fmu)
    with zipfile.ZipFile(fmu, "a") as z:
        z.writestr("documentation/tag.txt", f"{tag}-{i}")
    fmu_store.cached_folder(fmu)      # a new content: extracted, pruning the other's unused folders
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run(scenario, out_dir=f"{out}/run{i}")
print("ok")
"""


def test_two_checkouts_using_and_pruning_one_store_at_once_both_succeed(tmp_path, toy_dir):
    """Two processes (as two checkouts: each with FMU files of its own) share one store and
    run at once, each extracting new FMU contents that prune all but one folder while the other
    runs from its own: both succeed with the same results, and the store ends within its
    bound once both have ended."""
    import os
    import subprocess
    from orchestration import fmu_store
    env = {**os.environ, "FLEXFUSION_CACHE_DIR": str(tmp_path / "cache")}
    scenario = write(tmp_path, CHAIN)
    users = [subprocess.Popen([sys.executable, "-c", PRUNING_USER, str(scenario), str(tmp_path / tag), str(toy_dir), tag],
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for tag in "ab"]
    for user in users:
        out, err = user.communicate(timeout=300)
        assert user.returncode == 0 and out.strip().endswith("ok"), err
    results = {(tmp_path / tag / f"run{i}" / "results.csv").read_bytes() for tag in "ab" for i in range(6)}
    assert len(results) == 1
    root = tmp_path / "cache" / "fmus"
    assert len([p for p in root.iterdir() if not p.name.startswith(".")]) >= 2      # both ended holding some
    fmu_store.prune(root, 1)
    assert len(list(root.iterdir())) == 1


def test_a_cached_folder_pruned_under_a_process_comes_back_at_its_path(tmp_path, monkeypatch):
    """A folder this process used was removed (by hand: pruning leaves it): its next run
    extracts it again, at the same path (its imported packages keep their paths), whole."""
    import shutil
    from orchestration import fmu_store
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(fmu_store, "_EXTRACTED", {})
    scenario = write(tmp_path, CHAIN)
    run(scenario, out_dir=tmp_path / "a")
    folders = sorted(fmu_store._EXTRACTED.values())
    shutil.rmtree(tmp_path / "cache" / "fmus")
    run(scenario, out_dir=tmp_path / "b")
    assert sorted(fmu_store._EXTRACTED.values()) == folders
    assert all(Path(f, ".complete").is_file() and (Path(f) / "resources" / "pythonfmu").is_dir() for f in folders)
    assert (tmp_path / "a" / "results.csv").read_bytes() == (tmp_path / "b" / "results.csv").read_bytes()


def test_a_resources_folder_is_extracted_unless_an_fmu_provided_that_package():
    from orchestration import fmu_store
    assert fmu_store._still_read("resources/xml/config.xml") is True       # xml: the stdlib's
    assert fmu_store._still_read("resources/no_such_package_here/x.py") is True
    assert fmu_store._still_read("resources/slavemodule.txt") is True
    assert fmu_store._still_read("binaries/linux64/Gain.so") is True


def test_a_cache_folder_others_can_write_is_not_used_for_fmus(tmp_path, toy_dir, monkeypatch):
    """Extracted FMUs are loaded code: a cache whose fmus/ folder is writable by
    others (or another user's) is not used; the FMU is extracted to a private temporary folder."""
    from orchestration import fmu_store
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    (tmp_path / "cache" / "fmus").mkdir(parents=True, exist_ok=True)
    (tmp_path / "cache" / "fmus").chmod(0o777)
    assert fmu_store.cached_folder(toy_dir / "Gain.fmu") is None
    assert list((tmp_path / "cache" / "fmus").iterdir()) == []
    (tmp_path / "cache" / "fmus").chmod(0o700)
    assert Path(fmu_store.cached_folder(toy_dir / "Gain.fmu")).is_relative_to(tmp_path / "cache" / "fmus")


def test_a_truncated_library_in_a_cached_fmu_folder_is_set_aside_and_extracted_again(tmp_path, toy_dir, monkeypatch):
    """A library left truncated in the cache (a full disk, a killed copy) made every later run
    die with a bus error: the folder is set aside and extracted again, and a run goes on."""
    import zipfile

    from fmpy import platform

    from orchestration import fmu_store
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    fmu = toy_dir / "Gain.fmu"
    folder = Path(fmu_store.cached_folder(fmu))
    with zipfile.ZipFile(fmu) as z:
        sizes = {m.filename: m.file_size for m in z.infolist() if m.filename.endswith(".so")
                 and (not m.filename.startswith("binaries/") or m.filename.startswith(f"binaries/{platform}/"))}
    assert any(n.startswith("binaries/") for n in sizes)
    for name in sizes:
        with open(folder / name, "r+b") as f:
            f.truncate(100)
    with pytest.warns(UserWarning, match="not whole .*: set aside, the FMU is extracted again"):
        assert fmu_store.cached_folder(fmu) == str(folder)
    assert {n: (folder / n).stat().st_size for n in sizes} == sizes
    assert len(list((tmp_path / "cache" / "fmus").glob(".bad-*"))) == 1
    assert fmu_store.cached_folder(fmu) == str(folder)        # whole now: no warning, the same folder
    scenario = write(tmp_path, CHAIN)
    monkeypatch.setattr(fmu_store, "_EXTRACTED", {})
    run(scenario, out_dir=tmp_path / "run")


def test_an_fmu_beyond_the_archive_limits_is_refused_before_anything_is_extracted(tmp_path, toy_dir, monkeypatch, capsys):
    """The limits of orchestration/archive.py hold for FMUs too: checked on the zip's central
    directory when the FMU is first read (its content key), so nothing of it is extracted or
    parsed; the run ends in one error line naming the FMU and the variable to set."""
    import shutil

    from orchestration.cli import main
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    fmu = tmp_path / "Many.fmu"
    shutil.copy(toy_dir / "Gain.fmu", fmu)
    with zipfile.ZipFile(fmu) as z:
        entries = len(z.infolist())
    monkeypatch.setenv("FLEXFUSION_ARCHIVE_MAX_ENTRIES", str(entries - 1))
    scenario = write(tmp_path, f'[scenario]\nstop_time = 0.01\nbase_step = 0.001\n[components.g]\nfmu = "{fmu}"\n')
    assert main(["run", str(scenario), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{fmu}: {entries} entries, more than the limit of {entries - 1}" in err[0]
    assert "FLEXFUSION_ARCHIVE_MAX_ENTRIES" in err[0], err
    assert not (tmp_path / "cache" / "fmus").exists() and not (tmp_path / "o").exists()

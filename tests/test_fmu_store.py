"""The FMU store (orchestration/fmu_store.py) on toy FMUs (tests/fmus): extraction into the cache
by content, shared packages, temporary folders without a cache, pruning that never removes what
another process uses, repair of a truncated library."""
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


def bundled(folder: Path) -> dict[str, Path]:
    """The Python packages in an FMU folder's ``resources/`` (``pythonfmu``, ``fmus_<hash>``),
    each with the folder it really is."""
    return {p.name: p.resolve() for p in (folder / "resources").iterdir() if (p / "__init__.py").is_file()}


def files_below(folder: Path) -> set[str]:
    """Every file below ``folder`` (through links), relative, without the bytecode Python wrote."""
    import os
    return {Path(d, f).relative_to(folder).as_posix() for d, _, names in os.walk(folder, followlinks=True)
            for f in names if not f.endswith(".pyc") and f != ".complete"}


def test_a_cold_cache_extracts_each_bundled_package_once(tmp_path, toy_dir, no_cache):
    """Every FMU bundles the same packages: a cold run extracts each once into ``packages/``
    and links it from each FMU folder (relative links); each folder still holds all of its
    FMU (this platform's binaries), and the run's results are those of a run without a cache."""
    import os
    cache = tmp_path / "cache"
    scenario = write(tmp_path, CHAIN)
    seen = folders_of_a_run(scenario, tmp_path / "a", {"FLEXFUSION_CACHE_DIR": str(cache)})
    folders = {Path(f["folder"]) for f in seen.values()}
    packages = [bundled(f) for f in folders]
    assert len(folders) == 2 and packages[0] == packages[1]
    assert {"pythonfmu"} < set(packages[0]) and any(n.startswith("fmus_") for n in packages[0])
    assert {p.parent.parent for p in packages[0].values()} == set((cache / "packages").iterdir())
    for folder in folders:
        for name in packages[0]:
            link = folder / "resources" / name
            assert link.is_symlink() and not Path(os.readlink(link)).is_absolute()
    copies = sum(names.count("fmi2slave.py") for _, _, names in os.walk(cache))     # links not followed
    assert copies == 1
    source = next(Path(f["folder"]) for f in seen.values() if "source_fmu" in str(f["resources"]))
    with zipfile.ZipFile(toy_dir / "Source.fmu") as z:
        whole = {m for m in z.namelist() if not m.endswith(("/", ".pyc"))
                 and (not m.startswith("binaries/") or m.startswith("binaries/linux64/"))}
    assert files_below(source) == whole
    folders_of_a_run(scenario, tmp_path / "b", no_cache)
    assert (tmp_path / "a" / "results.csv").read_bytes() == (tmp_path / "b" / "results.csv").read_bytes()


def test_fmus_share_a_bundled_package_only_when_it_is_the_same(tmp_path, toy_dir, monkeypatch):
    """A second FMU with the same bundle reuses the extracted packages; one whose bundle
    differs (a file more in ``pythonfmu``) gets its own copy of that package only."""
    import shutil
    from orchestration import fmu_store
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    fmus = {name: tmp_path / f"{name}.fmu" for name in ("gain", "documented", "changed")}
    for path in fmus.values():
        shutil.copy(toy_dir / "Gain.fmu", path)
    with zipfile.ZipFile(fmus["documented"], "a") as z:
        z.writestr("documentation/notes.txt", "changed")
    with zipfile.ZipFile(fmus["changed"], "a") as z:
        z.writestr("resources/pythonfmu/extra.py", "x = 1\n")
    gain, documented, changed = (Path(fmu_store.cached_folder(p)) for p in fmus.values())
    assert len({gain, documented, changed}) == 3
    assert bundled(documented) == bundled(gain)
    (fmus_hash,) = (n for n in bundled(gain) if n.startswith("fmus_"))
    assert bundled(changed)[fmus_hash] == bundled(gain)[fmus_hash]
    assert bundled(changed)["pythonfmu"] != bundled(gain)["pythonfmu"]
    assert (changed / "resources" / "pythonfmu" / "extra.py").is_file()
    assert not (gain / "resources" / "pythonfmu" / "extra.py").exists()
    assert len(list((tmp_path / "cache" / "packages").iterdir())) == 3


def test_processes_extracting_the_same_fmus_at_once_all_succeed(tmp_path, toy_dir):
    """Three fresh processes fill one empty cache at the same time: each run works with the
    same results, and the cache ends with one folder per FMU, one copy per package and no
    temporary folder."""
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
    assert len(os.listdir(tmp_path / "cache" / "packages")) == 2


def test_a_package_another_process_extracted_first_is_used(tmp_path, toy_dir, monkeypatch):
    """The loser of a race: its package was not there when it looked, and another process
    published it before this one's rename; this one links to that copy and leaves no
    temporary folder."""
    import os
    import shutil
    from orchestration import fmu_store
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    first = bundled(Path(fmu_store.cached_folder(toy_dir / "Gain.fmu")))
    stamps = {p: p.stat().st_ino for p in first.values()}
    shutil.rmtree(tmp_path / "cache" / "fmus")
    utime = os.utime

    def not_there_yet(path, *args, **kwargs):
        if Path(path).parent.name == "packages":
            raise FileNotFoundError(path)
        return utime(path, *args, **kwargs)

    monkeypatch.setattr(os, "utime", not_there_yet)
    again = bundled(Path(fmu_store.cached_folder(toy_dir / "Gain.fmu")))
    assert again == first and {p: p.stat().st_ino for p in again.values()} == stamps
    assert all(not p.name.startswith(".") for p in (tmp_path / "cache" / "packages").iterdir())


def test_pruning_keeps_the_packages_a_kept_folder_links_to(tmp_path, toy_dir, monkeypatch):
    """Packages go when no FMU folder links to them and they were not used for an hour (so a
    process that just took one up keeps it); temporary folders a dead process left go too."""
    import os
    import shutil
    import time
    from orchestration import fmu_store
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    packages = tmp_path / "cache" / "packages"
    linked = {p.parent.parent.name for p in bundled(Path(fmu_store.cached_folder(toy_dir / "Gain.fmu"))).values()}
    hours_ago = time.time() - 7200
    for name in ("old-1", "recent-2", ".extracting-3", "taken-up-again-4"):
        (packages / name / "resources").mkdir(parents=True)
    for entry in packages.iterdir():
        if entry.name != "recent-2":
            os.utime(entry, (hours_ago, hours_ago))
    rename = Path.rename

    def used_meanwhile(self, target):      # another process marks it between the look and the rename
        moved = rename(self, target)
        if self.name == "taken-up-again-4":
            os.utime(target)
        return moved

    monkeypatch.setattr(Path, "rename", used_meanwhile)
    fmu_store._prune_packages(tmp_path / "cache" / "fmus")
    assert {p.name for p in packages.iterdir()} == linked | {"recent-2", "taken-up-again-4"}
    monkeypatch.setattr(Path, "rename", rename)
    for entry in packages.iterdir():
        os.utime(entry, (hours_ago, hours_ago))
    fmu_store._prune_packages(tmp_path / "cache" / "fmus")
    assert {p.name for p in packages.iterdir()} == linked               # still linked: kept
    shutil.rmtree(tmp_path / "cache" / "fmus")
    (tmp_path / "cache" / "fmus").mkdir()
    fmu_store._prune_packages(tmp_path / "cache" / "fmus")
    assert list(packages.iterdir()) == []


def test_a_cached_folder_whose_packages_were_removed_gets_them_again(tmp_path, toy_dir, monkeypatch):
    import shutil
    from orchestration import fmu_store
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    folder = Path(fmu_store.cached_folder(toy_dir / "Gain.fmu"))
    files = files_below(folder)
    shutil.rmtree(tmp_path / "cache" / "packages")
    assert fmu_store.cached_folder(toy_dir / "Gain.fmu") == str(folder)
    assert files_below(folder) == files


def test_a_cached_folder_pruned_under_a_process_comes_back_at_its_path(tmp_path, monkeypatch):
    """Another process pruned the folders this one used: its next run extracts them again,
    at the same paths (its imported packages keep their paths), whole and with links."""
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
    assert all(Path(f, ".complete").is_file() and (Path(f) / "resources" / "pythonfmu").is_symlink() for f in folders)
    assert (tmp_path / "a" / "results.csv").read_bytes() == (tmp_path / "b" / "results.csv").read_bytes()


def test_without_symbolic_links_each_fmu_folder_gets_its_own_packages(tmp_path, toy_dir, monkeypatch):
    import os
    from orchestration import fmu_store
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    linked = Path(fmu_store.cached_folder(toy_dir / "Gain.fmu"))

    def no_links(*args, **kwargs):
        raise OSError("symbolic links are not supported here")

    monkeypatch.setattr(os, "symlink", no_links)
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "other"))
    own = Path(fmu_store.cached_folder(toy_dir / "Gain.fmu"))
    assert not any(p.is_symlink() for p in (own / "resources").iterdir())
    assert files_below(own) == files_below(linked)


def test_a_resources_folder_is_extracted_unless_an_fmu_provided_that_package():
    from orchestration import fmu_store
    assert fmu_store._still_read("resources/xml/config.xml") is True       # xml: the stdlib's
    assert fmu_store._still_read("resources/no_such_package_here/x.py") is True
    assert fmu_store._still_read("resources/slavemodule.txt") is True
    assert fmu_store._still_read("binaries/linux64/Gain.so") is True


def test_a_cache_folder_others_can_write_is_not_used_for_fmus(tmp_path, toy_dir, monkeypatch):
    """Extracted FMUs are loaded code: a cache whose fmus/ (or packages/) folder is writable by
    others (or another user's) is not used; the FMU is extracted to a private temporary folder."""
    from orchestration import fmu_store
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    for name in ("fmus", "packages"):
        (tmp_path / "cache" / name).mkdir(parents=True, exist_ok=True)
        (tmp_path / "cache" / name).chmod(0o777)
        assert fmu_store.cached_folder(toy_dir / "Gain.fmu") is None
        assert list((tmp_path / "cache" / name).iterdir()) == []
        (tmp_path / "cache" / name).chmod(0o700)
    assert Path(fmu_store.cached_folder(toy_dir / "Gain.fmu")).is_relative_to(tmp_path / "cache" / "fmus")


def test_a_truncated_library_in_a_cached_fmu_folder_is_set_aside_and_extracted_again(tmp_path, toy_dir, monkeypatch):
    """A library left truncated in the cache (a full disk, a killed copy) made every later run
    die with a bus error: the folder (and the shared package holding a truncated library) is
    set aside and extracted again, and a run goes on."""
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
        with open(folder / name, "r+b") as f:            # through the link for a package's library
            f.truncate(100)
    with pytest.warns(UserWarning, match="not whole .*: set aside, the FMU is extracted again"):
        assert fmu_store.cached_folder(fmu) == str(folder)
    assert {n: (folder / n).stat().st_size for n in sizes} == sizes
    assert len(list((tmp_path / "cache" / "fmus").glob(".bad-*"))) == 1
    assert fmu_store.cached_folder(fmu) == str(folder)        # whole now: no warning, the same folder
    scenario = write(tmp_path, CHAIN)
    monkeypatch.setattr(fmu_store, "_EXTRACTED", {})
    run(scenario, out_dir=tmp_path / "run")

"""The co-simulation master on toy FMUs (tests/fmus): accuracy against an analytic solution,
Gauss–Seidel order, multi-rate, cycles, reproducibility, failures."""
from __future__ import annotations

import json
import re
import sys
import warnings
import zipfile
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


@pytest.fixture
def no_cache(tmp_path, monkeypatch):
    """No writable cache (its root is a file), and a process that has extracted nothing yet."""
    from orchestration import master
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("")
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(blocker))
    for name, empty in (("_EXTRACTED", {}), ("_EXTRACT_ROOT", [])):
        monkeypatch.setattr(master, name, empty)
    return {"FLEXFUSION_CACHE_DIR": str(blocker)}


def test_fmu_extraction_folders_are_removed_when_a_run_ends(tmp_path, no_cache):
    """Without a cache, study workers end without Python's exit handlers: a run must not leave
    its FMU folders behind (after a failed run neither), and the next run in the process
    extracts them again to the same paths (the loaded libraries are reused)."""
    from orchestration import master
    path = write(tmp_path, NOISE)
    run(path, out_dir=tmp_path / "a")
    root = Path(master._EXTRACT_ROOT[0])
    folders = set(master._EXTRACTED.values())
    assert not root.exists()
    run(path, out_dir=tmp_path / "b")
    assert not root.exists() and set(master._EXTRACTED.values()) == folders
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
    from orchestration import master
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    fmus = {name: tmp_path / f"{name}.fmu" for name in ("gain", "documented", "changed")}
    for path in fmus.values():
        shutil.copy(toy_dir / "Gain.fmu", path)
    with zipfile.ZipFile(fmus["documented"], "a") as z:
        z.writestr("documentation/notes.txt", "changed")
    with zipfile.ZipFile(fmus["changed"], "a") as z:
        z.writestr("resources/pythonfmu/extra.py", "x = 1\n")
    gain, documented, changed = (Path(master._cached_folder(p)) for p in fmus.values())
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
    from orchestration import master
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    first = bundled(Path(master._cached_folder(toy_dir / "Gain.fmu")))
    stamps = {p: p.stat().st_ino for p in first.values()}
    shutil.rmtree(tmp_path / "cache" / "fmus")
    utime = os.utime

    def not_there_yet(path, *args, **kwargs):
        if Path(path).parent.name == "packages":
            raise FileNotFoundError(path)
        return utime(path, *args, **kwargs)

    monkeypatch.setattr(os, "utime", not_there_yet)
    again = bundled(Path(master._cached_folder(toy_dir / "Gain.fmu")))
    assert again == first and {p: p.stat().st_ino for p in again.values()} == stamps
    assert all(not p.name.startswith(".") for p in (tmp_path / "cache" / "packages").iterdir())


def test_pruning_keeps_the_packages_a_kept_folder_links_to(tmp_path, toy_dir, monkeypatch):
    """Packages go when no FMU folder links to them and they were not used for an hour (so a
    process that just took one up keeps it); temporary folders a dead process left go too."""
    import os
    import shutil
    import time
    from orchestration import master
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    packages = tmp_path / "cache" / "packages"
    linked = {p.parent.parent.name for p in bundled(Path(master._cached_folder(toy_dir / "Gain.fmu"))).values()}
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
    master._prune_packages(tmp_path / "cache" / "fmus")
    assert {p.name for p in packages.iterdir()} == linked | {"recent-2", "taken-up-again-4"}
    monkeypatch.setattr(Path, "rename", rename)
    for entry in packages.iterdir():
        os.utime(entry, (hours_ago, hours_ago))
    master._prune_packages(tmp_path / "cache" / "fmus")
    assert {p.name for p in packages.iterdir()} == linked               # still linked: kept
    shutil.rmtree(tmp_path / "cache" / "fmus")
    (tmp_path / "cache" / "fmus").mkdir()
    master._prune_packages(tmp_path / "cache" / "fmus")
    assert list(packages.iterdir()) == []


def test_a_cached_folder_whose_packages_were_removed_gets_them_again(tmp_path, toy_dir, monkeypatch):
    import shutil
    from orchestration import master
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    folder = Path(master._cached_folder(toy_dir / "Gain.fmu"))
    files = files_below(folder)
    shutil.rmtree(tmp_path / "cache" / "packages")
    assert master._cached_folder(toy_dir / "Gain.fmu") == str(folder)
    assert files_below(folder) == files


def test_a_cached_folder_pruned_under_a_process_comes_back_at_its_path(tmp_path, monkeypatch):
    """Another process pruned the folders this one used: its next run extracts them again,
    at the same paths (its imported packages keep their paths), whole and with links."""
    import shutil
    from orchestration import master
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(master, "_EXTRACTED", {})
    scenario = write(tmp_path, CHAIN)
    run(scenario, out_dir=tmp_path / "a")
    folders = sorted(master._EXTRACTED.values())
    shutil.rmtree(tmp_path / "cache" / "fmus")
    run(scenario, out_dir=tmp_path / "b")
    assert sorted(master._EXTRACTED.values()) == folders
    assert all(Path(f, ".complete").is_file() and (Path(f) / "resources" / "pythonfmu").is_symlink() for f in folders)
    assert (tmp_path / "a" / "results.csv").read_bytes() == (tmp_path / "b" / "results.csv").read_bytes()


def test_without_symbolic_links_each_fmu_folder_gets_its_own_packages(tmp_path, toy_dir, monkeypatch):
    import os
    from orchestration import master
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    linked = Path(master._cached_folder(toy_dir / "Gain.fmu"))

    def no_links(*args, **kwargs):
        raise OSError("symbolic links are not supported here")

    monkeypatch.setattr(os, "symlink", no_links)
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "other"))
    own = Path(master._cached_folder(toy_dir / "Gain.fmu"))
    assert not any(p.is_symlink() for p in (own / "resources").iterdir())
    assert files_below(own) == files_below(linked)


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
    print(json.dumps({"status": status, "at_first_step": first[0], "at_end": "scipy.signal" in sys.modules}))
"""


def test_a_run_imports_what_its_metrics_need_after_the_run(tmp_path):
    """``flexfusion run`` steps without scipy.signal, scipy.stats or matplotlib loaded (the
    band-pass metric imports scipy.signal after the run); ``flexfusion --help`` loads none."""
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
    assert json.loads(done.stdout.splitlines()[-1]) == {"status": 0, "at_first_step": [], "at_end": True}
    done = subprocess.run([sys.executable, "-c", LAZY_RUN, "--help"], capture_output=True, text=True, check=True)
    assert json.loads(done.stdout.splitlines()[-1]) == []


def test_a_resources_folder_is_extracted_unless_an_fmu_provided_that_package():
    from orchestration import master
    assert master._still_read("resources/xml/config.xml") is True       # xml: the stdlib's
    assert master._still_read("resources/no_such_package_here/x.py") is True
    assert master._still_read("resources/slavemodule.txt") is True
    assert master._still_read("binaries/linux64/Gain.so") is True


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
    from orchestration import master
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
    assert set().union(*map(loaded_from, master._EXTRACTED.values())) == set()


def test_a_cache_folder_others_can_write_is_not_used_for_fmus(tmp_path, toy_dir, monkeypatch):
    """Extracted FMUs are loaded code: a cache whose fmus/ (or packages/) folder is writable by
    others (or another user's) is not used; the FMU is extracted to a private temporary folder."""
    from orchestration import master
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    for name in ("fmus", "packages"):
        (tmp_path / "cache" / name).mkdir(parents=True, exist_ok=True)
        (tmp_path / "cache" / name).chmod(0o777)
        assert master._cached_folder(toy_dir / "Gain.fmu") is None
        assert list((tmp_path / "cache" / name).iterdir()) == []
        (tmp_path / "cache" / name).chmod(0o700)
    assert Path(master._cached_folder(toy_dir / "Gain.fmu")).is_relative_to(tmp_path / "cache" / "fmus")


def test_a_truncated_library_in_a_cached_fmu_folder_is_set_aside_and_extracted_again(tmp_path, toy_dir, monkeypatch):
    """A library left truncated in the cache (a full disk, a killed copy) made every later run
    die with a bus error: the folder (and the shared package holding a truncated library) is
    set aside and extracted again, and a run goes on."""
    import zipfile

    from fmpy import platform

    from orchestration import master
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    fmu = toy_dir / "Gain.fmu"
    folder = Path(master._cached_folder(fmu))
    with zipfile.ZipFile(fmu) as z:
        sizes = {m.filename: m.file_size for m in z.infolist() if m.filename.endswith(".so")
                 and (not m.filename.startswith("binaries/") or m.filename.startswith(f"binaries/{platform}/"))}
    assert any(n.startswith("binaries/") for n in sizes)
    for name in sizes:
        with open(folder / name, "r+b") as f:            # through the link for a package's library
            f.truncate(100)
    with pytest.warns(UserWarning, match="not whole .*: set aside, the FMU is extracted again"):
        assert master._cached_folder(fmu) == str(folder)
    assert {n: (folder / n).stat().st_size for n in sizes} == sizes
    assert len(list((tmp_path / "cache" / "fmus").glob(".bad-*"))) == 1
    assert master._cached_folder(fmu) == str(folder)        # whole now: no warning, the same folder
    scenario = write(tmp_path, CHAIN)
    monkeypatch.setattr(master, "_EXTRACTED", {})
    run(scenario, out_dir=tmp_path / "run")


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

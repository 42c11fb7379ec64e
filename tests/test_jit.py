"""fmus/common/jit.py: numba's own on-disk cache for the kernels, never stale: in an FMU's
content-named folder, and in the working tree under a folder named by the package's content."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fmus.common import jit

REPO = Path(__file__).resolve().parent.parent

pytest.importorskip("numba")

KERNEL = '''
import math
from {pkg}.common.jit import kernel

@kernel
def damped(x, n):
    s = 0.0
    for i in range(n):
        s = s * 0.5 + math.tanh(x * i)
    return s
'''

PROBE = '''
import json, sys
sys.path.insert(0, sys.argv[1])
from {pkg}.common import kern
value = kern.damped(0.3, 50)
print(json.dumps({{"value": value.hex(), "hits": sum(kern.damped.stats.cache_hits.values()),
                  "misses": sum(kern.damped.stats.cache_misses.values()),
                  "cache": kern.damped.stats.cache_path}}))
'''


def _bundle(where: Path, pkg: str, bundle_id: str | None, kernel_src: str = KERNEL) -> Path:
    """A package laid out as in an FMU's resources/: ``<pkg>/common/{jit,kern}.py`` (+ BUNDLE_ID)."""
    common = where / pkg / "common"
    common.mkdir(parents=True)
    (where / pkg / "__init__.py").write_text("")
    (common / "__init__.py").write_text("")
    shutil.copy(REPO / "fmus" / "common" / "jit.py", common / "jit.py")
    if pkg == "fmus":           # a working tree: its own fmus.common (an FMU's jit imports ours)
        shutil.copy(REPO / "fmus" / "common" / "disk_cache.py", common / "disk_cache.py")
    (common / "kern.py").write_text(kernel_src.format(pkg=pkg))
    if bundle_id:
        (where / pkg / jit.BUNDLE_ID_FILE).write_text(bundle_id + "\n")
    return where


def _probe(folder: Path, pkg: str, cache: Path, numba_cache_dir: str | None = None,
           numba_first: bool = False) -> dict:
    env = {**os.environ, "FLEXFUSION_CACHE_DIR": str(cache)}
    env.pop("NUMBA_DISABLE_JIT", None)
    env.pop("NUMBA_CACHE_DIR", None)              # the test runner's own (fmus.common.jit set it)
    if numba_cache_dir:
        env["NUMBA_CACHE_DIR"] = numba_cache_dir
    code = ("import numba\n" if numba_first else "") + PROBE.format(pkg=pkg)
    out = subprocess.run([sys.executable, "-c", code, str(folder)], env=env,
                         capture_output=True, text=True, check=True)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    result["stderr"] = out.stderr
    return result


def test_an_fmu_package_hits_numbas_own_cache_in_its_folder_across_processes(tmp_path):
    """An FMU's package (BUNDLE_ID) with numba's own cache (``__pycache__`` beside it): compiled
    in the first process, loaded from disk in the next; through a symbolic link (the FMU
    store's folders link to one shared package) too. Another extraction folder of the same
    package compiles again (numba's cache follows the folder: a host extracting afresh in
    each process compiles in each)."""
    folder = _bundle(tmp_path / "x1", "fmus_abc", "ab" * 32)
    first = _probe(folder, "fmus_abc", tmp_path / "cache")
    second = _probe(folder, "fmus_abc", tmp_path / "cache")
    (tmp_path / "fmu2").mkdir()
    os.symlink(folder / "fmus_abc", tmp_path / "fmu2" / "fmus_abc", target_is_directory=True)
    linked = _probe(tmp_path / "fmu2", "fmus_abc", tmp_path / "cache")
    elsewhere = _probe(_bundle(tmp_path / "x2", "fmus_abc", "ab" * 32), "fmus_abc", tmp_path / "cache")
    assert (first["misses"], first["hits"]) == (1, 0)
    assert (second["misses"], second["hits"]) == (0, 1)
    assert (linked["misses"], linked["hits"]) == (0, 1)
    assert (elsewhere["misses"], elsewhere["hits"]) == (1, 0)
    assert first["value"] == second["value"] == linked["value"] == elsewhere["value"]
    assert any((folder / "fmus_abc" / "common" / "__pycache__").glob("kern.damped-*.nbi"))
    assert not (tmp_path / "cache").exists()          # nothing under the working tree's folders


CALLER = '''
from {pkg}.common.jit import kernel
from {pkg}.common.callee import inner

@kernel
def damped(x, n):
    s = 0.0
    for i in range(n):
        s = s * 0.5 + inner(x, i)
    return s
'''

CALLEE = '''
import math
from {pkg}.common.jit import kernel

@kernel
def inner(x, i):
    return math.tanh(x * i)
'''


def test_the_working_tree_never_loads_a_kernel_whose_callee_changed(tmp_path):
    """numba's own check covers only the kernel's file: with a callee in another module
    changed, it would load the old machine code. The working tree's cache folder is named by
    the whole package (NUMBA_CACHE_DIR): the changed callee compiles anew, and the old
    package's kernels are found again when it comes back."""
    tree = _bundle(tmp_path / "tree", "fmus", None, CALLER)
    callee = tree / "fmus" / "common" / "callee.py"
    callee.write_text(CALLEE.format(pkg="fmus"))
    cache = tmp_path / "cache"
    before = _probe(tree, "fmus", cache)
    callee.write_text(CALLEE.format(pkg="fmus").replace("x * i", "x * i * 0.5"))
    after = _probe(tree, "fmus", cache)
    s = 0.0
    import math
    for i in range(50):
        s = s * 0.5 + math.tanh(0.3 * i * 0.5)
    assert (before["misses"], after["misses"], after["hits"]) == (1, 1, 0)
    assert after["value"] == s.hex() != before["value"]
    callee.write_text(CALLEE.format(pkg="fmus"))
    back = _probe(tree, "fmus", cache)
    assert (back["hits"], back["value"]) == (1, before["value"])
    assert len(list((cache / "numba").iterdir())) == 2


def test_the_working_tree_compiles_uncached_where_numba_is_configured_elsewhere(tmp_path):
    """numba imported before the kernels, or the user's own NUMBA_CACHE_DIR: no folder named by
    the package's content can be given to numba, so the kernels compile without a cache (right,
    slower), and one warning says why."""
    tree = _bundle(tmp_path / "tree", "fmus", None)
    imported = _probe(tree, "fmus", tmp_path / "cache", numba_first=True)
    users = _probe(tree, "fmus", tmp_path / "cache", numba_cache_dir=str(tmp_path / "mine"))
    for got, cause in ((imported, "numba was imported before"), (users, "NUMBA_CACHE_DIR is set")):
        assert got["cache"] is None and got["hits"] == 0
        assert cause in got["stderr"] and "compiled without numba's cache" in got["stderr"]
    assert imported["value"] == users["value"]
    assert not (tmp_path / "mine").exists()
    other_tree = _probe(tree, "fmus", tmp_path / "cache", numba_cache_dir=str(tmp_path / "x" / ("ab" * 8 + "-fmus")))
    assert other_tree["cache"].startswith(str(tmp_path / "cache" / "numba"))
    assert "without numba's cache" not in other_tree["stderr"]


def test_kernel_rounds_as_plain_python(tmp_path):
    """No fastmath, no contraction: the compiled loop equals the same code run by Python."""
    got = _probe(_bundle(tmp_path / "x", "fmus_abc", "ef" * 32), "fmus_abc", tmp_path / "cache")
    s = 0.0
    import math
    for i in range(50):
        s = s * 0.5 + math.tanh(0.3 * i)
    assert got["value"] == s.hex()


def test_bundle_id_of_the_working_tree_is_the_build_digest():
    """Without a BUNDLE_ID file the tree is hashed as the build hashes it."""
    assert jit.bundle_id() == jit.package_digest(REPO / "fmus")
    assert len(jit.bundle_id()) == 64


def test_unwritable_cache_falls_back_to_the_temporary_folder(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")          # a file where the cache folder should be: not writable
    env = {**os.environ, "FLEXFUSION_CACHE_DIR": str(blocker), "PYTHONPATH": str(REPO)}
    env.pop("NUMBA_CACHE_DIR", None)
    code = "import os; from fmus.common import jit; jit._cached(); print(os.environ['NUMBA_CACHE_DIR'])"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert "flexfusion-numba-" in out.stdout and str(blocker) not in out.stdout


def test_a_kernel_without_a_source_file_compiles_uncached():
    """Code run from a string (a benchmark's baseline module taken from git) has no file for the
    cache to key on: it still compiles, without the cache."""
    namespace: dict = {}
    exec(compile("from fmus.common.jit import kernel\n@kernel\ndef twice(x):\n    return 2.0 * x\n",
                 "6324638:fmus/common/kern.py", "exec"), namespace)
    assert namespace["twice"](1.5) == 3.0


def test_a_kernel_cache_folder_others_can_write_is_not_used(tmp_path):
    """numba loads code (pickled indexes, machine code) from the kernel cache: a fallback folder
    in the temporary directory that another user made, or made writable by others, is not
    used; the kernels compile without a cache (with a warning) and still run."""
    blocker = tmp_path / "file"
    blocker.write_text("")
    tmp = tmp_path / "tmp"
    planted = tmp / f"flexfusion-numba-{os.getuid()}"
    planted.mkdir(parents=True)
    planted.chmod(0o777)
    env = {**os.environ, "FLEXFUSION_CACHE_DIR": str(blocker), "PYTHONPATH": str(REPO), "TMPDIR": str(tmp)}
    code = ("from fmus.common import jit; print(jit._kernel_cache_dir())\n"
            "twice = jit.kernel(lambda x: 2.0 * x); print(twice(1.5))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["None", "3.0"]
    assert "no private folder for the compiled kernels" in out.stderr and "writable by group or others" in out.stderr
    assert list(planted.iterdir()) == []
    planted.chmod(0o700)                 # private: used
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split()[0].startswith(str(planted))

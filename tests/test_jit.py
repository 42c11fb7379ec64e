"""fmus/common/jit.py: numba kernels whose on-disk cache survives an FMU's extraction folder."""
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
                  "misses": sum(kern.damped.stats.cache_misses.values())}}))
'''


def _bundle(where: Path, pkg: str, bundle_id: str | None, kernel_src: str = KERNEL) -> Path:
    """A package laid out as in an FMU's resources/: ``<pkg>/common/{jit,kern}.py`` (+ BUNDLE_ID)."""
    common = where / pkg / "common"
    common.mkdir(parents=True)
    (where / pkg / "__init__.py").write_text("")
    (common / "__init__.py").write_text("")
    shutil.copy(REPO / "fmus" / "common" / "jit.py", common / "jit.py")
    (common / "kern.py").write_text(kernel_src.format(pkg=pkg))
    if bundle_id:
        (where / pkg / jit.BUNDLE_ID_FILE).write_text(bundle_id + "\n")
    return where


def _probe(folder: Path, pkg: str, cache: Path) -> dict:
    env = {**os.environ, "FLEXFUSION_CACHE_DIR": str(cache)}
    env.pop("NUMBA_DISABLE_JIT", None)
    out = subprocess.run([sys.executable, "-c", PROBE.format(pkg=pkg), str(folder)], env=env,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_cache_hits_in_a_fresh_extraction_folder_and_process(tmp_path):
    """Two extractions of one bundle in two processes: compiled once, loaded from disk after."""
    cache = tmp_path / "cache"
    first = _probe(_bundle(tmp_path / "x1", "fmus_abc", "ab" * 32), "fmus_abc", cache)
    second = _probe(_bundle(tmp_path / "x2", "fmus_abc", "ab" * 32), "fmus_abc", cache)
    assert first["misses"] == 1 and first["hits"] == 0
    assert second["hits"] == 1 and second["misses"] == 0
    assert second["value"] == first["value"]
    assert list((cache / "numba").iterdir()) == [cache / "numba" / ("ab" * 8 + "-fmus_abc")]


def test_changed_sources_never_load_a_stale_kernel(tmp_path):
    """Another bundle id (any source changed) compiles anew, in its own folder."""
    cache = tmp_path / "cache"
    _probe(_bundle(tmp_path / "x1", "fmus_abc", "ab" * 32), "fmus_abc", cache)
    changed = KERNEL.replace("0.5", "0.25")
    other = _probe(_bundle(tmp_path / "x2", "fmus_abc", "cd" * 32, changed), "fmus_abc", cache)
    assert other["misses"] == 1 and other["hits"] == 0
    assert sorted(p.name for p in (cache / "numba").iterdir()) == ["ab" * 8 + "-fmus_abc", "cd" * 8 + "-fmus_abc"]


def test_the_working_tree_and_an_fmu_of_the_same_sources_keep_apart(tmp_path):
    """One bundle id, two packages (``fmus`` and an FMU's ``fmus_<hash>`` with its imports
    rewritten): each keeps its own compiled copy instead of overwriting the other's."""
    cache = tmp_path / "cache"
    for pkg in ("fmus_abc", "fmus_abd", "fmus_abc"):
        _probe(_bundle(tmp_path / f"x-{pkg}-{len(list(tmp_path.iterdir()))}", pkg, "ab" * 32), pkg, cache)
    again = _probe(_bundle(tmp_path / "last", "fmus_abd", "ab" * 32), "fmus_abd", cache)
    assert again["hits"] == 1 and again["misses"] == 0


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
    code = "from fmus.common import jit; print(jit._kernel_cache_dir())"
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

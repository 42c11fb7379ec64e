"""Tests of fmus.common.disk_cache: content keys, the last-used pruning, cached arrays."""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pytest

from fmus.common import disk_cache
from fmus.common.disk_cache import cached_array, content_key, prune


@dataclass(frozen=True)
class Params:
    k: tuple = (1.0, 2.0)
    name: str = "a"


class Geometry:
    def __init__(self, rho: float) -> None:
        self.rho = rho


def test_content_key_is_the_content_bit_for_bit():
    base = (Params(), Geometry(0.5), np.linspace(0.0, 1.0, 5), 1e-3, 7, "iso9283")
    assert content_key(*base) == content_key(Params(), Geometry(0.5), np.linspace(0.0, 1.0, 5), 1e-3, 7, "iso9283")
    changed = [
        (Params(k=(1.0, np.nextafter(2.0, 3.0))),) + base[1:],            # one ulp
        (Params(name="b"),) + base[1:],
        base[:1] + (Geometry(0.25),) + base[2:],
        base[:2] + (np.linspace(0.0, 1.0, 5).astype(np.float32),) + base[3:],   # dtype
        base[:2] + (np.linspace(0.0, 1.0, 6)[:5].reshape(5, 1),) + base[3:],    # shape
        base[:3] + (-1e-3,) + base[4:],
        base[:4] + (7.0,) + base[5:],                                       # int vs float
        base[:4] + (True,) + base[5:],
        base[:5] + ("p1",),
        base + (None,),
    ]
    keys = {content_key(*parts) for parts in changed}
    assert len(keys) == len(changed) and content_key(*base) not in keys
    assert content_key(("ab", "c")) != content_key(("a", "bc"))          # no ambiguous joins
    with pytest.raises(TypeError, match="cannot key"):
        content_key(lambda x: x)                                        # code is no content


def test_prune_keeps_the_last_used_entries_and_removes_left_over_temporaries(tmp_path):
    for i in range(6):
        (tmp_path / f"e{i}").mkdir() if i % 2 else (tmp_path / f"e{i}.npy").write_bytes(b"")
    for i, entry in enumerate(sorted(tmp_path.iterdir(), key=lambda p: p.name)):
        os.utime(entry, (1000 + i, 1000 + i))                           # e0 oldest ... e5 newest
    os.utime(tmp_path / "e1", None)                                     # e1 used just now
    (tmp_path / ".old.npy").write_bytes(b"")
    os.utime(tmp_path / ".old.npy", (1000, 1000))                       # a process died writing it
    (tmp_path / ".now.npy").write_bytes(b"")                            # being written
    prune(tmp_path, 3)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".now.npy", "e1", "e4.npy", "e5"]


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_a_cached_array_is_computed_once_per_key(cache):
    calls = []

    def compute(scale: float):
        calls.append(scale)
        return np.arange(6.0).reshape(3, 2) * scale / 3.0

    first = cached_array("tables", content_key(1.0), (3, 2), lambda: compute(1.0), keep=4)
    again = cached_array("tables", content_key(1.0), (3, 2), lambda: compute(1.0), keep=4)
    other = cached_array("tables", content_key(2.0), (3, 2), lambda: compute(2.0), keep=4)
    assert calls == [1.0, 2.0]                                            # the second was a hit
    np.testing.assert_array_equal(again, first)
    assert again.tobytes() == (np.arange(6.0).reshape(3, 2) / 3.0).tobytes()
    np.testing.assert_array_equal(other, 2.0 * first)
    assert sorted(p.name for p in (cache / "tables").iterdir()) == sorted(
        f"{content_key(s)}.npy" for s in (1.0, 2.0))
    # an entry of another shape (not what the caller asks for) is computed again
    cached_array("tables", content_key(1.0), (2, 3), lambda: compute(1.0).reshape(2, 3), keep=4)
    assert calls == [1.0, 2.0, 1.0]


def test_without_a_writable_cache_the_array_is_computed(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(blocker))
    assert disk_cache.cache_root() == blocker
    for _ in range(2):
        out = cached_array("tables", "k", (2,), lambda: np.ones(2), keep=4)
        np.testing.assert_array_equal(out, np.ones(2))
    assert blocker.read_text() == ""


def test_private_folder_is_made_0700_and_refuses_what_others_can_write(tmp_path):
    top = tmp_path / "root"
    made = disk_cache.private_folder(top / "a" / "b", top)
    for p in (top, top / "a", top / "a" / "b"):
        assert p.is_dir() and p.stat().st_mode & 0o777 == 0o700, p
    (top / "a").chmod(0o775)
    with pytest.raises(PermissionError, match=r"root/a: writable by group or others \(mode 775\)"):
        disk_cache.private_folder(made, top)
    (top / "a").chmod(0o755)               # not writable by others: accepted as it is
    assert disk_cache.private_folder(made, top) == made
    (tmp_path / "elsewhere").mkdir()
    os.symlink(tmp_path / "elsewhere", top / "link")
    with pytest.raises(PermissionError, match="a symbolic link"):
        disk_cache.private_folder(top / "link", top)
    (top / "file").write_text("")
    with pytest.raises(PermissionError, match="not a folder"):
        disk_cache.private_folder(top / "file", top)
    (top / "file").chmod(0o646)
    with pytest.raises(PermissionError, match="writable by group or others"):
        disk_cache.check_private(top / "file", folder=False)
    if os.geteuid() == 0:                  # changing an owner needs root
        os.chown(top / "a" / "b", 4242, 4242)
        with pytest.raises(PermissionError, match="owned by user 4242"):
            disk_cache.private_folder(made, top)

"""The compiled kernels' one path (fmus/common/cython_kernels.py): compiled on first use into the
private cache in a working tree, imported from beside its source in a built package; rounding as
Python does (no contraction into fused multiply-adds); a changed source or .pxd is another entry."""
from __future__ import annotations

import os
import shutil
import sys
from fractions import Fraction

import pytest

from fmus.common import cython_kernels

SOURCE = """# cython: language_level=3
from helper cimport twice

cpdef double axpy(double a, double x, double y):
    return a * x + y

cpdef double doubled(double x):
    return twice(x)
"""
HELPER = "cdef inline double twice(double x) noexcept nogil:\n    return {factor} * x\n"


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One cache for the module's tests: a source compiled by one is found by the next."""
    return tmp_path_factory.mktemp("cache")


@pytest.fixture
def package(tmp_path, monkeypatch, cache):
    """A package ``pkg`` with one kernel module and a .pxd it cimports, and the shared cache."""
    root = tmp_path / "pkg"
    root.mkdir()
    (root / "__init__.py").write_text("")
    (root / "toy_kernels.pyx").write_text(SOURCE)
    (root / "helper.pxd").write_text(HELPER.format(factor="2.0"))
    monkeypatch.setenv("FLEXFUSION_CACHE_DIR", str(cache))
    monkeypatch.setattr(cython_kernels, "PACKAGE", root)
    for name in [n for n in sys.modules if n == "pkg" or n.startswith("pkg.")]:
        monkeypatch.delitem(sys.modules, name)           # another test's toy package
    return root


def _load(name: str = "toy_kernels"):
    return cython_kernels.load.__wrapped__(name)


def test_compiled_on_first_use_and_found_again(package, cache):
    module = _load()
    entries = list((cache / "kernels").glob("*/toy_kernels*.so"))
    assert len(entries) == 1 and module.__name__ == "pkg.toy_kernels"
    stamp = entries[0].stat().st_mtime_ns
    assert _load().doubled(3.0) == 6.0
    assert entries[0].stat().st_mtime_ns == stamp                  # not compiled again


def test_rounds_as_python_without_fused_multiply_add(package):
    a = x = 1.0 + 2.0 ** -30
    y = -(1.0 + 2.0 ** -29)
    exact = Fraction(a) * Fraction(x) + Fraction(y)                  # what a fused multiply-add gives
    assert a * x + y == 0.0 and exact == Fraction(2) ** -60
    assert _load().axpy(a, x, y) == a * x + y


def test_a_changed_pxd_is_another_entry(package):
    first = cython_kernels.module_key(package / "toy_kernels.pyx", package)
    (package / "helper.pxd").write_text(HELPER.format(factor="3.0"))
    assert cython_kernels.module_key(package / "toy_kernels.pyx", package) != first
    assert _load().doubled(3.0) == 9.0


def test_a_built_package_imports_its_module_without_compiling(package, monkeypatch, tmp_path, cache):
    compiled = cython_kernels.compiled(package / "toy_kernels.pyx")         # as the build compiles it
    shutil.copy(compiled, package / f"toy_kernels{cython_kernels.EXTENSION}")
    entries = sorted((cache / "kernels").iterdir())
    (package / cython_kernels.BUNDLE_ID_FILE).write_text("0" * 64)
    monkeypatch.syspath_prepend(str(tmp_path))

    def no_compiling(*args, **kwargs):
        raise AssertionError("compiled although the package has its module")

    monkeypatch.setattr(cython_kernels, "compile_module", no_compiling)
    assert _load().doubled(1.5) == 3.0
    assert sorted((cache / "kernels").iterdir()) == entries


def test_a_source_that_does_not_compile_names_itself(package):
    (package / "broken_kernels.pyx").write_text("cpdef double f(double x):\n    return y\n")
    with pytest.raises(cython_kernels.KernelError, match="compiling broken_kernels.pyx failed"):
        _load("broken_kernels")
    with pytest.raises(cython_kernels.KernelError, match="no kernel module missing_kernels"):
        _load("missing_kernels")


def test_a_truncated_entry_is_set_aside_and_compiled_again(package):
    entry = cython_kernels.compiled(package / "toy_kernels.pyx")
    half = entry.with_name(".half")                   # a new file: this process may have the old one mapped
    half.write_bytes(entry.read_bytes()[:os.path.getsize(entry) // 2])
    half.chmod(0o700)
    os.replace(half, entry)
    with pytest.warns(UserWarning, match="kernel module toy_kernels was not loaded .*compiled again"):
        assert _load().doubled(2.0) == 4.0
    assert len(list(entry.parent.glob(".bad-*"))) == 2              # the library and its hash

"""The tests with stored references, run as another machine would run them (issue 29).

What moves the last bits of our numbers between machines, found here: numpy's SIMD loops
(chosen at import by the CPU's features: ``NPY_DISABLE_CPU_FEATURES`` turns them off) and
glibc's elementary functions (``sin``, ``exp``, ... have FMA variants picked on CPUs with FMA:
``GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA`` picks the others). numba's compiled kernels
follow libm (they call it), and compile without fast-math, so its target CPU changes nothing
(``NUMBA_CPU_NAME=generic`` gave the same bits on every reference); OpenBLAS's kernel is not
changed here (``OPENBLAS_CORETYPE`` is the machine's own setting). The FMUs' ahead-of-time
kernels are compiled for the architecture's generic CPU (fmus/common/jit.py).

A test that holds only on the machine that recorded its numbers fails here first, in a
subprocess with both settings; the study references (montecarlo, robustness), which need every
FMU built, are covered by the same tolerance rule (tests/references.py).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from references import NEEDS_FMUS, REFERENCES

TESTS = Path(__file__).parent
#: the reference tests that need no FMU
KERNEL_REFERENCE_TESTS = [f"tests/{module}.py" for name, (module, _) in REFERENCES.items() if name not in NEEDS_FMUS]

PROBE = ("import math, hashlib, numpy as np; x = np.linspace(-9.0, 9.0, 20001); "
         "print(hashlib.sha1(np.sin(x).tobytes() + np.exp(x / 3).tobytes() + "
         "np.array([math.sin(v) + math.exp(v / 3) for v in x]).tobytes()).hexdigest())")


def other_machine_env() -> dict[str, str]:
    """This process's environment with numpy's optional SIMD extensions off and glibc's
    non-FMA elementary functions."""
    env = dict(os.environ)
    found = np.show_config(mode="dicts")["SIMD Extensions"]["found"]
    env["NPY_DISABLE_CPU_FEATURES"] = " ".join(found)
    env["GLIBC_TUNABLES"] = ":".join(filter(None, [env.get("GLIBC_TUNABLES"), "glibc.cpu.hwcaps=-AVX2,-FMA"]))
    return env


def _probe(env: dict[str, str]) -> str:
    return subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True,
                          check=True).stdout.strip()


def test_the_settings_change_the_last_bits() -> None:
    """On this machine the settings change elementary functions' last bits (else the run
    below would be this machine again): a sine and an exponential through numpy and libm."""
    found = np.show_config(mode="dicts")["SIMD Extensions"]["found"]
    if not found and "fma" not in Path("/proc/cpuinfo").read_text():
        import pytest
        pytest.skip("this machine has neither numpy SIMD extensions beyond the baseline nor FMA: "
                    "it already computes as the baseline machine does")
    assert _probe(other_machine_env()) != _probe(dict(os.environ))


def test_reference_tests_hold_as_another_machine() -> None:
    """Every kernel reference test passes with numpy's baseline SIMD and glibc's non-FMA
    functions."""
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *KERNEL_REFERENCE_TESTS],
                         cwd=TESTS.parent, env=other_machine_env(), capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]

"""Ahead-of-time compiled numba kernels (fmus/common/jit.py, orchestration/build.py): the build's
compiled module returns what the just-in-time kernels return, bit for bit; an FMU with it runs
the flagship byte-identical to one without, and never imports numba; the build without it
still makes FMUs that run (on the JIT).

The kernels move to Cython module by module (ARCHITECTURE.md, "The kernel path"): this tour
covers the numba kernels that remain; the Cython ones are held bit for bit to their readable
Python forms in tests/test_compiled_kernels.py."""
from __future__ import annotations

import copy
import importlib.util
import json
import os
import shutil
import struct
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fmus.common import jit

REPO = Path(__file__).resolve().parent.parent
MODULE = jit.COMPILED_MODULE + sysconfig.get_config_var("EXT_SUFFIX")
FLAGSHIP = [f"{m}.fmu" for m in ("FlexibleRobot2DOF", "MotionController", "Encoder", "Imu",
                                 "RigidKinematics", "Tracker", "EkfAccelerometer")]

pytestmark = pytest.mark.usefixtures("fmu_env_module")


def _compiled_file(fmu: Path) -> str | None:
    with zipfile.ZipFile(fmu) as z:
        return next((n for n in z.namelist() if n.endswith("/" + MODULE)), None)


@pytest.fixture(scope="module")
def compiled(every_fmu: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Any:
    """The compiled module of the suite's build (every FMU carries the same), imported from a
    copy (not the FMUs' package: this process may run those FMUs too)."""
    name = _compiled_file(every_fmu["EkfAccelerometer"])
    if name is None:
        if os.environ.get("FLEXFUSION_NO_AOT"):
            pytest.skip("FLEXFUSION_NO_AOT is set: the build made no ahead-of-time kernels")
        pytest.fail("the build made no ahead-of-time kernels (see its message on stderr)")
    folder = tmp_path_factory.mktemp("aot")
    with zipfile.ZipFile(every_fmu["EkfAccelerometer"]) as z:
        (folder / MODULE).write_bytes(z.read(name))
    spec = importlib.util.spec_from_file_location(jit.COMPILED_MODULE, folder / MODULE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _bits(value: Any) -> Any:
    """``value`` (arrays, floats, tuples of them ...) in a form equal only when bit for bit equal."""
    if isinstance(value, np.ndarray):
        return value.dtype.str, value.shape, value.tobytes()
    if isinstance(value, (tuple, list)):
        return tuple(_bits(v) for v in value)
    if isinstance(value, (float, np.floating)):
        return struct.pack("<d", value)
    return type(value).__name__, value


def _record_kernel_calls(run: Any) -> dict[str, list[tuple]]:
    """The arguments of the Python calls of every ``aot=`` kernel of the working tree's
    ``fmus`` during ``run()`` (copies: kernels write into their arguments), by export name: the
    first calls and the 10th, 100th ... of each."""
    from numba import _dispatcher
    from numba.core.registry import CPUDispatcher
    calls: dict[str, list[tuple]] = {}
    seen: dict[str, int] = {}

    def recording(self, *args, **kwargs):
        if getattr(self, "aot_signature", None) and self.py_func.__module__.startswith("fmus."):
            name = jit.export_name(self.py_func)
            n = seen[name] = seen.get(name, 0) + 1
            if n <= 2 or n in (10, 100, 1000, 10000):
                calls.setdefault(name, []).append(copy.deepcopy(args))
        return _dispatcher.Dispatcher.__call__(self, *args, **kwargs)

    CPUDispatcher.__call__ = recording
    try:
        run()
    finally:
        del CPUDispatcher.__call__
    return calls


def _tour() -> None:
    """Python calls of every kernel Python calls: two runs (seeds) of the shipped scenarios on
    the batched engine (the FMUs' classes and batched kernels, in this process), and the
    Python functions of the kernels no such run calls."""
    from fmus.common import kalman
    from fmus.estimators import ekf_accelerometer_model as em
    from fmus.estimators.axelsson2012_batched import BatchedMeasurement
    from fmus.robot_plant.motion_control_model import MotionControllerParameters, build_controller
    from orchestration.batched import run_recorded
    def run(name: str, seeds: tuple[int, ...] = (1,)) -> None:
        runs = [[f"scenario.seed={seed}", "scenario.stop_time=0.03"] for seed in seeds]
        run_recorded(str(REPO / "orchestration" / "scenarios" / f"{name}.toml"), runs, [])
    run("flagship", (1, 2))           # two runs: the sensors and the EKF batched over runs
    for name in ("flagship", "axelsson2012_pf", "henriksson2009_p1", "contact_observer", "imu2019_square"):
        run(name)                     # one: every component its FMU class
    kalman.is_positive_definite(np.array([[2.0, 0.3], [0.3, 1.0]]))
    meas = em.EkfAccelerometerModel(em.EkfAccelerometerParameters()).meas
    x = np.linspace(0.05, 0.5, meas.layout.n)
    meas.h_and_jacobian(x), meas.arm_torque_jacobian(x[0:2], x[2:4], x[4:6]), meas.specific_force(x)
    BatchedMeasurement(meas).h_and_jacobian(np.stack([x, 0.5 * x]))
    controller = build_controller(MotionControllerParameters())
    controller.model.offset_arm_angles(controller.model.sample(0.5), np.array([1e-3, -2e-3]))
    # Python paths beside the FMUs' one-call steps (studies, identification, the CRLB)
    controller.evaluate(0.5, np.zeros(2), np.zeros(2), np.zeros(2))
    controller.advance(1e-3)
    controller.measure(0.5, np.zeros(2)), controller.measure(0.501, np.array([1e-3, -2e-3]))
    controller.law_speed(0.501)
    ekf = em.EkfAccelerometerModel(em.EkfAccelerometerParameters())
    ekf.predict(np.array([1.0, -1.0]), 1e-3)
    ekf.update(ekf.meas.h_and_jacobian(ekf.x)[0] + 1e-4)


@pytest.fixture(scope="module")
def recorded() -> dict[str, list[tuple]]:
    """:func:`_tour`'s kernel calls (:func:`_record_kernel_calls`)."""
    return _record_kernel_calls(_tour)


def test_every_exported_kernel_returns_the_jit_kernels_bits(compiled, recorded):
    """Each exported kernel, on the arguments the tour called it with: the same results, and
    the same numbers written into its arguments, as the just-in-time kernel, bit for bit."""
    exports = {name for name in dir(compiled) if "__" in name.strip("_")}
    assert exports, "the compiled module exports no kernel"
    assert not exports - set(recorded), ("kernels with aot= that the tour never calls: add a "
                                         f"call to _tour: {sorted(exports - set(recorded))}")
    for name, calls in sorted(recorded.items()):
        *module, function = name.split("__")
        jitted = getattr(importlib.import_module(".".join(["fmus", *module])), function)
        assert name in exports, f"{name} has aot= but is not in the compiled module"
        for args in calls:
            jit_args, aot_args = copy.deepcopy(args), copy.deepcopy(args)
            expected = jitted(*jit_args)
            got = getattr(compiled, name)(*aot_args)
            assert _bits(got) == _bits(expected), f"{name}: another result"
            assert _bits(aot_args) == _bits(jit_args), f"{name}: other numbers written into its arguments"


RUN_FLAGSHIP = '''
import json, sys, warnings
from orchestration import master
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    master.run(sys.argv[1], ["scenario.stop_time=0.6"], out_dir=sys.argv[2])
print(json.dumps({"numba": "numba" in sys.modules}))
'''


def _run_flagship(fmus: Path, out: Path) -> dict:
    env = {**os.environ, "FLEXFUSION_FMU_DIR": str(fmus), "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-c", RUN_FLAGSHIP, str(REPO / "orchestration/scenarios/flagship.toml"),
                           str(out)], env=env, capture_output=True, text=True, cwd=REPO)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_compiled_fmus_run_the_flagship_as_jit_ones_without_numba(fmu_dir, compiled, tmp_path, monkeypatch,
                                                                   capfd):
    """The flagship on the suite's FMUs (compiled kernels) and on FMUs built without them
    (``FLEXFUSION_NO_AOT``: the build says so, and they compile with numba): the same
    results.csv, byte for byte; the process of the compiled ones never imports numba."""
    from orchestration.build import build_all
    monkeypatch.setenv("FLEXFUSION_NO_AOT", "1")
    jit_fmus = tmp_path / "jit_fmus"
    build_all(jit_fmus, only=[f[:-4] for f in FLAGSHIP], quiet=True)
    assert "no ahead-of-time kernels (FLEXFUSION_NO_AOT is set)" in capfd.readouterr().err
    assert all(_compiled_file(jit_fmus / f) is None for f in FLAGSHIP)
    assert all(_compiled_file(fmu_dir / f) is not None for f in FLAGSHIP)
    monkeypatch.delenv("FLEXFUSION_NO_AOT")
    aot_fmus = tmp_path / "aot_fmus"
    aot_fmus.mkdir()
    for f in FLAGSHIP:                  # only the flagship's: the run must not find the others'
        shutil.copy(fmu_dir / f, aot_fmus / f)
    assert _run_flagship(aot_fmus, tmp_path / "aot") == {"numba": False}
    assert _run_flagship(jit_fmus, tmp_path / "jit") == {"numba": True}
    assert (tmp_path / "aot" / "results.csv").read_bytes() == (tmp_path / "jit" / "results.csv").read_bytes()


KERNELS = '''
import math
from {pkg}.common.jit import kernel

@kernel
def _inner(x, i):
    return math.tanh(x * i)

@kernel(aot="{signature}")
def damped(x, n):
    s = 0.0
    for i in range(n):
        s = s * 0.5 + _inner(x, i)
    return s
'''

PROBE = '''
import json, sys
sys.path.insert(0, sys.argv[1])
from {pkg}.common import kern
print(json.dumps({{"value": kern.damped(0.3, 50).hex(), "type": type(kern.damped).__name__,
                  "inner": kern._inner(0.3, 7).hex(), "inner_type": type(kern._inner).__name__,
                  "numba": "numba" in sys.modules}}))
'''


def _package(where: Path, signature: str) -> Path:
    """A package laid out as the build stages it: ``fmus_aot/common/{jit,kern}.py`` and BUNDLE_ID."""
    common = where / "fmus_aot" / "common"
    common.mkdir(parents=True)
    (where / "fmus_aot" / "__init__.py").write_text("")
    (common / "__init__.py").write_text("")
    shutil.copy(REPO / "fmus" / "common" / "jit.py", common / "jit.py")
    (common / "kern.py").write_text(KERNELS.format(pkg="fmus_aot", signature=signature))
    (where / "fmus_aot" / jit.BUNDLE_ID_FILE).write_text(jit.package_digest(where / "fmus_aot") + "\n")
    return where / "fmus_aot"


def _probe(folder: Path, cache: Path) -> dict:
    env = {**os.environ, "FLEXFUSION_CACHE_DIR": str(cache)}
    out = subprocess.run([sys.executable, "-c", PROBE.format(pkg="fmus_aot"), str(folder)], env=env,
                         capture_output=True, text=True, check=True)
    sys.stderr.write(out.stderr)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_compile_kernels_makes_a_module_the_package_runs_without_numba(tmp_path, capfd):
    """A staged package's kernel with ``aot=``: compiled into the package (then taken from the
    cache), it returns the JIT's bits in a process that never imports numba; the same package
    without the module runs on the JIT. The kernel without ``aot=``, called from Python there,
    runs as plain Python (one warning), still without numba."""
    from orchestration.build import compile_kernels
    package = _package(tmp_path / "a", "float64(float64, int64)")
    jitted = _probe(package.parent, tmp_path / "numba")
    assert jitted["type"] == "CPUDispatcher" and jitted["numba"]
    assert compile_kernels(package, cache=tmp_path / "cache", quiet=True) == package / MODULE
    compiled = _probe(package.parent, tmp_path / "numba")
    assert compiled == {**jitted, "type": "builtin_function_or_method", "inner_type": "PythonKernel",
                        "numba": False}
    assert "_inner is called from Python but has no aot= signature" in capfd.readouterr().err
    again = _package(tmp_path / "b", "float64(float64, int64)")
    assert compile_kernels(again, cache=tmp_path / "cache") == again / MODULE
    assert "kernels unchanged" in capfd.readouterr().out               # from the cache
    assert len([p for p in (tmp_path / "cache").iterdir() if p.is_dir()]) == 1


def test_compile_kernels_failing_says_why_and_the_build_goes_on(tmp_path, capfd):
    """A signature numba cannot compile: no module, one message naming the cause."""
    from orchestration.build import compile_kernels
    package = _package(tmp_path, "float64(no_such_type, int64)")
    assert compile_kernels(package, cache=tmp_path / "cache", quiet=True) is None
    err = capfd.readouterr().err
    assert "no ahead-of-time kernels (compilation failed:" in err and "no_such_type" in err
    assert not (package / MODULE).exists()


def test_kernels_raise_only_builtin_exceptions():
    """The compiled module is reused under another package name (orchestration/build.py,
    kernel_sources): nothing of the package may be compiled in, such as an exception class of
    its own that a kernel raises."""
    import ast
    import builtins
    offenders = []
    for source in sorted((REPO / "fmus").rglob("*.py")):
        for node in ast.walk(ast.parse(source.read_text())):
            if isinstance(node, ast.FunctionDef) and any("kernel" in ast.unparse(d) for d in node.decorator_list):
                for r in (n for n in ast.walk(node) if isinstance(n, ast.Raise) and n.exc is not None):
                    exc = r.exc.func if isinstance(r.exc, ast.Call) else r.exc
                    if not (isinstance(exc, ast.Name) and isinstance(getattr(builtins, exc.id, None), type)):
                        offenders.append(f"{source.relative_to(REPO)}: {node.name}: {ast.unparse(r)[:60]}")
    assert offenders == []

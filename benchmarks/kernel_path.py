"""The kernel path's options on one hot kernel, the plant's RK4 step (``chain4_step``), in one run:
numba just in time (the working tree's dispatcher, numba's cache), numba.pycc ahead of time (what
``flexfusion build`` does, here for this kernel alone) and Cython (``kernel_path/chain4_step.pyx``,
a measurement prototype, compiled with the system C compiler as the native layer is).

Prints, for each: the build (CPU of the compiling processes, and wall), the start-up of a fresh
process to the first call (CPU and wall; numpy imported before the clock; the JIT's includes
importing numba, the working tree's module and loading its cached kernels) and the cost of one
call (CPU, best of ``--repeat`` rounds of ``--calls`` chained calls, the three interleaved), and
whether 2000 chained steps give the kernel's bits. The machine is shared: compare within a run.

Needs Cython (``pip install cython``: not one of the project's dependencies).

Run: ``.venv/bin/python benchmarks/kernel_path.py [--calls 20000] [--repeat 7]``
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import resource
import shutil
import struct
import subprocess
import sys
import sysconfig
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
PYX = REPO / "benchmarks" / "kernel_path" / "chain4_step.pyx"
EXT = sysconfig.get_config_var("EXT_SUFFIX")

PYCC = """
import sys
from numba.pycc import CC
from fmus.robot_plant import plant_dynamics as pd
cc = CC("chain4_pycc")
cc.output_dir = sys.argv[1]
cc.export("chain4_step", pd.chain4_step.aot_signature)(pd.chain4_step.py_func)
cc.compile()
"""

FIRST_CALL = """
import sys, time
import numpy as np
P = np.linspace(1.0, 2.0, 51)
P[[2, 3]], P[[8, 9]], P[[16, 17]], P[[18, 19]] = 200.0, 0.01, 0.1, 5e-3
c0, w0 = time.process_time(), time.perf_counter()
{load}
f((0.0,) * 12, 1.0, 1.0, 0.0, 0.0, 1e-3, 1, P)
print(time.process_time() - c0, time.perf_counter() - w0)
"""


def _timed(*commands: list[str], **kwargs) -> tuple[float, float]:
    """CPU seconds of the child processes running ``commands`` one after another, and wall."""
    before, w0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    for command in commands:
        subprocess.run(command, check=True, capture_output=True, **kwargs)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, time.perf_counter() - w0)


def _module(path: Path):
    spec = importlib.util.spec_from_file_location(path.name.split(".")[0], path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=20000, help="chained calls per round")
    ap.add_argument("--repeat", type=int, default=7, help="rounds of each, interleaved (the least counts)")
    args = ap.parse_args()
    if importlib.util.find_spec("Cython") is None:
        raise SystemExit("benchmarks/kernel_path.py needs Cython: pip install cython")
    sys.path.insert(0, str(REPO))
    from fmus.robot_plant.plant_dynamics import chain4_step, plant_model
    from fmus.robot_plant.plant_model import PlantParameters
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    with tempfile.TemporaryDirectory(prefix="ff_kernel_path_") as tmp:
        out = Path(tmp)
        built = {"numba JIT": (0.0, 0.0)}        # compiled at first use, then numba's cache
        built["numba.pycc AOT"] = _timed([sys.executable, "-c", PYCC, tmp], env={**env, "NUMBA_CACHE_DIR": tmp})
        shutil.copy(PYX, out / "chain4_cy.pyx")
        include = sysconfig.get_paths()["include"]
        built["Cython"] = _timed(
            [sys.executable, "-m", "cython", "-3", "chain4_cy.pyx", "-o", "chain4_cy.c"],
            [os.environ.get("CC", "cc"), "-O2", "-fPIC", "-shared", "-ffp-contract=off", f"-I{include}",
             "chain4_cy.c", "-o", f"chain4_cy{EXT}", "-lm"], cwd=tmp)
        kernels = {"numba JIT": chain4_step, "numba.pycc AOT": _module(out / f"chain4_pycc{EXT}").chain4_step,
                   "Cython": _module(out / f"chain4_cy{EXT}").chain4_step}
        loads = {"numba JIT": "from fmus.robot_plant.plant_dynamics import chain4_step as f",
                 "numba.pycc AOT": f"import importlib.util as u; s = u.spec_from_file_location('chain4_pycc', "
                                   f"{str(out / f'chain4_pycc{EXT}')!r}); m = u.module_from_spec(s); "
                                   "s.loader.exec_module(m); f = m.chain4_step",
                 "Cython": f"sys.path.insert(0, {tmp!r}); import chain4_cy; f = chain4_cy.chain4_step"}
        startup = {k: [float("inf")] * 2 for k in kernels}
        for round_ in range(4):          # the first fills numba's cache
            for k, load in loads.items():
                done = subprocess.run([sys.executable, "-c", FIRST_CALL.format(load=load)], env=env, check=True,
                                      capture_output=True, text=True).stdout.split()
                if round_:
                    startup[k] = [min(a, float(b)) for a, b in zip(startup[k], done)]
    model = plant_model(PlantParameters())
    P, s0, fixed = model._k.P, model._s, (20.0, -10.0, 5.0, -3.0, 1e-3, model.substeps, model._k.P)
    bits = {}
    for k, f in kernels.items():
        s = s0
        for _ in range(2000):
            s = f(s, *fixed)
        bits[k] = struct.pack("<12d", *s)
    per_call = {k: float("inf") for k in kernels}
    for _ in range(args.repeat):
        for k, f in kernels.items():
            s, c0 = s0, time.process_time()
            for _ in range(args.calls):
                s = f(s, *fixed)
            per_call[k] = min(per_call[k], (time.process_time() - c0) / args.calls)
    print(f"plant RK4 step (chain4_step, {len(P)} constants), best of {args.repeat} x {args.calls} calls")
    print(f"  {'':16}{'build CPU':>10}{'wall':>7}{'start-up CPU':>14}{'wall':>7}{'per call':>10}  bits")
    for k in kernels:
        build = "   at first use" if k == "numba JIT" else f"{built[k][0]:9.1f}s{built[k][1]:6.1f}s"
        print(f"  {k:16}{build}{startup[k][0] * 1e3:12.1f}ms"
              f"{startup[k][1] * 1e3:5.0f}ms{per_call[k] * 1e6:8.2f}us  "
              f"{'same' if bits[k] == bits['numba JIT'] else 'DIFFERENT'}")
    print(json.dumps({"build": built, "startup": startup, "per_call": per_call}))


if __name__ == "__main__":
    main()

"""Master overhead: time per component-step of our master against a hand-written fmpy loop.

Both drive the same toy FMUs (tests/fmus: a source feeding two gains in a chain, and two coupled
mass-springs) with one setReal / doStep / getReal per component and step. The hand-written loop
uses fmpy's FMU2Slave methods with Python lists, as a user would write it; the master's time is
measured as the difference of two run lengths, so instantiation and initialisation cancel, with
its C loop (orchestration/cosim_loop.c) and with its Python loop, interleaved with the
hand-written loop. Prints the three, the ratios to the hand-written loop (goal: at most 1.2)
and the cost of a full ``run`` with CSV output (C loop).

Run: ``.venv/bin/python benchmarks/master_overhead.py``.
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from orchestration import cloop  # noqa: E402
from orchestration.build import build_all  # noqa: E402
from orchestration.master import CouplingWarning, simulate  # noqa: E402
from orchestration.scenario import load_scenario  # noqa: E402

H = 1e-3
SCENARIO = """
connections = ["src.y -> g1.u", "g1.y -> g2.u", "a.x -> b.x_other", "b.x -> a.x_other"]
[scenario]
stop_time = {stop}
base_step = 0.001
[components.src]
fmu = "Source"
[components.g1]
fmu = "Gain"
[components.g2]
fmu = "Gain"
[components.a]
fmu = "MassSpring"
parameters = {{ kc = 1.0, x0 = 1.0 }}
[components.b]
fmu = "MassSpring"
parameters = {{ kc = 1.0 }}
[record]
variables = ["g2.y", "a.x", "b.x"]
"""


def master_time(tmp: Path, n_steps: int, python_loop: bool = False) -> float:
    """Seconds of a master run of ``n_steps`` (the C loop, or the Python one)."""
    library = cloop.library
    if python_loop:
        cloop.library = lambda: None
    try:
        return _master_time(tmp, n_steps)
    finally:
        cloop.library = library


def _master_time(tmp: Path, n_steps: int) -> float:
    path = tmp / f"s{n_steps}.toml"
    path.write_text(SCENARIO.format(stop=n_steps * H))
    sc = load_scenario(path)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CouplingWarning)
        simulate(sc, lambda t, v: None)
    return time.perf_counter() - t0


def raw_loop(fmu_dir: Path, n_steps: int) -> tuple[float, int]:
    """The same system with plain fmpy calls; returns (seconds of the stepping loop, components)."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    specs = [("src", "Source", {}, [], ["y"]), ("g1", "Gain", {}, ["u"], ["y"]),
             ("g2", "Gain", {}, ["u"], ["y"]),
             ("a", "MassSpring", {"kc": 1.0, "x0": 1.0}, ["x_other"], ["x"]),
             ("b", "MassSpring", {"kc": 1.0}, ["x_other"], ["x"])]
    wires = {"g1": [("src", 0)], "g2": [("g1", 0)], "a": [("b", 0)], "b": [("a", 0)], "src": []}
    comps = {}
    for name, ident, params, ins, outs in specs:
        path = str(fmu_dir / f"{ident}.fmu")
        md = read_model_description(path)
        vr = {v.name: v.valueReference for v in md.modelVariables}
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(path), modelIdentifier=ident,
                        instanceName=name)
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        if params:
            fmu.setReal([vr[k] for k in params], list(params.values()))
        fmu.exitInitializationMode()
        comps[name] = (fmu, [vr[i] for i in ins], [vr[o] for o in outs])
    out = {n: c[0].getReal(c[2]) for n, c in comps.items()}
    order = ["src", "g1", "g2", "a", "b"]
    t0 = time.perf_counter()
    for k in range(n_steps):
        t = k * H
        for n in order:
            fmu, in_vr, out_vr = comps[n]
            if in_vr:
                fmu.setReal(in_vr, [out[p][i] for p, i in wires[n]])
            fmu.doStep(t, H)
            out[n] = fmu.getReal(out_vr)
    elapsed = time.perf_counter() - t0
    for fmu, _, _ in comps.values():
        fmu.terminate()
        fmu.freeInstance()
    return elapsed, len(order)


def main() -> int:
    n_short, n_long = 1000, 6000
    with tempfile.TemporaryDirectory(prefix="ff_bench_") as tmp:
        tmp = Path(tmp)
        build_all(tmp / "fmus", quiet=True, scripts=sorted((REPO / "tests" / "fmus").glob("*_fmu.py")))
        os.environ["FLEXFUSION_FMU_DIR"] = str(tmp / "fmus")
        master_time(tmp, 200)  # warm up (imports, first FMU load)
        raw_loop(tmp / "fmus", 200)
        best = {"c": float("inf"), "python": float("inf"), "raw": float("inf")}
        for _ in range(3):
            for mode in ("c", "python"):
                dt = master_time(tmp, n_long, mode == "python") - master_time(tmp, n_short, mode == "python")
                best[mode] = min(best[mode], dt / ((n_long - n_short) * 5))
            raw, n_comp = raw_loop(tmp / "fmus", n_long - n_short)
            best["raw"] = min(best["raw"], raw / ((n_long - n_short) * n_comp))
        from orchestration import run
        path = tmp / "full.toml"
        path.write_text(SCENARIO.format(stop=n_long * H))
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CouplingWarning)
            run(path, out_dir=tmp / "out")
        full = time.perf_counter() - t0
    print(f"hand-written fmpy loop         : {1e6 * best['raw']:6.2f} us per component-step")
    print(f"our master, C loop (no output) : {1e6 * best['c']:6.2f} us per component-step, "
          f"ratio to the hand-written loop {best['c'] / best['raw']:.2f} (goal <= 1.2)")
    print(f"our master, Python loop        : {1e6 * best['python']:6.2f} us per component-step, "
          f"ratio {best['python'] / best['raw']:.2f}")
    print(f"full run() incl. set-up and CSV, {n_long} steps x 5 components: {full:.2f} s "
          f"({1e6 * full / (n_long * 5):.1f} us per component-step)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

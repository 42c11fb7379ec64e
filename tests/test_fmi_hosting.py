"""Self-contained FMUs in any Python host (issue 13): any number of different FlexFusion FMUs,
from one build or two, in one process with plain fmpy, whatever the host does with the
extraction folders (``fmpy.simulate_fmu`` deletes each one after its run)."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path


REPO = Path(__file__).resolve().parent.parent

# Runs in a fresh interpreter that has the working tree's own `fmus` imported first (as the
# CLI and the tests have): the FMUs must use their bundled copies, not it.
HOST = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
import fmus.common.fmi                     # the working tree's package, as in our own processes
import fmpy
runs = json.loads(sys.argv[2])
failures, outputs = [], {}
for r in range(3):
    for path in runs:
        try:
            res = fmpy.simulate_fmu(path, stop_time=0.02, step_size=0.001, output_interval=0.001)
            outputs.setdefault(path, res.tolist())
            failures += [] if res.tolist() == outputs[path] else [f"{path}: round {r} differs"]
        except Exception as exc:
            failures.append(f"{path}: round {r}: {type(exc).__name__}: {exc}")
bundles = sorted(m for m in sys.modules if m.startswith("fmus_") and "." not in m)
print(json.dumps({"failures": failures, "bundles": bundles, "outputs": outputs}, default=str))
"""


def test_every_fmu_of_two_builds_in_one_plain_fmpy_process(tmp_path_factory, monkeypatch, every_fmu) -> None:
    import orchestration.build as build
    first = list(every_fmu.values())
    # a second build from different sources (one more comment line, in a module no kernel
    # imports): a different bundle, with the same compiled kernels (build.kernel_sources)
    sources = tmp_path_factory.mktemp("other_sources") / "fmus"
    shutil.copytree(REPO / "fmus", sources, ignore=shutil.ignore_patterns("__pycache__"))
    init = sources / "estimators" / "henriksson2009_model.py"
    init.write_text(init.read_text() + "# another build\n")
    monkeypatch.setattr(build, "FMU_SOURCES", sources)
    second = build.build_all(tmp_path_factory.mktemp("second_build"), quiet=True)
    assert len(first) == len(second) == len(build.fmu_scripts())
    runs = [str(p) for pair in zip(first, second) for p in pair]    # alternate the builds
    proc = subprocess.run([sys.executable, "-c", HOST, str(REPO), json.dumps(runs)],
                          capture_output=True, text=True, timeout=600,
                          cwd=tmp_path_factory.mktemp("host_cwd"), env={"PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert report["failures"] == []
    assert len(report["bundles"]) == 2                 # the two builds did not share modules
    for a, b in zip(first, second):                    # same code, same results
        assert report["outputs"][str(a)] == report["outputs"][str(b)], a.name


def test_every_fmu_alone_gives_the_same_bits_under_plain_fmpy_and_our_master(tmp_path_factory, fmu_env,
                                                                          every_fmu) -> None:
    """Standalone (default inputs), 50 steps of 1 ms. fmpy's simulate_fmu passes the step as
    (n + 1) h - n h, which is not h in the last bits for some n (from t = 0.011 s here): the
    ParticleFilter's estimate used to differ from there on."""
    import fmpy
    import numpy as np
    from fmpy import read_model_description

    from orchestration.master import run
    from orchestration.scenario import load_scenario
    from toys import write

    tmp = tmp_path_factory.mktemp("alone")
    h, n = 1e-3, 50
    for path in every_fmu.values():
        md = read_model_description(str(path))
        outputs = [v.name for v in md.modelVariables if v.causality == "output"]
        bases = sorted({o.split("[")[0] for o in outputs})
        scenario = load_scenario(write(tmp, f"""
[scenario]
name = "alone"
stop_time = {n * h}
base_step = {h}
[components.c]
fmu = "{path.stem}"
[record]
variables = {[f"c.{b}" for b in bases]!r}
""".replace("'", '"'), f"{path.stem}.toml"))
        ours = run(scenario, out_dir=tmp / path.stem)
        seed = scenario.components["c"].parameters.get("seed")
        theirs = fmpy.simulate_fmu(str(path), stop_time=n * h, step_size=h, output_interval=h,
                                   output=outputs, start_values={} if seed is None else {"seed": seed})
        assert len(theirs) == len(ours.time) == n + 1, path.stem
        for b in bases:
            mine = ours[f"c.{b}"].reshape(n + 1, -1)
            names = [o for o in outputs if o == b or o.startswith(b + "[")]
            fmpy_values = np.column_stack([theirs[o] for o in names])
            assert np.array_equal(mine, fmpy_values), f"{path.stem}.{b}"


def test_a_thin_script_instantiates_again_under_pythonfmus_library(tmp_path_factory, every_fmu) -> None:
    """pythonfmu 0.7's library (still the FMUs' Windows binary) releases the script module's
    dictionary once per ``fmi2Instantiate``; FlexFusionSlave's _MODULE_DICTS balances that.
    Without it, EkfMotor (a script without functions) fails to instantiate the 2nd time.

    The host leaves with ``os._exit`` after the three runs: pythonfmu 0.7's library frees memory
    twice at interpreter finalisation (why our native layer exists), which glibc reports as
    "corrupted double-linked list" in some processes (measured: 3 of 6 here; none before the
    three runs end)."""
    from orchestration import native
    ours = every_fmu["EkfMotor"]
    fmu = tmp_path_factory.mktemp("pythonfmu_library") / ours.name
    shutil.copy(ours, fmu)
    native.install_into(fmu, native.pythonfmu_library())
    proc = subprocess.run([sys.executable, "-c", "import fmpy, os, sys\nfor _ in range(3):\n"
                           "    fmpy.simulate_fmu(sys.argv[1], stop_time=0.003, step_size=0.001)\n"
                           "print('three runs', flush=True)\nos._exit(0)",
                           str(fmu)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and proc.stdout.strip() == "three runs", proc.stderr[-3000:]

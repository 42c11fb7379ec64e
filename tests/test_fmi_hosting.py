"""Self-contained FMUs in any Python host (issue 13): any number of different FlexFusion FMUs,
from one build or two, in one process with plain fmpy, whatever the host does with the
extraction folders (``fmpy.simulate_fmu`` deletes each one after its run)."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

from fmu_host import every_fmu

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
sys.stdout.flush()
import os; os._exit(0)    # pythonfmu 0.7's exit-time destructors crash (see fmpy_compat)
"""


def test_every_fmu_of_two_builds_in_one_plain_fmpy_process(tmp_path_factory, monkeypatch) -> None:
    import orchestration.build as build
    first = every_fmu(tmp_path_factory)
    # a second build from different sources (one more comment line): a different bundle
    sources = tmp_path_factory.mktemp("other_sources") / "fmus"
    shutil.copytree(REPO / "fmus", sources, ignore=shutil.ignore_patterns("__pycache__"))
    init = sources / "common" / "__init__.py"
    init.write_text(init.read_text() + "# another build\n")
    monkeypatch.setattr(build, "FMU_SOURCES", sources)
    second = build.build_all(tmp_path_factory.mktemp("second_build"), quiet=True)
    assert len(first) == len(second) == 18
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

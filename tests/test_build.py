"""The FMU build (orchestration/build.py)."""
from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

AFTER_AN_FMU_RAN = """
import sys, zipfile
from pathlib import Path
from fmpy import simulate_fmu
simulate_fmu(sys.argv[1], stop_time=0.003, step_size=0.001)
import pythonfmu
bundled = 'resources' in Path(pythonfmu.__file__).parts
from orchestration.build import build_all
fmu, = build_all(Path(sys.argv[2]), only=["Encoder"], quiet=True)
binaries = [n for n in zipfile.ZipFile(fmu).namelist() if n.startswith("binaries/")]
print(bundled, len(binaries))
"""


def test_build_after_an_fmu_ran_in_the_process_has_binaries(tmp_path, every_fmu) -> None:
    """After an FMU ran, 'pythonfmu' resolves to its bundled copy (no binaries); the build must
    still use the installed package's builder (fresh process: pytest has imported the builder)."""
    encoder = every_fmu["Encoder"]
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", AFTER_AN_FMU_RAN, str(encoder), str(tmp_path)],
                         capture_output=True, text=True, timeout=120, cwd=REPO, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    bundled, n_binaries = out.stdout.split()
    assert bundled == "True"          # the situation under test did arise
    assert int(n_binaries) > 0

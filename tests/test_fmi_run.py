"""``flexfusion run`` runs only the FMUs' bundled code (never the working tree's ``fmus``) and
leaves no temporary extraction behind (the FMUs' folders are in the cache)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from toys import write

REPO = Path(__file__).resolve().parent.parent

# the console script's path: main(), then a normal exit
RUN = r"""
import sys
from orchestration import cli
status = cli.main(sys.argv[1:])
tree = sorted(m for m in sys.modules if m == "fmus" or m.startswith("fmus."))
bundled = sorted(m for m in sys.modules if m.startswith("fmus_") and "." not in m)
print("TREE", tree, "BUNDLED", bundled)
sys.exit(status)
"""


def test_run_imports_no_working_tree_fmus_and_cleans_its_extractions(tmp_path_factory, fmu_dir) -> None:
    tmp = tmp_path_factory.mktemp("run")
    scenario = write(tmp, """
connections = ["plant.q_m -> enc.q_m", "enc.q_m_meas -> pf.q_m_meas"]
[scenario]
name = "small"
stop_time = 0.02
base_step = 0.001
[components.plant]
fmu = "FlexibleRobot2DOF"
[components.enc]
fmu = "Encoder"
[components.pf]
fmu = "ParticleFilter"
step = 0.01
parameters = { n_particles = 100 }
[record]
variables = ["pf.q_a_hat"]
""")
    temp = tmp / "temp"
    temp.mkdir()
    env = dict(os.environ, PYTHONPATH=str(REPO), TMPDIR=str(temp),
               FLEXFUSION_FMU_DIR=str(fmu_dir))
    proc = subprocess.run([sys.executable, "-c", RUN, "run", str(scenario), "--out", str(tmp / "out"),
                           "--no-progress"], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    # of the tree, only the caches (the master's extracted FMUs, the C loop, the metrics' compiled
    # filter): no model code
    assert ("TREE ['fmus', 'fmus.common', 'fmus.common.cython_kernels', 'fmus.common.disk_cache', "
            "'fmus.common.native_cache'] BUNDLED ['fmus_") in proc.stdout, proc.stdout
    assert (tmp / "out" / "results.csv").is_file()
    assert list(temp.iterdir()) == []            # no extraction folder left

"""IMU fusion: cost per step of the complementary filter and the IMU EKF, through their FMUs.

The IMU paper's claim: the complementary filter performs on par with the EKF "while having lower
complexity both in the tuning process and the filtering computations". This measures, in one
run and interleaved (so that both see the same machine load), the wall time per communication
step of each FMU driven through fmpy's FMU2Slave (set the 8 inputs, doStep, get all outputs,
as the master does) on recorded-like inputs (a planar motion with sensor noise), plus the plain
models called directly; and their ratio.

Run: ``.venv/bin/python benchmarks/imu_fusion.py [n_steps]``.
"""
from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from fmus.common.frames import G, planar_pose  # noqa: E402
from fmus.estimators import complementary_filter_model as cfm  # noqa: E402
from fmus.estimators import imu_ekf_model as iem  # noqa: E402

DT = 1e-3


def inputs(n: int) -> np.ndarray:
    """(n, 8): p_fk[2], phi_fk, acc_s[3], gyro_s[3] of a planar motion with sensor noise."""
    rng = np.random.default_rng(0)
    t = np.arange(n) * DT
    w = 2 * np.pi * 0.7
    phi = 0.3 + 0.1 * np.sin(w * t)
    x = np.column_stack([1.0 + 0.05 * np.cos(w * t), 0.8 + 0.05 * np.sin(w * t), phi])
    a = -w * w * 0.05 * np.column_stack([np.cos(w * t), np.sin(w * t)])
    c, s = np.cos(phi), np.sin(phi)
    fx, fz = c * a[:, 0] - s * (a[:, 1] + G), s * a[:, 0] + c * (a[:, 1] + G)
    acc = np.column_stack([fx, np.zeros(n), fz]) + 0.02 * rng.standard_normal((n, 3))
    gyro = np.column_stack([np.zeros(n), 0.1 * w * np.cos(w * t), np.zeros(n)])
    gyro += 0.005 * rng.standard_normal((n, 3))
    return np.column_stack([x, acc, gyro])


def open_fmu(path: Path):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    s = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName=path.stem)
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    ins = [vr["p_fk[1]"], vr["p_fk[2]"], vr["phi_fk"]] + [vr[f"{n}[{i}]"] for n in ("acc_s", "gyro_s")
                                                          for i in (1, 2, 3)]
    outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    return s, ins, outs


def main(n: int = 4000) -> dict[str, float]:
    from orchestration.build import build_all
    u = inputs(n + 1)
    with tempfile.TemporaryDirectory() as tmp:
        build_all(Path(tmp), only=["ComplementaryFilter", "ImuEkf"], quiet=True)
        fmus = {name: open_fmu(Path(tmp) / f"{name}.fmu") for name in ("ComplementaryFilter", "ImuEkf")}
        for s, ins, _ in fmus.values():
            s.setReal(ins, list(u[0]))
            s.exitInitializationMode()
        cost = {name: 0.0 for name in fmus}
        t = 0.0
        for k in range(1, n + 1):           # interleaved: both see the same load
            row = list(u[k])
            for name, (s, ins, outs) in fmus.items():
                c0 = time.perf_counter()
                s.setReal(ins, row)
                s.doStep(currentCommunicationPoint=t, communicationStepSize=DT)
                s.getReal(outs)
                cost[name] += time.perf_counter() - c0
            t += DT
    res = {f"{name} FMU [us/step]": c / n * 1e6 for name, c in cost.items()}
    # the plain models, interleaved likewise
    models = {"ComplementaryFilter": cfm.ComplementaryFilterModel(cfm.ComplementaryFilterParameters()),
              "ImuEkf": iem.ImuEkfModel(iem.ImuEkfParameters())}
    direct = {name: 0.0 for name in models}
    poses = [planar_pose(r[0:2], r[2]) for r in u]
    for m in models.values():
        m.reset(*poses[0], u[0, 3:6], u[0, 6:9])
    for k in range(1, n + 1):
        for name, m in models.items():
            c0 = time.perf_counter()
            m.step(*poses[k], u[k, 3:6], u[k, 6:9], DT)
            direct[name] += time.perf_counter() - c0
    res.update({f"{name} model [us/step]": c / n * 1e6 for name, c in direct.items()})
    res["EKF / CF cost ratio, FMU"] = cost["ImuEkf"] / cost["ComplementaryFilter"]
    res["EKF / CF cost ratio, model"] = direct["ImuEkf"] / direct["ComplementaryFilter"]
    return res


if __name__ == "__main__":
    steps = int(sys.argv[1]) if len(sys.argv) > 1 else 4000
    for key, value in main(steps).items():
        print(f"{key:<36} {value:10.2f}")

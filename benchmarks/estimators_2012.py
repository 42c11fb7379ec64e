"""Cost per filter step of the 2012 estimators (Axelsson, Karlsson, Norrlöf): EKF and particle filter.

Prints, for each configuration, the cost of one filter step

* of the plain model (no FMI): ``update`` (measurement update, eq. 3b / Algorithm 1 steps 2-3)
  plus ``predict`` (eq. 3a / the prior means of eqs. 13-14);
* through the FMU with fmpy's FMU2Slave, as a master drives it: one ``setReal`` of the inputs
  (q_m_meas, acc_s, dddq_a_ref), ``doStep`` (commit, predict, update from the inputs) and one
  ``getReal`` of every output;

their ratio (the FMI overhead), and the real-time factor ``T / cost`` at the filter's sample
period ``T``. Each figure is the fastest of a few runs, by the wall clock and by the CPU
time of this process (on a loaded machine the CPU time is the better measure of the cost; the
wall clock is what a real-time loop would see). Configurations:

* ``EkfAccelerometer`` at T = 0.5 ms (2 kHz, the sample rate of the paper's experiments);
* ``ParticleFilter`` with N = 1000 particles at T = 10 ms (100 Hz, the paper's simulation),
  with the bootstrap proposal (eq. 28) and with the EKF proposal (eq. 30), always resampling;
  also microseconds per step and particles x steps per second.

Requirements: the EKF faster than real time at 2 kHz; the PF with 1000 particles and the EKF
proposal faster than real time at 100 Hz. The machine is shared: figures vary with the load.

Run: ``.venv/bin/python benchmarks/estimators_2012.py [--steps N] [--repeat R]``.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from fmus.estimators import axelsson2012_model as am  # noqa: E402
from fmus.estimators.axelsson2012_batched import BatchedMeasurement  # noqa: E402
from fmus.estimators import ekf_accelerometer_model as em  # noqa: E402
from fmus.estimators import particle_filter_model as pm  # noqa: E402

Q0 = (0.2, -0.1)


def signals(n: int, T: float, p) -> tuple[np.ndarray, ...]:
    """A smooth motion from rest (``q = q0 + A (1 - cos w t)^2``), its noisy motor angles and
    accelerometer readings (eqs. 15-19, the paper's noise levels) and its jerk."""
    t = np.arange(n) * T
    q0, A, w = np.array(Q0), np.array([0.05, 0.03]), np.array([3.0, 5.0])
    c, s = np.cos(np.outer(t, w)), np.sin(np.outer(t, w))
    S = 1 - c
    x = np.column_stack([q0 + A * S * S, 2 * A * w * S * s, 2 * A * w * w * (s * s + S * c)])
    u = 2 * A * w ** 3 * (3 * s * c - S * s)
    batch = BatchedMeasurement(am.MeasurementModel(p.robot(), am.Layout(True, False)))
    rng = np.random.default_rng(0)
    y = batch.h(x) + rng.normal(0, 1, (n, 4)) * [1e-3, 1e-3, 1e-2, 1e-2]
    acc = np.column_stack([y[:, 2], np.zeros(n), y[:, 3]])
    return y[:, 0:2], acc, u, y


def plain_cost(model, y: np.ndarray, u: np.ndarray, T: float) -> tuple[float, float]:
    """Seconds per step (wall clock, CPU time of this process) of ``update`` + ``predict`` of a
    plain filter model."""
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(len(u)):
        model.update(y[k])
        model.predict(u[k], T)
    return (time.perf_counter() - t0) / len(u), (time.process_time() - c0) / len(u)


def fmu_cost(fmu: Path, params: dict, qm, acc, u, T: float) -> tuple[float, float]:
    """Seconds per step (wall clock, CPU time) through the FMU: setReal of the inputs, doStep,
    getReal of the outputs."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    s = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu)),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    for name, value in params.items():
        if isinstance(value, str):
            s.setString([vr[name]], [value])
        elif isinstance(value, tuple):
            s.setReal([vr[f"{name}[{i + 1}]"] for i in range(len(value))], list(value))
        elif isinstance(value, int):
            s.setInteger([vr[name]], [value])
        else:
            s.setReal([vr[name]], [float(value)])
    s.exitInitializationMode()
    ins = [vr[f"{n}[{i}]"] for n, k in (("q_m_meas", 2), ("acc_s", 3), ("dddq_a_ref", 2))
           for i in range(1, k + 1)]
    outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    values = np.column_stack([qm, acc, u]).tolist()
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(len(u)):
        s.setReal(ins, values[k])
        s.doStep(currentCommunicationPoint=k * T, communicationStepSize=T)
        s.getReal(outs)
    cost = (time.perf_counter() - t0) / len(u), (time.process_time() - c0) / len(u)
    s.terminate()
    s.freeInstance()
    return cost


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=400, help="filter steps per measurement (EKF: 10x)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per configuration; the fastest counts")
    args = ap.parse_args()
    print(f"load average (1, 5, 15 min): {' '.join(Path('/proc/loadavg').read_text().split()[:3])} "
          f"on {os.cpu_count()} CPUs; cost = fastest of {args.repeat} runs")
    cases = [
        ("EkfAccelerometer", 5e-4, {}, 10 * args.steps),
        ("ParticleFilter", 1e-2, dict(proposal="prior", n_particles=1000), args.steps),
        ("ParticleFilter", 1e-2, dict(proposal="ekf", n_particles=1000), args.steps),
    ]
    with tempfile.TemporaryDirectory() as tmp:
        from orchestration.build import build_all
        paths = {f.stem: f for f in build_all(Path(tmp), only=["EkfAccelerometer", "ParticleFilter"], quiet=True)}
        print(f"{'filter':<36} {'time':>4} {'T [ms]':>6} {'plain [us]':>11} {'FMU [us]':>10} {'FMU/plain':>9} "
              f"{'RTF (T/FMU)':>11} {'particles*steps/s':>18}")
        results = {}
        for name, T, extra, n in cases:
            params = dict(q_a0=Q0, **extra)
            if name == "EkfAccelerometer":
                p = am.EkfAccelerometerParameters(q_a0=Q0)
                make = lambda: em.EkfAccelerometerModel(p)   # noqa: E731
                label = "EkfAccelerometer"
            else:
                p = pm.ParticleFilterParameters(q_a0=Q0, **extra)
                make = lambda: pm.ParticleFilterModel(p)     # noqa: E731
                label = f"ParticleFilter N={p.n_particles} {p.proposal}"
            qm, acc, u, y = signals(n, T, p)
            plain_cost(make(), y[: n // 10], u[: n // 10], T)              # warm-up
            fmu_cost(paths[name], params, qm[: n // 10], acc[: n // 10], u[: n // 10], T)   # warm-up
            # the least disturbed of a few runs (the machine is shared)
            plain = [plain_cost(make(), y, u, T) for _ in range(args.repeat)]
            fmu = [fmu_cost(paths[name], params, qm, acc, u, T) for _ in range(args.repeat)]
            for i, clock in enumerate(("wall", "CPU")):
                t_plain, t_fmu = min(c[i] for c in plain), min(c[i] for c in fmu)
                pps = f"{getattr(p, 'n_particles', 0) / t_fmu:18.3g}" if name == "ParticleFilter" else f"{'':>18}"
                print(f"{label:<36} {clock:>4} {T * 1e3:6.1f} {t_plain * 1e6:11.1f} {t_fmu * 1e6:10.1f} "
                      f"{t_fmu / t_plain:9.2f} {T / t_fmu:11.1f} {pps}")
                results[label, clock] = T / t_fmu
    for clock in ("wall", "CPU"):
        ekf_ok = results["EkfAccelerometer", clock] > 1
        pf_ok = results["ParticleFilter N=1000 ekf", clock] > 1
        print(f"{clock:>4} time: EKF faster than real time at 2 kHz: {'yes' if ekf_ok else 'NO'}; "
              f"PF (N = 1000, EKF proposal) faster than real time at 100 Hz: {'yes' if pf_ok else 'NO'}")


if __name__ == "__main__":
    main()

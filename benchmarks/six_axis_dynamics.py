"""Per-call CPU cost of the six-axis arm's rigid-body dynamics (issue 23: "measure Pinocchio
against a compiled kernel of your own for the step cost, and choose"): Pinocchio's ABA, RNEA,
CRBA and computeABADerivatives called from Python, against a prototype 6-DOF RNEA and ABA
written as numba ``@njit`` plain-loop kernels (Featherstone 2008, "Rigid Body Dynamics
Algorithms", tables 5.1 and 7.1), on the IRB4600-class arm of ``fmus/common/irb4600.py``.

The prototype kernels live here, not in the product: they are checked against Pinocchio before
they are timed (to round-off). Also timed: one plant step as the six-axis plant would take it
(RK4 on the rigid arm's 12 states, 4 forward-dynamics calls), in Python around ``pin.aba`` and as
one ``@njit`` function around the kernel, and the simulated second they cost at 1 kHz with
``--substeps`` RK4 substeps per step.

CPU time (``time.process_time``), per call: the best of ``--repeat`` runs of ``--number`` calls
(the machine is shared; the best run is the least disturbed).

Then the plants as FMUs (``--fmu-seconds``, default 10): ``FlexibleRobot6DOF`` (its compiled
kernel, ``fmus/robot_plant/six_axis_kernels.pyx``) and ``FlexibleRobot2DOF`` in the same run,
each alone under fmpy's FMU2Slave at a 1 kHz communication step for 10 s simulated (setReal of
every input, doStep, getReal of every output at each step, as a master does), held at rest by
their holding torques: CPU time per simulated second (the issue's goal: the whole six-axis
flagship at least 10 times faster than real time, 0.1 s CPU per simulated second, so the plant
must take well under that), and the six-axis model's step called directly (``SixAxisPlant.step``).
The FMUs are built into ``dist/fmus`` first if missing or stale (``flexfusion build``'s
incremental build).

Run: ``.venv/bin/python benchmarks/six_axis_dynamics.py [--number 20000] [--repeat 5] [--substeps 2] [--fmu-seconds 10]``
"""
from __future__ import annotations

import argparse
import math
import sys
import time
import timeit
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from fmus.common import irb4600  # noqa: E402

G = np.array([0.0, 0.0, -9.81])


# ---- the prototype kernels: spatial vectors (angular; linear), link frames at the joints -------
def spatial_inertias(a: irb4600.Arm) -> np.ndarray:
    """(6, 6, 6) spatial inertia of each link about its joint origin, in the link frame:
    ``[[I_c + m c~ c~^T, m c~], [m c~^T, m 1]]`` (Featherstone, eq. 2.63)."""
    out = np.zeros((6, 6, 6))
    for i in range(6):
        m, c = a.mass[i], a.com[i]
        cx = np.array([[0, -c[2], c[1]], [c[2], 0, -c[0]], [-c[1], c[0], 0]])
        out[i, :3, :3] = a.inertia[i] + m * cx @ cx.T
        out[i, :3, 3:] = m * cx
        out[i, 3:, :3] = m * cx.T
        out[i, 3:, 3:] = m * np.eye(3)
    return out


@njit(cache=True)
def _frames(q, origins, axis, Xs):
    """Fill ``Xs`` (6, 6, 6) with the parent-to-child motion transforms ``[[E, 0], [-E r~, E]]``
    of the joints at ``q``: ``E = Rot(axis, q)^T``, ``r`` the joint origin in the parent."""
    for i in range(6):
        c, s = math.cos(q[i]), math.sin(q[i])
        X = Xs[i]
        X[:, :] = 0.0
        k = axis[i]
        if k == 0:
            X[0, 0] = 1.0; X[1, 1] = c; X[1, 2] = s; X[2, 1] = -s; X[2, 2] = c
        elif k == 1:
            X[1, 1] = 1.0; X[0, 0] = c; X[0, 2] = -s; X[2, 0] = s; X[2, 2] = c
        else:
            X[2, 2] = 1.0; X[0, 0] = c; X[0, 1] = s; X[1, 0] = -s; X[1, 1] = c
        r0, r1, r2 = origins[i, 0], origins[i, 1], origins[i, 2]
        for a in range(3):
            e0, e1, e2 = X[a, 0], X[a, 1], X[a, 2]
            X[a + 3, 3] = e0
            X[a + 3, 4] = e1
            X[a + 3, 5] = e2
            # -(E r~)[a, :] with r~ = [[0, -r2, r1], [r2, 0, -r0], [-r1, r0, 0]]
            X[a + 3, 0] = -(e1 * r2 - e2 * r1)
            X[a + 3, 1] = -(-e0 * r2 + e2 * r0)
            X[a + 3, 2] = -(e0 * r1 - e1 * r0)


@njit(cache=True)
def _crm(v, u, out):
    """``out = v x u``, the motion cross product of spatial motion vectors."""
    w0, w1, w2, v0, v1, v2 = v[0], v[1], v[2], v[3], v[4], v[5]
    out[0] = w1 * u[2] - w2 * u[1]
    out[1] = w2 * u[0] - w0 * u[2]
    out[2] = w0 * u[1] - w1 * u[0]
    out[3] = w1 * u[5] - w2 * u[4] + v1 * u[2] - v2 * u[1]
    out[4] = w2 * u[3] - w0 * u[5] + v2 * u[0] - v0 * u[2]
    out[5] = w0 * u[4] - w1 * u[3] + v0 * u[1] - v1 * u[0]


@njit(cache=True)
def _crf(v, f, out):
    """``out = v x* f``, the force cross product."""
    w0, w1, w2, v0, v1, v2 = v[0], v[1], v[2], v[3], v[4], v[5]
    out[0] = w1 * f[2] - w2 * f[1] + v1 * f[5] - v2 * f[4]
    out[1] = w2 * f[0] - w0 * f[2] + v2 * f[3] - v0 * f[5]
    out[2] = w0 * f[1] - w1 * f[0] + v0 * f[4] - v1 * f[3]
    out[3] = w1 * f[5] - w2 * f[4]
    out[4] = w2 * f[3] - w0 * f[5]
    out[5] = w0 * f[4] - w1 * f[3]


@njit(cache=True)
def _mv(X, x, out):
    """``out = X x`` for a 6x6 ``X``, in plain loops."""
    for r in range(6):
        acc = 0.0
        for k in range(6):
            acc += X[r, k] * x[k]
        out[r] = acc


@njit(cache=True)
def _mtv_add(X, x, out):
    """``out += X^T x``."""
    for r in range(6):
        acc = 0.0
        for k in range(6):
            acc += X[k, r] * x[k]
        out[r] += acc


@njit(cache=True)
def rnea(q, dq, ddq, origins, axis, Isp, g):
    """Joint torques ``M ddq + C dq + G`` (Featherstone table 5.1, gravity as a base acceleration)."""
    Xs = np.empty((6, 6, 6))
    _frames(q, origins, axis, Xs)
    f = np.zeros((6, 6))
    vp = np.zeros(6)
    ap = np.zeros(6)
    ap[3] = -g[0]; ap[4] = -g[1]; ap[5] = -g[2]
    vi = np.empty(6)
    ai = np.empty(6)
    s = np.zeros(6)
    Iv = np.empty(6)
    tmp = np.empty(6)
    for i in range(6):
        k = axis[i]
        _mv(Xs[i], vp, vi)
        vi[k] += dq[i]
        s[:] = 0.0
        s[k] = dq[i]
        _mv(Xs[i], ap, ai)
        _crm(vi, s, tmp)
        for r in range(6):
            ai[r] += tmp[r]
        ai[k] += ddq[i]
        _mv(Isp[i], vi, Iv)
        _mv(Isp[i], ai, f[i])
        _crf(vi, Iv, tmp)
        for r in range(6):
            f[i, r] += tmp[r]
        vp[:] = vi
        ap[:] = ai
    tau = np.empty(6)
    for i in range(5, -1, -1):
        tau[i] = f[i, axis[i]]
        if i > 0:
            _mtv_add(Xs[i], f[i], f[i - 1])
    return tau


@njit(cache=True)
def aba(q, dq, tau, origins, axis, Isp, g):
    """Joint accelerations (Featherstone table 7.1, the articulated-body algorithm)."""
    Xs = np.empty((6, 6, 6))
    _frames(q, origins, axis, Xs)
    c = np.zeros((6, 6))
    IA = Isp.copy()
    pA = np.empty((6, 6))
    vp = np.zeros(6)
    vi = np.empty(6)
    s = np.zeros(6)
    Iv = np.empty(6)
    for i in range(6):
        k = axis[i]
        _mv(Xs[i], vp, vi)
        vi[k] += dq[i]
        s[:] = 0.0
        s[k] = dq[i]
        _crm(vi, s, c[i])
        _mv(Isp[i], vi, Iv)
        _crf(vi, Iv, pA[i])
        vp[:] = vi
    U = np.empty((6, 6))
    D = np.empty(6)
    u = np.empty(6)
    Ia = np.empty((6, 6))
    pa = np.empty(6)
    T = np.empty((6, 6))
    for i in range(5, -1, -1):
        k = axis[i]
        for r in range(6):
            U[i, r] = IA[i, r, k]
        D[i] = U[i, k]
        u[i] = tau[i] - pA[i, k]
        if i > 0:
            ud = u[i] / D[i]
            for r in range(6):
                for cc in range(6):
                    Ia[r, cc] = IA[i, r, cc] - U[i, r] * U[i, cc] / D[i]
            _mv(Ia, c[i], pa)
            for r in range(6):
                pa[r] += pA[i, r] + U[i, r] * ud
            X = Xs[i]
            for r in range(6):              # T = Ia X
                for cc in range(6):
                    acc = 0.0
                    for m in range(6):
                        acc += Ia[r, m] * X[m, cc]
                    T[r, cc] = acc
            for r in range(6):              # IA[parent] += X^T T
                for cc in range(6):
                    acc = 0.0
                    for m in range(6):
                        acc += X[m, r] * T[m, cc]
                    IA[i - 1, r, cc] += acc
            _mtv_add(X, pa, pA[i - 1])
    ddq = np.empty(6)
    ap = np.zeros(6)
    ap[3] = -g[0]; ap[4] = -g[1]; ap[5] = -g[2]
    a1 = np.empty(6)
    for i in range(6):
        _mv(Xs[i], ap, a1)
        acc = u[i]
        for r in range(6):
            a1[r] += c[i, r]
            acc -= U[i, r] * a1[r]
        ddq[i] = acc / D[i]
        a1[axis[i]] += ddq[i]
        ap[:] = a1
    return ddq


@njit(cache=True)
def rk4_step_kernel(q, dq, tau, h, origins, axis, Isp, g):
    """One RK4 step of the rigid arm ``(q, dq)`` under the joint torques ``tau`` (compiled)."""
    k1v = aba(q, dq, tau, origins, axis, Isp, g)
    k1q = dq
    k2q = dq + 0.5 * h * k1v
    k2v = aba(q + 0.5 * h * k1q, k2q, tau, origins, axis, Isp, g)
    k3q = dq + 0.5 * h * k2v
    k3v = aba(q + 0.5 * h * k2q, k3q, tau, origins, axis, Isp, g)
    k4q = dq + h * k3v
    k4v = aba(q + h * k3q, k4q, tau, origins, axis, Isp, g)
    return (q + h / 6.0 * (k1q + 2 * k2q + 2 * k3q + k4q),
            dq + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v))


@njit(cache=True)
def aba_loop(n, q, dq, tau, origins, axis, Isp, g):
    """``n`` ABA kernel calls inside compiled code (as a compiled plant step makes them): the
    kernel's cost without the Python-to-numba call."""
    acc = 0.0
    for _ in range(n):
        acc += aba(q, dq, tau, origins, axis, Isp, g)[0]
    return acc


def rk4_step_pinocchio(pin, model, data, q, dq, tau, h):
    """The same RK4 step in Python around ``pin.aba``."""
    k1v = pin.aba(model, data, q, dq, tau).copy()
    k1q = dq
    k2q = dq + 0.5 * h * k1v
    k2v = pin.aba(model, data, q + 0.5 * h * k1q, k2q, tau).copy()
    k3q = dq + 0.5 * h * k2v
    k3v = pin.aba(model, data, q + 0.5 * h * k2q, k3q, tau).copy()
    k4q = dq + h * k3v
    k4v = pin.aba(model, data, q + h * k3q, k4q, tau).copy()
    return (q + h / 6.0 * (k1q + 2 * k2q + 2 * k3q + k4q),
            dq + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v))


POSES = (np.zeros(6), np.array([0.0, 0.5, -0.3, 0.0, 0.5, 0.0]), np.array([0.5, -0.3, 0.3, 1.0, -1.0, 0.5]))


def locked_modes(pin, model, arm, q) -> np.ndarray:
    """Frequencies [Hz] of the arm on its gearbox springs (``arm.k_hi``) with the motors held, at
    the joint angles ``q``: ``M ddq = -(K + dG/dq) dq`` (as ``dynamics.locked_motor_frequencies``)."""
    data = model.createData()
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    h = 1e-6
    dG = np.column_stack([(pin.computeGeneralizedGravity(model, data, q + h * e)
                           - pin.computeGeneralizedGravity(model, data, q - h * e)) / (2 * h) for e in np.eye(6)])
    w2 = np.linalg.eigvals(np.linalg.solve(M, np.diag(arm.k_hi) + dG)).real
    return np.sort(np.sqrt(np.abs(w2))) / (2 * np.pi)


def fmu_cpu(fmu: Path, hold: dict[str, list[float]], seconds: float) -> float:
    """CPU seconds per simulated second of the FMU ``fmu`` alone under fmpy's FMU2Slave at 1 kHz
    for ``seconds`` simulated: each step setReal of every input (``hold``: name -> values, the
    others 0), doStep, getReal of every output."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(fmu))
    ins = [v for v in md.modelVariables if v.causality == "input"]
    outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    values = []
    for v in ins:
        name, _, index = v.name.partition("[")
        values.append(float(hold.get(name, [0.0] * 9)[int(index[:-1]) - 1]) if index else 0.0)
    refs = [v.valueReference for v in ins]
    s = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu)), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="plant")
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    n = int(round(seconds / 1e-3))
    for k in range(100):                                     # warm-up (first loads, caches)
        s.setReal(refs, values)
        s.doStep(currentCommunicationPoint=k * 1e-3, communicationStepSize=1e-3)
        s.getReal(outs)
    t0 = time.process_time()
    for k in range(100, 100 + n):
        s.setReal(refs, values)
        s.doStep(currentCommunicationPoint=k * 1e-3, communicationStepSize=1e-3)
        s.getReal(outs)
    cpu = time.process_time() - t0
    s.terminate()
    s.freeInstance()
    return cpu / seconds


def plant_fmus(seconds: float) -> None:
    """Print the two plants' FMU cost (module docstring)."""
    from fmus.common.parameters import as_array
    from fmus.robot_plant import plant_dynamics
    from fmus.robot_plant.plant_model import PlantParameters
    from fmus.robot_plant.six_axis_model import SixAxisParameters, SixAxisPlant
    from orchestration.build import DEFAULT_DEST, build_all

    built = {p.stem: p for p in build_all(DEFAULT_DEST, only=["FlexibleRobot6DOF", "FlexibleRobot2DOF"], quiet=True)}
    p2 = PlantParameters()
    two = plant_dynamics.plant_model(p2)
    hold2 = list(as_array(two.spring_torques()) / as_array(p2.gear_ratio))
    model = SixAxisPlant(SixAxisParameters())
    tau, w = model.current.copy(), np.zeros(6)
    for _ in range(100):
        model.step(tau, w, 1e-3)
    t0 = time.process_time()
    n = int(round(seconds / 1e-3))
    for _ in range(n):
        model.step(tau, w, 1e-3)
    direct = (time.process_time() - t0) / seconds
    rows = [("FlexibleRobot6DOF FMU (fmpy FMU2Slave: setReal, doStep, getReal of 59 outputs)",
             fmu_cpu(built["FlexibleRobot6DOF"], {"tau_m": list(tau)}, seconds)),
            ("six-axis model's step called directly (SixAxisPlant.step, the kernel's RK4)", direct),
            ("FlexibleRobot2DOF FMU (fmpy FMU2Slave: setReal, doStep, getReal of 24 outputs)",
             fmu_cpu(built["FlexibleRobot2DOF"], {"tau_m": hold2}, seconds))]
    print()
    print(f"Plants at 1 kHz, {seconds:g} s simulated each, held at rest by their holding torques, "
          f"{model.substeps_for(1e-3)} RK4 substeps for the six-axis plant; CPU time (process_time):")
    print()
    print("| plant | ms CPU per simulated second | times faster than real time |")
    print("| --- | ---: | ---: |")
    for name, cpu in rows:
        print(f"| {name} | {cpu * 1e3:.1f} | {1.0 / cpu:.0f} |")


def per_call(fn, number: int, repeat: int) -> float:
    """Best CPU time per call [us] over ``repeat`` runs of ``number`` calls."""
    t = timeit.Timer(fn, timer=time.process_time)
    return min(t.repeat(repeat=repeat, number=number)) / number * 1e6


def main(argv=None) -> int:
    """Print the table (markdown) of per-call CPU costs; ``argv``: the command-line options."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--number", type=int, default=20000, help="calls per run")
    ap.add_argument("--repeat", type=int, default=5, help="runs; the best is reported")
    ap.add_argument("--substeps", type=int, default=2, help="RK4 substeps per 1 ms plant step")
    ap.add_argument("--fmu-seconds", type=float, default=10.0, help="simulated seconds of each plant FMU "
                    "(0: skip the FMUs)")
    args = ap.parse_args(argv)
    import pinocchio as pin

    arm = irb4600.arm()
    model = pin.buildModelFromXML(irb4600.urdf(arm))
    model.gravity.linear[:] = G
    data = model.createData()
    origins = np.ascontiguousarray(arm.origins)
    axis = np.array([int(np.argmax(ax)) for ax in arm.axes], dtype=np.int64)
    Isp = spatial_inertias(arm)
    rng = np.random.default_rng(0)
    q = rng.uniform(arm.q_min, arm.q_max)
    dq, ddq = rng.uniform(-1, 1, 6), rng.uniform(-3, 3, 6)
    tau = pin.rnea(model, data, q, dq, ddq).copy()

    # the kernels against Pinocchio before timing them (round-off of ~1e3 N m torques)
    err_rnea = np.abs(rnea(q, dq, ddq, origins, axis, Isp, G) - tau).max()
    err_aba = np.abs(aba(q, dq, tau, origins, axis, Isp, G) - pin.aba(model, data, q, dq, tau)).max()
    for _ in range(20):
        qq, vv, aa = rng.uniform(arm.q_min, arm.q_max), rng.uniform(-2, 2, 6), rng.uniform(-5, 5, 6)
        tt = pin.rnea(model, data, qq, vv, aa).copy()
        err_rnea = max(err_rnea, np.abs(rnea(qq, vv, aa, origins, axis, Isp, G) - tt).max())
        err_aba = max(err_aba, np.abs(aba(qq, vv, tt, origins, axis, Isp, G) - aa).max())
    assert err_rnea < 1e-9 and err_aba < 1e-9, (err_rnea, err_aba)
    h = 1e-3 / args.substeps
    qa, va = rk4_step_kernel(q, dq, tau, h, origins, axis, Isp, G)
    qb, vb = rk4_step_pinocchio(pin, model, data, q, dq, tau, h)
    assert np.abs(qa - qb).max() < 1e-12 and np.abs(va - vb).max() < 1e-9

    n, r = args.number, args.repeat
    aba_loop(1, q, dq, tau, origins, axis, Isp, G)
    steps = 1000 * args.substeps           # RK4 steps per simulated second
    rows = [  # (call, us per call, calls per simulated second)
        ("Pinocchio `aba` (Python call)", per_call(lambda: pin.aba(model, data, q, dq, tau), n, r), 4 * steps),
        ("Pinocchio `rnea` (Python call)", per_call(lambda: pin.rnea(model, data, q, dq, ddq), n, r), 0),
        ("Pinocchio `crba` (Python call)", per_call(lambda: pin.crba(model, data, q), n, r), 0),
        ("Pinocchio `computeABADerivatives` (Python call)",
         per_call(lambda: pin.computeABADerivatives(model, data, q, dq, tau), n, r), 1000),
        ("numba `@njit` ABA kernel (call from Python)",
         per_call(lambda: aba(q, dq, tau, origins, axis, Isp, G), n, r), 4 * steps),
        ("numba `@njit` ABA kernel (inside compiled code)",
         per_call(lambda: aba_loop(n, q, dq, tau, origins, axis, Isp, G), 1, r) / n, 4 * steps),
        ("numba `@njit` RNEA kernel (call from Python)",
         per_call(lambda: rnea(q, dq, ddq, origins, axis, Isp, G), n, r), 0),
        ("RK4 step, Python around `pin.aba` (4 calls)",
         per_call(lambda: rk4_step_pinocchio(pin, model, data, q, dq, tau, h), n // 4, r), steps),
        ("RK4 step, one `@njit` function around the ABA kernel",
         per_call(lambda: rk4_step_kernel(q, dq, tau, h, origins, axis, Isp, G), n, r), steps),
    ]
    print(f"IRB4600-class arm, 6 DOF; Pinocchio {pin.__version__}; kernels checked against it: "
          f"RNEA {err_rnea:.1e} N m, ABA {err_aba:.1e} rad/s^2; CPU time per call, best of {r} runs "
          f"of {n}; plant at 1 kHz with {args.substeps} RK4 substeps")
    print()
    print("| call | us per call | calls per simulated second | ms CPU per simulated second |")
    print("| --- | ---: | ---: | ---: |")
    for name, us, calls in rows:
        print(f"| {name} | {us:.2f} | {calls or '-'} | {f'{us * calls / 1000:.1f}' if calls else '-'} |")
    print()
    print("10x real time leaves 100 ms of CPU per simulated second for the whole six-axis flagship; "
          "computeABADerivatives counted once per 1 ms step (an EKF's Jacobian).")
    print()
    print("Locked-motor modes [Hz] (motors held, gearboxes at k_hi, gravity's stiffness included; "
          "eigenvalues of M^-1 (K + dG/dq), Pinocchio's CRBA and gravity):")
    print()
    print("| pose q [rad] | modes [Hz] |")
    print("| --- | --- |")
    for pose in POSES:
        print(f"| {tuple(float(v) for v in pose)} | {', '.join(f'{f:.1f}' for f in locked_modes(pin, model, arm, pose))} |")
    if args.fmu_seconds > 0:
        plant_fmus(args.fmu_seconds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

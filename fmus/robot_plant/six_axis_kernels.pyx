# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""The six-axis plant's compiled kernel (issue 23): the right side of
:mod:`fmus.robot_plant.six_axis_model`'s continuous-time model, its RK4 step with the current
loop exact, the rigid-body algorithms it rests on and the plant's outputs, in C through Cython.

The model is the module docstring of :mod:`fmus.robot_plant.six_axis_model`; this is its one
implementation in the product (the numpy form it was first written in is the tests' oracle,
``tests/six_axis_reference.py``, which ``tests/test_six_axis_kernel.py`` holds this to).

Parameters: a :class:`Plant` holds the :c:type:`Params` block, named fields set from
``Plant(**fields)`` (:data:`FIELDS` lists them). The tree (``n`` <= 12 revolute joints, parents
before children) and the drive train of axes 1-6, as :class:`fmus.robot_plant.six_axis_model.SixAxisPlant`
builds them.

Rigid-body dynamics, world coordinates, spatial vectors at the world origin (angular part
first): Featherstone 2008, *Rigid Body Dynamics Algorithms*: RNEA (section 5.3) as a forward
pass ``v_i = v_parent + S_i dq_i``, ``a_i = a_parent + S_i ddq_i + v_parent x S_i dq_i`` (``a_0 =
(0, 0, 0, 0, 0, g)``: gravity as the base's acceleration upward) and a backward one
``f_i = I_i a_i + v_i x* I_i v_i + sum_children f_c``, ``tau_i = S_i . f_i``; CRBA (section
6.2): composite inertias ``I^c_i = I_i + sum_children I^c_c``, ``M_ij = S_j . I^c_i S_i`` for
``j`` ``i`` or an ancestor of it; forward dynamics by Cholesky of ``M`` over the free joints.

State ``x = (q (n), q_m (6), dq (n), dq_m (6), z (6))``, inputs the motor current (6) [N m]
(the current loop's output) and the tool wrench (6: force [N], moment [N m], world axes, at the
tool centre point).
"""
from libc.math cimport cos, sin, exp, tanh, fabs, sqrt
import numpy as np

cdef enum:
    NMAX = 12          # joints of the tree: 6 actuated + up to 6 passive
    NA = 6             # actuated axes
    XMAX = 2 * NMAX + 18

#: one output row of :meth:`Plant.outputs`, in this order: (name, size)
OUTPUTS = (("q_m", 6), ("dq_m", 6), ("q_a", 6), ("dq_a", 6), ("tau_s", 6), ("p_tool", 3), ("quat_tool", 4),
           ("v_tool", 3), ("a_tool", 3), ("omega_tool", 3), ("p_sensor", 3), ("a_sensor", 3))


cdef struct Params:
    # the tree
    int n                       # joints
    int parent[NMAX]            # parent joint, -1: the ground
    double origin[NMAX][3]      # joint origin in the parent body's frame [m]
    double axis[NMAX][3]        # unit joint axis in the body's frame
    double K[NMAX][3][3]        # [axis]x and [axis]x^2: Rodrigues' rotation I + sin K + (1 - cos) K^2
    double KK[NMAX][3][3]
    double mass[NMAX]           # [kg]
    double com[NMAX][3]         # centre of mass, body frame [m]
    double inertia[NMAX][3][3]  # about the centre of mass, body frame [kg m^2]
    int tool                    # the body carrying the tool
    double tcp[3]               # tool centre point, tool body frame [m]
    double sensor[3]            # accelerometer mount, tool frame, from the tcp [m]
    double g                    # gravity along -z [m/s^2]
    int on_tool_path[NMAX]      # 1: the joint is the tool body's or an ancestor's
    # passive joints (linear spring and damper)
    int npas
    int pas[NMAX]               # their tree indices
    double k_p[NMAX]            # [N m/rad]
    double d_p[NMAX]            # [N m s/rad]
    # the six drive trains (axis i: tree joint act[i])
    int act[NA]
    double r[NA]                # gear ratio
    double J_m[NA]              # motor inertia [kg m^2]
    double k_hi[NA]             # gearbox spring: k_hi D - k_soft delta tanh(D / delta)
    double k_soft[NA]           # k_hi - k_lo
    double delta[NA]
    double d[NA]                # gearbox damping [N m s/rad]
    double f_v[NA]              # friction f_v w + (f_c + (f_s - f_c) exp(-(w/w_s)^2) + mu_L |tau_g| / r) tanh(w / w_c)
    double f_c[NA]
    double f_s[NA]
    double w_s[NA]
    double w_c[NA]
    double mu_L[NA]
    int hyst                    # Bouc-Wen hysteresis on
    double k_h[NA]              # its stiffness T_h / z0 (0: off)
    double z0[NA]
    double kt[NA]               # 1 + torque-constant error
    double ripple[NA]           # ripple amplitude [N m] and periods per motor revolution
    double periods[NA]
    double w_i                  # current loop bandwidth [rad/s] (0: off)
    int locked[NA]
    int free[NMAX]              # 1: the tree joint moves (not a locked axis)


#: the named fields of :class:`Plant` (shapes: () scalar, (k,) vector, (k, 3) or (k, 3, 3))
FIELDS = ("parent", "origin", "axis", "mass", "com", "inertia", "tool", "tcp", "sensor", "g", "pas", "k_p", "d_p",
          "act", "r", "J_m", "k_hi", "k_soft", "delta", "d", "f_v", "f_c", "f_s", "w_s", "w_c", "mu_L", "hyst",
          "k_h", "z0", "kt", "ripple", "periods", "w_i", "locked")


cdef struct Kin:
    double R[NMAX][3][3]       # body rotation, body to world
    double o[NMAX][3]          # body origin, world [m]
    double S[NMAX][6]          # motion subspace at the world origin (z, o x z)
    double I[NMAX][6][6]       # spatial inertia at the world origin


cdef inline void cross3(const double* a, const double* b, double* out) noexcept nogil:
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


cdef inline void crm(const double* v, const double* m, double* out) noexcept nogil:
    """``out = v x m`` (spatial motion cross product, Featherstone eq. 2.31)."""
    cdef double t[3]
    cross3(v, m, out)
    cross3(v, m + 3, out + 3)
    cross3(v + 3, m, t)
    out[3] += t[0]
    out[4] += t[1]
    out[5] += t[2]


cdef inline void crf(const double* v, const double* f, double* out) noexcept nogil:
    """``out = v x* f`` (spatial force cross product, Featherstone eq. 2.32)."""
    cdef double t[3]
    cross3(v, f, out)
    cross3(v + 3, f + 3, t)
    out[0] += t[0]
    out[1] += t[1]
    out[2] += t[2]
    cross3(v, f + 3, out + 3)


cdef inline double dot6(const double* a, const double* b) noexcept nogil:
    cdef double s = 0.0
    cdef int k
    for k in range(6):
        s += a[k] * b[k]
    return s


cdef inline void mul6(const double (*I)[6], const double* v, double* out) noexcept nogil:
    cdef int a, b
    cdef double s
    for a in range(6):
        s = 0.0
        for b in range(6):
            s += I[a][b] * v[b]
        out[a] = s


cdef void kinematics(const Params* p, const double* q, Kin* k) noexcept nogil:
    """Body rotations and origins, motion subspaces and spatial inertias at ``q``."""
    cdef int i, a, b, c, j
    cdef double cq, sq, s
    cdef double rot[3][3]
    cdef double RI[3][3]
    cdef double z[3]
    cdef double cm[3]
    cdef double C[3][3]
    cdef double m
    for i in range(p.n):
        cq = cos(q[i])
        sq = sin(q[i])
        for a in range(3):
            for b in range(3):
                rot[a][b] = (1.0 if a == b else 0.0) + (sq * p.K[i][a][b] + (1.0 - cq) * p.KK[i][a][b])
        j = p.parent[i]
        if j < 0:
            for a in range(3):
                for b in range(3):
                    k.R[i][a][b] = rot[a][b]
                k.o[i][a] = p.origin[i][a]
        else:
            for a in range(3):
                for b in range(3):
                    s = 0.0
                    for c in range(3):
                        s += k.R[j][a][c] * rot[c][b]
                    k.R[i][a][b] = s
                s = 0.0
                for c in range(3):
                    s += k.R[j][a][c] * p.origin[i][c]
                k.o[i][a] = s + k.o[j][a]
        for a in range(3):
            z[a] = k.R[i][a][0] * p.axis[i][0] + k.R[i][a][1] * p.axis[i][1] + k.R[i][a][2] * p.axis[i][2]
            cm[a] = k.o[i][a] + (k.R[i][a][0] * p.com[i][0] + k.R[i][a][1] * p.com[i][1] + k.R[i][a][2] * p.com[i][2])
            k.S[i][a] = z[a]
        cross3(&k.o[i][0], z, &k.S[i][3])
        m = p.mass[i]
        C[0][0] = 0.0
        C[0][1] = -cm[2]
        C[0][2] = cm[1]
        C[1][0] = cm[2]
        C[1][1] = 0.0
        C[1][2] = -cm[0]
        C[2][0] = -cm[1]
        C[2][1] = cm[0]
        C[2][2] = 0.0
        for a in range(3):                          # R I_c
            for b in range(3):
                s = 0.0
                for c in range(3):
                    s += k.R[i][a][c] * p.inertia[i][c][b]
                RI[a][b] = s
        for a in range(3):
            for b in range(3):
                s = 0.0                             # (R I_c R^T)_ab
                for c in range(3):
                    s += RI[a][c] * k.R[i][b][c]
                k.I[i][a][b] = s + m * (C[a][0] * C[b][0] + C[a][1] * C[b][1] + C[a][2] * C[b][2])
                k.I[i][a][b + 3] = m * C[a][b]
                k.I[i][a + 3][b] = -m * C[a][b]
                k.I[i][a + 3][b + 3] = m if a == b else 0.0


cdef void rnea(const Params* p, const Kin* k, const double* dq, const double* ddq, double g,
               double (*v)[6], double (*acc)[6], double* tau) noexcept nogil:
    """``tau = M ddq + C dq + G`` with gravity ``g``, and the bodies' spatial velocities ``v``
    and accelerations ``acc`` (the base's acceleration ``(0, 0, 0, 0, 0, g)`` included)."""
    cdef int i, a, j
    cdef double f[NMAX][6]
    cdef double Sdq[6]
    cdef double t[6]
    cdef double Iv[6]
    for i in range(p.n):
        j = p.parent[i]
        for a in range(6):
            Sdq[a] = k.S[i][a] * dq[i]
        if j < 0:
            for a in range(6):
                v[i][a] = Sdq[a]
                acc[i][a] = k.S[i][a] * ddq[i]
            acc[i][5] += g
        else:
            crm(&v[j][0], Sdq, t)
            for a in range(6):
                v[i][a] = v[j][a] + Sdq[a]
                acc[i][a] = acc[j][a] + (k.S[i][a] * ddq[i] + t[a])
        mul6(k.I[i], &acc[i][0], &f[i][0])
        mul6(k.I[i], &v[i][0], Iv)
        crf(&v[i][0], Iv, t)
        for a in range(6):
            f[i][a] += t[a]
    for i in range(p.n - 1, -1, -1):
        tau[i] = dot6(&k.S[i][0], &f[i][0])
        j = p.parent[i]
        if j >= 0:
            for a in range(6):
                f[j][a] += f[i][a]


cdef void crba(const Params* p, const Kin* k, double (*M)[NMAX]) noexcept nogil:
    """The joint-space inertia matrix ``M`` (n, n)."""
    cdef int i, j, a, b
    cdef double Ic[NMAX][6][6]
    cdef double F[6]
    for i in range(p.n):
        for a in range(6):
            for b in range(6):
                Ic[i][a][b] = k.I[i][a][b]
        for j in range(p.n):
            M[i][j] = 0.0
    for i in range(p.n - 1, -1, -1):
        j = p.parent[i]
        if j >= 0:
            for a in range(6):
                for b in range(6):
                    Ic[j][a][b] += Ic[i][a][b]
    for i in range(p.n):
        mul6(Ic[i], &k.S[i][0], F)
        M[i][i] = dot6(&k.S[i][0], F)
        j = p.parent[i]
        while j >= 0:
            M[i][j] = dot6(&k.S[j][0], F)
            M[j][i] = M[i][j]
            j = p.parent[j]


cdef void tool_point(const Params* p, const Kin* k, const double* r, double* out) noexcept nogil:
    """World position of the point ``r`` of the tool body's frame."""
    cdef int a
    cdef int t = p.tool
    for a in range(3):
        out[a] = k.o[t][a] + (k.R[t][a][0] * r[0] + k.R[t][a][1] * r[1] + k.R[t][a][2] * r[2])


cdef void external(const Params* p, const Kin* k, const double* w, double* tau) noexcept nogil:
    """``tau += `` the generalised force of the tool wrench ``w`` at the tool centre point."""
    cdef double pt[3]
    cdef double f0[6]
    cdef int i
    tool_point(p, k, p.tcp, pt)
    cross3(pt, w, f0)
    f0[0] = w[3] + f0[0]
    f0[1] = w[4] + f0[1]
    f0[2] = w[5] + f0[2]
    f0[3] = w[0]
    f0[4] = w[1]
    f0[5] = w[2]
    for i in range(p.n):
        if p.on_tool_path[i]:
            tau[i] += dot6(&k.S[i][0], f0)


cdef int solve_free(const Params* p, double (*M)[NMAX], const double* rhs, double* ddq) noexcept nogil:
    """``ddq`` of the free joints from ``M ddq = rhs`` (Cholesky), zero for the others; -1 if
    ``M`` is not positive definite."""
    cdef int idx[NMAX]
    cdef double L[NMAX][NMAX]
    cdef double y[NMAX]
    cdef int m = 0, i, j, c
    cdef double s
    for i in range(p.n):
        ddq[i] = 0.0
        if p.free[i]:
            idx[m] = i
            m += 1
    for i in range(m):
        for j in range(i + 1):
            s = M[idx[i]][idx[j]]
            for c in range(j):
                s -= L[i][c] * L[j][c]
            if i == j:
                if s <= 0.0:
                    return -1
                L[i][i] = sqrt(s)
            else:
                L[i][j] = s / L[j][j]
    for i in range(m):
        s = rhs[idx[i]]
        for c in range(i):
            s -= L[i][c] * y[c]
        y[i] = s / L[i][i]
    for i in range(m - 1, -1, -1):
        s = y[i]
        for c in range(i + 1, m):
            s -= L[c][i] * ddq[idx[c]]
        ddq[idx[i]] = s / L[i][i]
    return 0


cdef inline double gearbox(const Params* p, int i, double D, double Dd, double z) noexcept nogil:
    """Arm-side gearbox torque of axis ``i``: spring, damping and hysteresis."""
    return p.k_hi[i] * D - p.k_soft[i] * p.delta[i] * tanh(D / p.delta[i]) + p.d[i] * Dd + p.k_h[i] * z


cdef int derivatives(const Params* p, const double* x, const double* current, const double* wrench,
                     double* xd, Kin* k) noexcept nogil:
    """``xd = x_dot`` at ``x`` with the motor ``current`` and the tool ``wrench`` (``NULL``:
    none); ``k`` is left with the kinematics of ``x``. -1: the inertia matrix is not positive
    definite."""
    cdef int n = p.n
    cdef const double* q = x
    cdef const double* qm = x + n
    cdef const double* dq = x + n + 6
    cdef const double* dqm = x + 2 * n + 6
    cdef const double* z = x + 2 * n + 12
    cdef double tau[NMAX]
    cdef double bias[NMAX]
    cdef double zero[NMAX]
    cdef double rhs[NMAX]
    cdef double M[NMAX][NMAX]
    cdef double v[NMAX][6]
    cdef double acc[NMAX][6]
    cdef double D, Dd, tg, w, level, applied
    cdef int i, j
    kinematics(p, q, k)
    for i in range(n):
        tau[i] = 0.0
        zero[i] = 0.0
    for i in range(NA):
        j = p.act[i]
        tau[j] = gearbox(p, i, qm[i] / p.r[i] - q[j], dqm[i] / p.r[i] - dq[j], z[i])
    for i in range(p.npas):
        j = p.pas[i]
        tau[j] = -p.k_p[i] * q[j] - p.d_p[i] * dq[j]
    if wrench != NULL:
        external(p, k, wrench, tau)
    rnea(p, k, dq, zero, p.g, v, acc, bias)
    for i in range(n):
        rhs[i] = tau[i] - bias[i]
    crba(p, k, M)
    for i in range(n):
        xd[i] = dq[i]
    if solve_free(p, M, rhs, xd + n + 6) != 0:
        return -1
    for i in range(NA):
        j = p.act[i]
        D = qm[i] / p.r[i] - q[j]
        Dd = dqm[i] / p.r[i] - dq[j]
        tg = gearbox(p, i, D, Dd, z[i])
        w = dqm[i]
        xd[n + i] = w
        applied = p.kt[i] * current[i] + p.ripple[i] * sin(p.periods[i] * qm[i])
        level = p.f_c[i] + (p.f_s[i] - p.f_c[i]) * exp(-(w / p.w_s[i]) * (w / p.w_s[i])) + p.mu_L[i] * fabs(tg) / p.r[i]
        xd[2 * n + 6 + i] = 0.0 if p.locked[i] else (applied - (p.f_v[i] * w + level * tanh(w / p.w_c[i])) - tg / p.r[i]) / p.J_m[i]
        xd[2 * n + 12 + i] = Dd - (fabs(Dd) * z[i] + Dd * fabs(z[i])) / (2.0 * p.z0[i]) if p.hyst else 0.0
    return 0


cdef inline void current_at(const Params* p, const double* i0, const double* tau_m, double t, double* out) noexcept nogil:
    """The current loop's output a time ``t`` after it was ``i0``, the command ``tau_m`` held."""
    cdef int i
    cdef double e
    if p.w_i <= 0.0:
        for i in range(NA):
            out[i] = tau_m[i]
        return
    e = exp(-p.w_i * t)
    for i in range(NA):
        out[i] = tau_m[i] + (i0[i] - tau_m[i]) * e


cdef int rk4(const Params* p, double* x, double* i0, const double* tau_m, const double* wrench,
             double dt, int substeps) noexcept nogil:
    """Advance ``x`` and the current ``i0`` by ``dt``: ``substeps`` RK4 steps, the current
    exact at each stage's time. -1: the inertia matrix went indefinite (``x`` unchanged)."""
    cdef int m = 2 * p.n + 18, s, j
    cdef double h = dt / substeps, t0, h2 = 0.5 * h, h6 = h / 6.0
    cdef double k1[XMAX]
    cdef double k2[XMAX]
    cdef double k3[XMAX]
    cdef double k4[XMAX]
    cdef double xs[XMAX]
    cdef double xn[XMAX]
    cdef double c0[NA]
    cdef double cm[NA]
    cdef double c1[NA]
    cdef Kin k
    for j in range(m):
        xn[j] = x[j]
    for s in range(substeps):
        t0 = s * h
        current_at(p, i0, tau_m, t0, c0)
        current_at(p, i0, tau_m, t0 + 0.5 * h, cm)
        current_at(p, i0, tau_m, t0 + h, c1)
        if derivatives(p, xn, c0, wrench, k1, &k) != 0:
            return -1
        for j in range(m):
            xs[j] = xn[j] + h2 * k1[j]
        if derivatives(p, xs, cm, wrench, k2, &k) != 0:
            return -1
        for j in range(m):
            xs[j] = xn[j] + h2 * k2[j]
        if derivatives(p, xs, cm, wrench, k3, &k) != 0:
            return -1
        for j in range(m):
            xs[j] = xn[j] + h * k3[j]
        if derivatives(p, xs, c1, wrench, k4, &k) != 0:
            return -1
        for j in range(m):
            xn[j] = xn[j] + h6 * (((k1[j] + 2.0 * k2[j]) + 2.0 * k3[j]) + k4[j])
    for j in range(m):
        x[j] = xn[j]
    current_at(p, i0, tau_m, dt, c0)
    for j in range(NA):
        i0[j] = c0[j]
    return 0


cdef void quaternion(const double (*m)[3], double* q) noexcept nogil:
    """Unit quaternion (w, x, y, z), ``w >= 0``, of the rotation ``m`` (Shepperd 1978, as
    :func:`fmus.common.quaternion.from_matrix`)."""
    cdef double tr = m[0][0] + m[1][1] + m[2][2], s, nq
    cdef int a
    if tr > 0.0:
        s = 2.0 * sqrt(1.0 + tr)
        q[0] = 0.25 * s; q[1] = (m[2][1] - m[1][2]) / s; q[2] = (m[0][2] - m[2][0]) / s; q[3] = (m[1][0] - m[0][1]) / s
    elif m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = 2.0 * sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        q[0] = (m[2][1] - m[1][2]) / s; q[1] = 0.25 * s; q[2] = (m[0][1] + m[1][0]) / s; q[3] = (m[0][2] + m[2][0]) / s
    elif m[1][1] > m[2][2]:
        s = 2.0 * sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        q[0] = (m[0][2] - m[2][0]) / s; q[1] = (m[0][1] + m[1][0]) / s; q[2] = 0.25 * s; q[3] = (m[1][2] + m[2][1]) / s
    else:
        s = 2.0 * sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
        q[0] = (m[1][0] - m[0][1]) / s; q[1] = (m[0][2] + m[2][0]) / s; q[2] = (m[1][2] + m[2][1]) / s; q[3] = 0.25 * s
    nq = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    s = 1.0 / nq if q[0] >= 0.0 else -1.0 / nq
    for a in range(4):
        q[a] = q[a] * s


cdef int outputs(const Params* p, const double* x, const double* current, const double* wrench,
                 double* y) noexcept nogil:
    """The output row ``y`` (:data:`OUTPUTS`' order) at ``x`` with the ``current`` and the tool
    ``wrench`` (the accelerations depend on both). -1: the inertia matrix is not positive definite."""
    cdef int n = p.n, i, j, a, t = p.tool
    cdef double xd[XMAX]
    cdef double v[NMAX][6]
    cdef double acc[NMAX][6]
    cdef double tau[NMAX]
    cdef double pt[3]
    cdef double vp[3]
    cdef double ap[3]
    cdef double u[3]
    cdef double w[3]
    cdef double rs[3]
    cdef const double* r
    cdef Kin k
    if derivatives(p, x, current, wrench, xd, &k) != 0:
        return -1
    rnea(p, &k, x + n + 6, xd + n + 6, 0.0, v, acc, tau)          # accelerations without gravity
    for i in range(NA):
        j = p.act[i]
        y[i] = x[n + i]
        y[6 + i] = x[2 * n + 6 + i]
        y[12 + i] = x[j]
        y[18 + i] = x[n + 6 + j]
        y[24 + i] = gearbox(p, i, x[n + i] / p.r[i] - x[j], x[2 * n + 6 + i] / p.r[i] - x[n + 6 + j], x[2 * n + 12 + i])
    for a in range(3):
        rs[a] = p.tcp[a] + p.sensor[a]
    for j in range(2):                        # the tool centre point, then the sensor's mount
        if j == 0:
            r = &p.tcp[0]
        else:
            r = &rs[0]
        tool_point(p, &k, r, pt)
        cross3(&v[t][0], pt, u)               # w x p
        for a in range(3):
            vp[a] = v[t][3 + a] + u[a]
        cross3(&acc[t][0], pt, u)             # dw x p
        cross3(&v[t][0], vp, w)               # w x v_p
        for a in range(3):
            ap[a] = (acc[t][3 + a] + u[a]) + w[a]
        if j == 0:
            for a in range(3):
                y[30 + a] = pt[a]
                y[37 + a] = vp[a]
                y[40 + a] = ap[a]
                y[43 + a] = v[t][a]
        else:
            for a in range(3):
                y[46 + a] = pt[a]
                y[49 + a] = ap[a]
    quaternion(k.R[t], y + 33)
    return 0


# ---- Python's side --------------------------------------------------------------------------
cdef void _set(double* dst, object value, int count):
    cdef int i
    flat = np.ascontiguousarray(value, dtype=np.float64).ravel()
    if flat.size != count:
        raise ValueError(f"expected {count} values, got {flat.size}")
    for i in range(count):
        dst[i] = flat[i]


cdef void _seti(int* dst, object value, int count):
    cdef int i
    flat = np.asarray(value).ravel()
    if flat.size != count:
        raise ValueError(f"expected {count} values, got {flat.size}")
    for i in range(count):
        dst[i] = int(flat[i])


cdef class Plant:
    """The parameter block of the six-axis plant, set from its named fields (:data:`FIELDS`:
    ``parent`` (n), ``origin``, ``axis``, ``com`` (n, 3), ``mass`` (n), ``inertia`` (n, 3, 3),
    ``tool``, ``tcp`` (3), ``sensor`` (3), ``g``, ``pas`` (passive joints' tree indices),
    ``k_p``, ``d_p`` (per passive joint), ``act`` (6 tree indices), ``r``, ``J_m``, ``k_hi``,
    ``k_soft``, ``delta``, ``d``, ``f_v``, ``f_c``, ``f_s``, ``w_s``, ``w_c``, ``mu_L``, ``k_h``,
    ``z0``, ``kt``, ``ripple``, ``periods``, ``locked`` (6 each), ``hyst``, ``w_i``), and the
    kernels on it. Arrays are float64, contiguous: ``x`` (2 n + 18), currents, torques (6),
    wrenches (6)."""

    cdef Params p

    def __init__(self, **f):
        cdef int n, i, a, b, c, m
        missing = [name for name in FIELDS if name not in f]
        if missing or set(f) - set(FIELDS):
            raise TypeError(f"Plant needs the fields {FIELDS}: missing {missing}, unknown {sorted(set(f) - set(FIELDS))}")
        n = len(f["parent"])
        if not 1 <= n <= NMAX:
            raise ValueError(f"a tree of {n} joints: 1 to {NMAX}")
        self.p.n = n
        _seti(self.p.parent, f["parent"], n)
        _set(&self.p.origin[0][0], f["origin"], 3 * n)
        _set(&self.p.axis[0][0], f["axis"], 3 * n)
        _set(self.p.mass, f["mass"], n)
        _set(&self.p.com[0][0], f["com"], 3 * n)
        _set(&self.p.inertia[0][0][0], f["inertia"], 9 * n)
        self.p.tool = int(f["tool"])
        _set(self.p.tcp, f["tcp"], 3)
        _set(self.p.sensor, f["sensor"], 3)
        self.p.g = float(f["g"])
        m = len(f["pas"])
        self.p.npas = m
        _seti(self.p.pas, f["pas"], m)
        _set(self.p.k_p, f["k_p"], m)
        _set(self.p.d_p, f["d_p"], m)
        _seti(self.p.act, f["act"], NA)
        for name in ("r", "J_m", "k_hi", "k_soft", "delta", "d", "f_v", "f_c", "f_s", "w_s", "w_c", "mu_L",
                     "k_h", "z0", "kt", "ripple", "periods"):
            _set(self._vector(name), f[name], NA)
        self.p.hyst = 1 if f["hyst"] else 0
        self.p.w_i = float(f["w_i"])
        _seti(self.p.locked, f["locked"], NA)
        for i in range(n):
            self.p.free[i] = 1
            self.p.on_tool_path[i] = 0
            for a in range(3):                     # K = [axis]x, KK = K K
                for b in range(3):
                    self.p.K[i][a][b] = 0.0
            self.p.K[i][0][1] = -self.p.axis[i][2]
            self.p.K[i][0][2] = self.p.axis[i][1]
            self.p.K[i][1][2] = -self.p.axis[i][0]
            self.p.K[i][1][0] = self.p.axis[i][2]
            self.p.K[i][2][0] = -self.p.axis[i][1]
            self.p.K[i][2][1] = self.p.axis[i][0]
            for a in range(3):
                for b in range(3):
                    self.p.KK[i][a][b] = (self.p.K[i][a][0] * self.p.K[i][0][b] + self.p.K[i][a][1] * self.p.K[i][1][b]
                                          + self.p.K[i][a][2] * self.p.K[i][2][b])
        for i in range(NA):
            if self.p.locked[i]:
                self.p.free[self.p.act[i]] = 0
        i = self.p.tool
        while i >= 0:
            self.p.on_tool_path[i] = 1
            i = self.p.parent[i]

    cdef double* _vector(self, str name):
        cdef Params* p = &self.p
        return <double*><size_t>{"r": <size_t>p.r, "J_m": <size_t>p.J_m, "k_hi": <size_t>p.k_hi, "k_soft": <size_t>p.k_soft,
                "delta": <size_t>p.delta, "d": <size_t>p.d, "f_v": <size_t>p.f_v, "f_c": <size_t>p.f_c,
                "f_s": <size_t>p.f_s, "w_s": <size_t>p.w_s, "w_c": <size_t>p.w_c, "mu_L": <size_t>p.mu_L,
                "k_h": <size_t>p.k_h, "z0": <size_t>p.z0, "kt": <size_t>p.kt, "ripple": <size_t>p.ripple,
                "periods": <size_t>p.periods}[name]

    @property
    def n(self):
        """Joints of the tree."""
        return self.p.n

    @property
    def size(self):
        """State size ``2 n + 18``."""
        return 2 * self.p.n + 18

    def derivatives(self, double[::1] x, double[::1] current, double[::1] wrench, double[::1] out):
        """``out = x_dot`` at ``x`` with the motor ``current`` (6) and the tool ``wrench`` (6)."""
        cdef Kin k
        self._check(x, out, current, wrench)
        if derivatives(&self.p, &x[0], &current[0], &wrench[0], &out[0], &k) != 0:
            raise FloatingPointError("the inertia matrix is not positive definite")

    def step(self, double[::1] x, double[::1] current, double[::1] tau_m, double[::1] wrench, double dt, int substeps):
        """Advance ``x`` and the motor ``current`` (6, the current loop's state) in place by
        ``dt`` [s] with the commanded torque ``tau_m`` (6) and the tool ``wrench`` (6) held:
        ``substeps`` RK4 steps."""
        cdef int ok
        self._check(x, x, current, wrench)
        if tau_m.shape[0] != NA:
            raise ValueError("tau_m has 6 values")
        if substeps < 1:
            raise ValueError("substeps must be at least 1")
        with nogil:
            ok = rk4(&self.p, &x[0], &current[0], &tau_m[0], &wrench[0], dt, substeps)
        if ok != 0:
            raise FloatingPointError("the inertia matrix is not positive definite")

    def outputs(self, double[::1] x, double[::1] current, double[::1] wrench, double[::1] out):
        """The outputs (:data:`OUTPUTS`, 52 values) at ``x`` with the ``current`` and the tool
        ``wrench``: motor and arm angles and rates, gearbox torque, tool position, quaternion,
        velocity, acceleration (without gravity), angular velocity (world), sensor position
        and acceleration (without gravity, world)."""
        self._check(x, x, current, wrench)
        if out.shape[0] < 52:
            raise ValueError("out needs 52 values")
        if outputs(&self.p, &x[0], &current[0], &wrench[0], &out[0]) != 0:
            raise FloatingPointError("the inertia matrix is not positive definite")

    def mass_matrix(self, double[::1] q):
        """The joint-space inertia matrix (n, n) [kg m^2] at the tree angles ``q`` (CRBA)."""
        cdef Kin k
        cdef double M[NMAX][NMAX]
        cdef int i, j
        kinematics(&self.p, &q[0], &k)
        crba(&self.p, &k, M)
        out = np.empty((self.p.n, self.p.n))
        for i in range(self.p.n):
            for j in range(self.p.n):
                out[i, j] = M[i][j]
        return out

    def rnea(self, double[::1] q, double[::1] dq, double[::1] ddq, double g=-1.0):
        """Inverse dynamics ``M ddq + C dq + G`` (n) [N m] (gravity ``g``; -1: the tree's)."""
        cdef Kin k
        cdef double v[NMAX][6]
        cdef double acc[NMAX][6]
        cdef double tau[NMAX]
        kinematics(&self.p, &q[0], &k)
        rnea(&self.p, &k, &dq[0], &ddq[0], self.p.g if g < 0 else g, v, acc, tau)
        return np.array([tau[i] for i in range(self.p.n)])

    def external(self, double[::1] q, double[::1] wrench):
        """Generalised force (n) [N m] of the tool ``wrench`` (6) at ``q``."""
        cdef Kin k
        cdef double tau[NMAX]
        cdef int i
        kinematics(&self.p, &q[0], &k)
        for i in range(self.p.n):
            tau[i] = 0.0
        external(&self.p, &k, &wrench[0], tau)
        return np.array([tau[i] for i in range(self.p.n)])

    def point(self, double[::1] q, double[::1] r):
        """World position (3) [m] of the point ``r`` (3) of the tool body's frame at ``q``."""
        cdef Kin k
        cdef double out[3]
        kinematics(&self.p, &q[0], &k)
        tool_point(&self.p, &k, &r[0], out)
        return np.array([out[0], out[1], out[2]])

    def tool_rotation(self, double[::1] q):
        """The tool body's rotation (3, 3), body to world, at the tree angles ``q``."""
        cdef Kin k
        cdef int t = self.p.tool
        kinematics(&self.p, &q[0], &k)
        return np.array([[k.R[t][a][b] for b in range(3)] for a in range(3)])

    def potential_energy(self, double[::1] q):
        """Gravitational potential energy [J] of the bodies at ``q``."""
        cdef Kin k
        cdef double s = 0.0, zc
        cdef int i, a
        kinematics(&self.p, &q[0], &k)
        for i in range(self.p.n):
            zc = k.o[i][2] + (k.R[i][2][0] * self.p.com[i][0] + k.R[i][2][1] * self.p.com[i][1] + k.R[i][2][2] * self.p.com[i][2])
            s += self.p.mass[i] * zc
        return self.p.g * s

    cdef void _check(self, double[::1] x, double[::1] out, double[::1] a, double[::1] b):
        if x.shape[0] != 2 * self.p.n + 18 or out.shape[0] < 2 * self.p.n + 18:
            raise ValueError(f"state of {2 * self.p.n + 18} values expected")
        if a.shape[0] != NA or b.shape[0] != NA:
            raise ValueError("currents, torques and wrenches have 6 values")

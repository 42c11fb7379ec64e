# cython: language_level=3, cdivision=True
"""The laser tracker's compiled kernel (:mod:`fmus.robot_plant.tracker_model`): one update of
:class:`~fmus.robot_plant.tracker_model.TrackerModel` on its arrays.

Loaded with ``cython_kernels.load("robot_plant.tracker_kernels")``; the operations of its Python
form in the tests (tests/kernel_oracles.py) in the same order, compiled without contraction into
fused multiply-adds (fmus/common/cython_kernels.py)."""
from cpython.buffer cimport PyBuffer_Release

from common.arrays cimport acquire

# TrackerModel's state array (tracker_model.py's layout)
cdef enum:
    ENTRIES = 0     # history entries
    NEXT = 1        # index of the next sample instant
    T_MEAS = 2      # the held sample's stamp
    ROW = 3         # the next row of the drawn random numbers
    DONE = 0        # what tracker_update returns: done,
    FULL = 1        # nothing done: the history needs room,
    DRAWN = 2       # the random numbers are used up

#: the layouts as the kernel reads them (tracker_model.py's constants must be these)
LAYOUT = {"ENTRIES": ENTRIES, "NEXT": NEXT, "T_MEAS": T_MEAS, "ROW": ROW, "DONE": DONE, "FULL": FULL,
          "DRAWN": DRAWN}


cdef void _position(const double* hist, Py_ssize_t m, double t, double* x, double* z) noexcept nogil:
    # true position at t by linear interpolation in the m entries (t, x, z) of hist (rows of 3),
    # held before the first and after the last
    cdef Py_ssize_t i
    cdef double ta, xa, za, tb, xb, zb, w
    if t <= hist[0]:
        x[0], z[0] = hist[1], hist[2]
        return
    for i in range(m - 1):
        ta, xa, za = hist[3 * i], hist[3 * i + 1], hist[3 * i + 2]
        tb, xb, zb = hist[3 * i + 3], hist[3 * i + 4], hist[3 * i + 5]
        if t <= tb:
            w = (t - ta) / (tb - ta) if tb > ta else 1.0
            x[0], z[0] = xa + w * (xb - xa), za + w * (zb - za)
            return
    x[0], z[0] = hist[3 * (m - 1) + 1], hist[3 * (m - 1) + 2]


cdef long _update(double t, const double* p, bint append, double* hist, Py_ssize_t capacity, double* state,
                  const double* consts, const double* rows, Py_ssize_t n_rows, double* p_meas) noexcept nogil:
    cdef Py_ssize_t m = <Py_ssize_t> state[ENTRIES], row, d, i
    cdef double t0, period, skew, noise, t_k, x, z, oldest
    if append:
        if m == capacity:
            return FULL
        hist[3 * m], hist[3 * m + 1], hist[3 * m + 2] = t, p[0], p[1]
        m += 1
        state[ENTRIES] = m
    t0, period, skew, noise = consts[0], consts[1], consts[2], consts[3]
    while True:
        t_k = t0 + state[NEXT] * period
        if t_k > t + 1e-9 * period:
            break
        row = <Py_ssize_t> state[ROW]
        if row == n_rows:
            return DRAWN
        _position(hist, m, t_k - skew, &x, &z)
        p_meas[0], p_meas[1] = x + noise * rows[2 * row], z + noise * rows[2 * row + 1]   # drawn even when noise = 0
        state[ROW] = row + 1
        state[T_MEAS] = t_k
        state[NEXT] += 1.0
    # keep what the next sample can need: back to one entry at or before (next t_k - skew)
    oldest = t0 + state[NEXT] * period - skew
    d = 0
    while m - d > 1 and hist[3 * (d + 1)] <= oldest:
        d += 1
    if d:
        for i in range(m - d):
            hist[3 * i], hist[3 * i + 1], hist[3 * i + 2] = hist[3 * (i + d)], hist[3 * (i + d) + 1], hist[3 * (i + d) + 2]
        state[ENTRIES] = m - d
    return DONE


def tracker_update(double t, p, bint append, hist, state, consts, rows, p_meas):
    """:meth:`~fmus.robot_plant.tracker_model.TrackerModel.update` on arrays: append ``(t, p)``
    (``p``: 2 floats) to the history ``hist`` (entries ``(t, x, z)``, rows of 3) with
    ``append``, take every sample due by ``t`` into ``p_meas`` (2; ``consts``: first instant,
    period, skew, noise; ``state``: the layout above; ``rows``: standard normal numbers, 2 a
    row), drop the history no later sample needs. Returns ``FULL`` (1: nothing done, the
    history needs room), ``DRAWN`` (2: the random numbers are used up: call again with new ones,
    without ``append``) or ``DONE`` (0)."""
    cdef Py_buffer vp, vh, vs, vc, vr, vm
    cdef int got = 0
    cdef long done
    cdef Py_ssize_t m
    try:
        acquire(p, &vp, 1, False, False, 2, "p"); got = 1
        acquire(hist, &vh, 2, True, False, 3, "hist"); got = 2
        acquire(state, &vs, 1, True, False, 4, "state"); got = 3
        acquire(consts, &vc, 1, False, False, 4, "consts"); got = 4
        acquire(rows, &vr, 2, False, False, 2, "rows"); got = 5
        acquire(p_meas, &vm, 1, True, False, 2, "p_meas"); got = 6
        m = <Py_ssize_t> (<double*> vs.buf)[ENTRIES]
        if vh.shape[0] < 1 or vh.shape[1] != 3 or not 0 <= m <= vh.shape[0] or (m == 0 and not append):
            raise ValueError(f"tracker_update: the history holds {vh.shape[0]} entries (t, x, z), not {m}")
        if vr.shape[1] != 2:
            raise ValueError("tracker_update: the random numbers are 2 a row")
        done = _update(t, <const double*> vp.buf, append, <double*> vh.buf, vh.shape[0], <double*> vs.buf,
                       <const double*> vc.buf, <const double*> vr.buf, vr.shape[0], <double*> vm.buf)
    finally:
        if got >= 6:
            PyBuffer_Release(&vm)
        if got >= 5:
            PyBuffer_Release(&vr)
        if got >= 4:
            PyBuffer_Release(&vc)
        if got >= 3:
            PyBuffer_Release(&vs)
        if got >= 2:
            PyBuffer_Release(&vh)
        if got >= 1:
            PyBuffer_Release(&vp)
    return done

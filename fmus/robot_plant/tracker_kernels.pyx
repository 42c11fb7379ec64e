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


cdef double _position(const double* hist, Py_ssize_t w, Py_ssize_t m, double t, Py_ssize_t c) noexcept nogil:
    # coordinate c (a column, 1 and up) of the true position at t by linear interpolation in the
    # m entries (t, x, z) or (t, x, y, z) of hist (rows of w), held before the first and after
    # the last
    cdef Py_ssize_t i
    cdef double ta, xa, tb, xb, f
    if t <= hist[0]:
        return hist[c]
    for i in range(m - 1):
        ta, xa = hist[w * i], hist[w * i + c]
        tb, xb = hist[w * i + w], hist[w * i + w + c]
        if t <= tb:
            f = (t - ta) / (tb - ta) if tb > ta else 1.0
            return xa + f * (xb - xa)
    return hist[w * (m - 1) + c]


cdef long _update(double t, const double* p, Py_ssize_t dims, bint append, double* hist, Py_ssize_t capacity,
                  double* state, const double* consts, const double* rows, Py_ssize_t n_rows,
                  double* p_meas) noexcept nogil:
    cdef Py_ssize_t w = dims + 1, m = <Py_ssize_t> state[ENTRIES], row, d, i, c
    cdef double t0, period, skew, noise, t_k, oldest
    if append:
        if m == capacity:
            return FULL
        hist[w * m] = t
        for c in range(dims):
            hist[w * m + 1 + c] = p[c]
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
        for c in range(dims):                                   # drawn even when noise = 0
            p_meas[c] = _position(hist, w, m, t_k - skew, c + 1) + noise * rows[dims * row + c]
        state[ROW] = row + 1
        state[T_MEAS] = t_k
        state[NEXT] += 1.0
    # keep what the next sample can need: back to one entry at or before (next t_k - skew)
    oldest = t0 + state[NEXT] * period - skew
    d = 0
    while m - d > 1 and hist[w * (d + 1)] <= oldest:
        d += 1
    if d:
        for i in range(m - d):
            for c in range(w):
                hist[w * i + c] = hist[w * (i + d) + c]
        state[ENTRIES] = m - d
    return DONE


def tracker_update(double t, p, bint append, hist, state, consts, rows, p_meas):
    """:meth:`~fmus.robot_plant.tracker_model.TrackerModel.update` on arrays: append ``(t, p)``
    (``p``: 2 or 3 coordinates, world x, z or x, y, z) to the history ``hist`` (entries
    ``(t, x, z)`` or ``(t, x, y, z)``: rows of one more) with ``append``, take every sample due
    by ``t`` into ``p_meas`` (as many as ``p``; ``consts``: first instant, period, skew, noise;
    ``state``: the layout above; ``rows``: standard normal numbers, one a coordinate in a row), drop the history no later sample needs. Returns ``FULL`` (1: nothing done, the
    history needs room), ``DRAWN`` (2: the random numbers are used up: call again with new ones,
    without ``append``) or ``DONE`` (0)."""
    cdef Py_buffer vp, vh, vs, vc, vr, vm
    cdef int got = 0
    cdef long done
    cdef Py_ssize_t m, dims
    try:
        acquire(p, &vp, 1, False, False, 2, "p"); got = 1
        dims = vp.shape[0]
        if dims > 3:
            raise ValueError(f"tracker_update: a position has 2 or 3 coordinates, not {dims}")
        acquire(hist, &vh, 2, True, False, dims + 1, "hist"); got = 2
        acquire(state, &vs, 1, True, False, 4, "state"); got = 3
        acquire(consts, &vc, 1, False, False, 4, "consts"); got = 4
        acquire(rows, &vr, 2, False, False, dims, "rows"); got = 5
        acquire(p_meas, &vm, 1, True, False, dims, "p_meas"); got = 6
        m = <Py_ssize_t> (<double*> vs.buf)[ENTRIES]
        if vh.shape[0] < 1 or vh.shape[1] != dims + 1 or not 0 <= m <= vh.shape[0] or (m == 0 and not append):
            raise ValueError(f"tracker_update: the history holds {vh.shape[0]} entries of {dims + 1}, not {m}")
        if vr.shape[1] != dims or vm.shape[0] != dims:
            raise ValueError(f"tracker_update: the random numbers and the sample are {dims} a row")
        done = _update(t, <const double*> vp.buf, dims, append, <double*> vh.buf, vh.shape[0], <double*> vs.buf,
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

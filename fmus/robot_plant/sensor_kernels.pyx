# cython: language_level=3, cdivision=True
"""The sensors' compiled kernels (:mod:`fmus.robot_plant.sensor_model`): one step of
:class:`~fmus.robot_plant.sensor_model.SensorChannels` on its work array, and the ideal IMU
reading.

Loaded with ``cython_kernels.load("robot_plant.sensor_kernels")``; the operations of their
Python forms in the tests (tests/kernel_oracles.py) in the same order, compiled without
contraction into fused multiply-adds (fmus/common/cython_kernels.py)."""
from cpython.buffer cimport PyBuffer_Release
from libc.math cimport cos, fabs, fmod, rint, sin

from common.arrays cimport acquire

# SensorChannels' work array (sensor_model.py's layout): a header, the low-pass coefficients,
# the parameter table (6 rows of n), then per element the low-pass state (2 rows), the bias walk
# and the saturation flags
cdef enum:
    COUNT = 0       # steps since the last sample
    PERIOD = 1      # steps per sample
    ROW = 2         # the next row of the drawn random numbers
    STARTED = 3     # whether the low-pass has started
    ORDER = 4       # its order (0: none)
    N = 5           # the number of channels n
    COEF = 6        # b0, b1, b2, a1, a2
    TABLE = 11      # the parameter table's rows, n each:
    GAIN = 0        # 1 + scale-factor error
    BIAS = 1        # constant bias
    RW = 2          # bias-walk step per sample
    NOISE = 3       # white noise per sample
    RES = 4         # resolution (0: none)
    LIM = 5         # largest representable magnitude

HELD, SAMPLED, USED_UP = 0, 1, 2          # what channels_step returns


cdef void _channels(const double* x, Py_ssize_t nx, double* work, double* out, Py_ssize_t size,
                    const double* rows, Py_ssize_t width, Py_ssize_t row, long order, bint reset, bint sample,
                    bint noisy) noexcept nogil:
    # rows: the random numbers, ``width`` a row
    cdef Py_ssize_t n = <Py_ssize_t> work[N]
    cdef Py_ssize_t z0 = TABLE + 6 * n
    cdef Py_ssize_t z1 = z0 + size, walk = z0 + 2 * size, saturated = z0 + 3 * size
    cdef double b0 = work[COEF], b1 = work[COEF + 1], b2 = work[COEF + 2], a1 = work[COEF + 3], a2 = work[COEF + 4]
    cdef const double* r = rows + row * width
    cdef Py_ssize_t k, j
    cdef double y, u, res, lim
    for k in range(size):
        j = TABLE + k % n
        y = x[k % nx]
        if order > 0:
            u = y
            if reset:                            # steady state for a constant input
                if order == 2:
                    work[z1 + k] = (b2 - a2) * u
                work[z0 + k] = (1.0 - b0) * u
            y = b0 * u + work[z0 + k]            # direct form II transposed
            if order == 1:
                work[z0 + k] = b1 * u - a1 * y
            else:
                work[z0 + k] = b1 * u - a1 * y + work[z1 + k]
                work[z1 + k] = b2 * u - a2 * y
        if sample:
            if noisy:
                work[walk + k] = work[walk + k] + work[j + RW * n] * r[k]
                y = (work[j + GAIN * n] * y + work[j + BIAS * n] + work[walk + k]
                     + work[j + NOISE * n] * r[size + k])
            else:
                y = work[j + GAIN * n] * y + work[j + BIAS * n] + work[walk + k]
            res = work[j + RES * n]
            if res > 0.0:
                y = rint(y / res) * res          # round half to even, as numpy's rint
            lim = work[j + LIM * n]
            work[saturated + k] = 1.0 if fabs(y) >= lim else 0.0
            if y > lim:
                y = lim
            elif y < -lim:
                y = -lim
            out[k] = y


cdef int _run(object x, object work, object out, object rows, Py_ssize_t row, long order, bint reset,
              bint sample, bint noisy, bint step) except -1:
    """channels_kernel's call (``step`` false) or channels_step's (``step``: ``row``, ``order``,
    ``reset``, ``sample`` read from the work array, the counters moved on): the arrays acquired,
    checked and released; returns what channels_step returns."""
    cdef Py_buffer vx, vw, vo, vr
    cdef int got = 0, done = HELD
    cdef double* w
    cdef Py_ssize_t n, size
    try:
        acquire(x, &vx, 1, False, False, 1, "x"); got = 1
        acquire(work, &vw, 1, True, False, TABLE + 6, "work"); got = 2
        acquire(out, &vo, 1, True, False, 1, "out"); got = 3
        acquire(rows, &vr, 2, False, False, 0, "rows"); got = 4
        w = <double*> vw.buf
        n, size = <Py_ssize_t> w[N], vo.shape[0]
        if n < 1 or vw.shape[0] < TABLE + 6 * n + 4 * size:
            raise ValueError("the sensor channels' work array does not fit their outputs")
        if step:
            sample = w[COUNT] == 0.0
            order = <long> w[ORDER]
            reset = order > 0 and w[STARTED] == 0.0
            row = <Py_ssize_t> w[ROW]
            noisy = sample
        if noisy and not (0 <= row < vr.shape[0] and vr.shape[1] >= 2 * size):
            raise IndexError(f"no row {row} of {2 * size} random numbers")
        if step:
            if order > 0:
                w[STARTED] = 1.0
            if sample:
                w[ROW] = row + 1
        _channels(<const double*> vx.buf, vx.shape[0], w, <double*> vo.buf, size, <const double*> vr.buf,
                  vr.shape[1], row, order, reset, sample, noisy)
        if step:
            w[COUNT] = fmod(w[COUNT] + 1.0, w[PERIOD])    # both positive: Python's %
            if sample:
                done = USED_UP if row + 1 == vr.shape[0] else SAMPLED
    finally:
        if got >= 4:
            PyBuffer_Release(&vr)
        if got >= 3:
            PyBuffer_Release(&vo)
        if got >= 2:
            PyBuffer_Release(&vw)
        if got >= 1:
            PyBuffer_Release(&vx)
    return done


def channels_kernel(x, work, out, rows, Py_ssize_t row, long order, bint reset, bint sample, bint noisy):
    """One step of :class:`~fmus.robot_plant.sensor_model.SensorChannels` (its steps 1 and 3-7)
    on its ``work`` array (float arrays, C-contiguous).

    ``out`` holds ``runs * n`` values (one sensor: ``runs = 1``), element ``k`` of channel
    ``k % n``; the input ``x`` holds ``runs * n`` or ``n`` values (one input for every run).
    ``order`` 0: no filter; ``reset``: start the filter in steady state at ``x``; ``sample``:
    form the reading into ``out`` and the saturation flags; ``noisy``: with the bias-walk step
    ``rows[row, k]`` and the white noise ``rows[row, runs * n + k]`` (standard normal numbers)
    scaled by the table's rows."""
    _run(x, work, out, rows, row, order, reset, sample, noisy, False)


def channels_step(x, work, out, rows):
    """:meth:`~fmus.robot_plant.sensor_model.SensorChannels.step` after its checks, in one call:
    the low-pass (started in steady state at its first step), and at a sample (no step since the
    last) a reading into ``out`` with the next row of the drawn standard normal numbers ``rows``
    (:func:`channels_kernel`); then the counters move on. Returns ``HELD`` (0), ``SAMPLED`` (1)
    or ``USED_UP`` (2: sampled with the last row)."""
    return _run(x, work, out, rows, 0, 0, False, False, False, True)


def imu_reading_into(a_world_xz, double phi, double omega, mount, double g, acc, gyro):
    """:func:`~fmus.robot_plant.sensor_model.imu_reading` of ``a_world_xz`` (2), ``phi``,
    ``omega`` and ``g`` into the float arrays ``acc`` and ``gyro`` (3 each), with the mount
    matrix ``mount`` (9, row-major) of :func:`~fmus.robot_plant.sensor_model.mount_matrix`: the
    same operations."""
    cdef Py_buffer va, vm, vc, vg
    cdef int got = 0
    cdef const double* a
    cdef const double* m
    cdef double* out
    cdef double* gy
    try:
        acquire(a_world_xz, &va, 1, False, False, 2, "a_world_xz"); got = 1
        acquire(mount, &vm, 1, False, False, 9, "mount"); got = 2
        acquire(acc, &vc, 1, True, False, 3, "acc"); got = 3
        acquire(gyro, &vg, 1, True, False, 3, "gyro"); got = 4
        a, m, out, gy = <const double*> va.buf, <const double*> vm.buf, <double*> vc.buf, <double*> vg.buf
        _imu(a, phi, omega, m, g, out, gy)
    finally:
        if got >= 4:
            PyBuffer_Release(&vg)
        if got >= 3:
            PyBuffer_Release(&vc)
        if got >= 2:
            PyBuffer_Release(&vm)
        if got >= 1:
            PyBuffer_Release(&va)


cdef void _imu(const double* a_world_xz, double phi, double omega, const double* mount, double g, double* acc,
               double* gyro) noexcept nogil:
    cdef double m00 = mount[0], m01 = mount[1], m02 = mount[2], m10 = mount[3], m11 = mount[4]
    cdef double m12 = mount[5], m20 = mount[6], m21 = mount[7], m22 = mount[8]
    cdef double c = cos(phi), s = sin(phi)
    cdef double ax = a_world_xz[0], vz = a_world_xz[1] + g          # a - g_vec, y = 0
    # rows 0 and 2 of R_s (row 1 is R_mount's): acc = R_s^T (ax, 0, vz), gyro = R_s^T (0, omega, 0)
    cdef double r00 = c * m00 + s * m20, r01 = c * m01 + s * m21, r02 = c * m02 + s * m22
    cdef double r20 = c * m20 - s * m00, r21 = c * m21 - s * m01, r22 = c * m22 - s * m02
    acc[0] = r00 * ax + r20 * vz
    acc[1] = r01 * ax + r21 * vz
    acc[2] = r02 * ax + r22 * vz
    gyro[0] = m10 * omega
    gyro[1] = m11 * omega
    gyro[2] = m12 * omega


#: the work array's layout as the kernels read it (sensor_model.py's constants must be these)
LAYOUT = {"COUNT": COUNT, "PERIOD": PERIOD, "ROW": ROW, "STARTED": STARTED, "ORDER": ORDER, "N": N,
          "COEF": COEF, "TABLE": TABLE, "GAIN": GAIN, "BIAS": BIAS, "RW": RW, "NOISE": NOISE, "RES": RES,
          "LIM": LIM, "HELD": HELD, "SAMPLED": SAMPLED, "USED_UP": USED_UP}

# cython: language_level=3, boundscheck=False, wraparound=False, initializedcheck=False
"""Compiled signal-processing kernels (loaded with :func:`fmus.common.cython_kernels.load`).

``sosfilt`` is the cascade of second-order sections of ``scipy.signal.sosfilt`` (transposed direct
form II), the same operations in the same order as scipy's own compiled loop, so that a caller
gets scipy's bits without importing ``scipy.signal`` (about 0.9 s of a run's start-up):
tests/test_metrics.py holds the two equal bit for bit.
"""


def sosfilt(const double[:, ::1] sos, double[:, ::1] x, double[:, :, ::1] zi):
    """Filter each row of ``x`` (signals, samples) in place through the sections ``sos``
    (sections, 6: ``b0 b1 b2 a0 a1 a2`` with ``a0 = 1``), from and into the states ``zi``
    (signals, sections, 2), in place too."""
    cdef Py_ssize_t n_signals = x.shape[0], n_samples = x.shape[1], n_sections = sos.shape[0]
    cdef Py_ssize_t i, n, s
    cdef double x_cur, x_new
    if zi.shape[0] != n_signals or zi.shape[1] != n_sections or zi.shape[2] != 2 or sos.shape[1] != 6:
        raise ValueError("sosfilt: sos (sections, 6), x (signals, samples), zi (signals, sections, 2)")
    with nogil:
        for i in range(n_signals):
            for n in range(n_samples):
                x_cur = x[i, n]
                for s in range(n_sections):
                    x_new = sos[s, 0] * x_cur + zi[i, s, 0]
                    zi[i, s, 0] = sos[s, 1] * x_cur - sos[s, 4] * x_new + zi[i, s, 1]
                    zi[i, s, 1] = sos[s, 2] * x_cur - sos[s, 5] * x_new
                    x_cur = x_new
                x[i, n] = x_cur

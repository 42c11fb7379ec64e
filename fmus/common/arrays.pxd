# cython: language_level=3
"""The kernels' arrays: a contiguous float64 or int64 array's memory through the buffer protocol,
compiled into each kernel module that cimports it (``from common.arrays cimport ...``:
fmus/common/cython_kernels.py's rules).

Why not typed memoryviews: acquiring one costs about 0.2 us per array and call (measured on the
plant's step, 5 arrays: 2.2 us a call with memoryviews, 1.2 us with these; numba's AOT 1.8 us),
and the kernels run once per communication step. A kernel takes each array with
:func:`acquire` (checked: dimensions, item kind, C-contiguity, at least ``n`` items in its last
dimension; an input array with strides is read from a contiguous copy, an output must be
contiguous) and gives every acquired one back with ``PyBuffer_Release`` in a ``finally``."""
from cpython.buffer cimport (PyBUF_C_CONTIGUOUS, PyBUF_FORMAT, PyBUF_WRITABLE, PyBuffer_Release,
                             PyObject_GetBuffer)


cdef inline int acquire(object array, Py_buffer* view, int ndim, bint writable, bint integer, Py_ssize_t n,
                        str name) except -1:
    """``view``: the memory of ``array``, a contiguous array of ``ndim`` dimensions of float64 (or
    int64 if ``integer``), ``writable`` if asked, with at least ``n`` items in its last
    dimension; raises TypeError or ValueError naming ``name`` otherwise (then nothing is held)."""
    try:
        PyObject_GetBuffer(array, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (PyBUF_WRITABLE if writable else 0))
    except (BufferError, ValueError, TypeError) as exc:
        if writable or not hasattr(array, "__array__"):
            raise TypeError(f"{name}: a C-contiguous{' writable' if writable else ''} array is needed ({exc})") from None
        import numpy                          # an input with strides: read from a contiguous copy
        PyObject_GetBuffer(numpy.ascontiguousarray(array), view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT)
    cdef const char* code = view.format
    if code[0] != 0 and code[1] != 0 and code[0] in b"@=<":
        code += 1
    cdef bint kind = code[0] != 0 and code[1] == 0 and (code[0] in (b"lq" if integer else b"d"))
    if view.ndim != ndim or view.itemsize != 8 or not kind:
        PyBuffer_Release(view)
        raise TypeError(f"{name}: a {ndim}-dimensional array of {'int64' if integer else 'float64'} is needed")
    if view.shape[ndim - 1] < n:
        PyBuffer_Release(view)
        raise ValueError(f"{name}: at least {n} values are needed, not {view.shape[ndim - 1]}")
    return 0

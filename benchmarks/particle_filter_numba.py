"""Does numba pay for the particle filter? (issue 16: measure and choose.) The bootstrap
proposal's likelihood of 10,000 particles (arm torque, eq. 11; spring inversion by Newton,
eq. 16; accelerometer, eqs. 17-19; ``nu^T R^-1 nu``) as one compiled loop over the particles,
against the filter's numpy code (``BatchMeasurementModel.deflection`` and ``h``).

Prints the compile time and the cost of one evaluation of each, and their largest relative
difference. Measured (numba 0.68.1, not a dependency of the project: installed with
``pip install --target DIR numba``, the numpy it brings along removed from ``DIR``, and ``DIR``
put on ``PYTHONPATH`` for this script only):
numpy 2.3-2.4 ms, numba 2.0-2.2 ms (1.1-1.2x), 0.5-0.7 s to compile in each process (no cache
here); the two agree to 3.6e-12 relative (presumably numpy's SIMD sines and tanh and libm's
differ in the last bits, amplified where r (q + D) - y cancels). About
eleven sines, cosines and tanh per particle dominate, and numpy evaluates them with SIMD,
the compiled loop one by one. Not worth a dependency.

Run: ``PYTHONPATH=.:DIR .venv/bin/python benchmarks/particle_filter_numba.py``.
"""
from __future__ import annotations

import math
import sys
import time
import timeit
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from estimators_2012 import Q0, signals  # noqa: E402

from fmus.estimators import particle_filter_model as pm  # noqa: E402


def _loglik(X, y, a, c, e, g1, g2, g, l1, v0, v1, Sv0, Sv1, r, k_hi, k_soft, delta, r_inv, out):
    """``nu^T R^-1 nu`` of each particle, the same arithmetic as the numpy code."""
    for n in range(X.shape[0]):
        q1, q2, dq1, dq2, a1, a2 = X[n, 0], X[n, 1], X[n, 2], X[n, 3], X[n, 4], X[n, 5]
        s2, c2 = math.sin(q2), math.cos(q2)
        b, bd = -e * s2, -e * c2
        gc = g2 * math.cos(q1 + q2)
        tau = ((a + 2 * b) * a1 + (c + b) * a2 + bd * (2 * dq1 * dq2 + dq2 * dq2) - g1 * math.sin(q1) - gc,
               (c + b) * a1 + c * a2 - bd * dq1 * dq1 - gc)
        s = 0.0
        for i in range(2):
            t, kh, ks, dl = tau[i], k_hi[i], k_soft[i], delta[i]
            D = (t + math.copysign(ks * dl * math.tanh(abs(t) / (kh * dl)), t)) / kh
            tol = 1e-12 * max(1.0, abs(t))
            for _ in range(50):
                th = math.tanh(D / dl)
                f = kh * D - ks * dl * th - t
                if abs(f) <= tol:
                    break
                D = D - f / (kh - ks * (1.0 - th * th))
            nu = y[i] - r[i] * (X[n, i] + D)
            s += nu * nu * r_inv[i]
        phi, dphi, aphi = q1 + q2, dq1 + dq2, a1 + a2
        u2, d2 = -dq1 * dq1, dphi * dphi
        fx = l1 * (c2 * a1 - s2 * u2) + Sv0 * aphi - v0 * d2 - g * math.sin(phi)
        fz = l1 * (s2 * a1 + c2 * u2) + Sv1 * aphi - v1 * d2 + g * math.cos(phi)
        out[n] = s + (y[2] - fx) ** 2 * r_inv[2] + (y[3] - fz) ** 2 * r_inv[3]


def main() -> None:
    try:
        import numba
    except ImportError:
        sys.exit("numba is not installed (see the module docstring)")
    p = pm.ParticleFilterParameters(q_a0=Q0, proposal="prior", n_particles=10000)
    f = pm.ParticleFilterModel(p)
    B = f.batch
    _, _, u, y = signals(30, 1e-2, p)
    for k in range(20):
        f.update(y[k])
        f.predict(u[k], 1e-2)
    X = f.M + np.random.default_rng(0).standard_normal((f.N, f.L.shape[1])) @ f.L.T
    yk = y[20]
    out = np.empty(f.N)
    args = (X, yk, B.a, B.c, B.e, B.g1, B.g2, B.g, B.l1, *map(float, B.v), *map(float, B.Sv), B.r,
            B.k_hi, B.k_soft, B.delta, f.r_inv, out)
    compiled = numba.njit(_loglik)
    t0 = time.perf_counter()
    compiled(*args)
    compile_s = time.perf_counter() - t0

    def numpy_loglik():
        nu = yk - B.h(X, B.deflection(X))
        return (nu * nu) @ f.r_inv

    ref = numpy_loglik()
    t_np = min(timeit.repeat(numpy_loglik, number=20, repeat=5)) / 20
    t_nb = min(timeit.repeat(lambda: compiled(*args), number=20, repeat=5)) / 20
    print(f"numba {numba.__version__}: compile {compile_s:.2f} s; one evaluation of 10,000 particles: "
          f"numpy {t_np * 1e3:.2f} ms, numba {t_nb * 1e3:.2f} ms ({t_np / t_nb:.2f}x); "
          f"largest relative difference {np.max(np.abs(out - ref) / np.abs(ref)):.1e}")


if __name__ == "__main__":
    main()

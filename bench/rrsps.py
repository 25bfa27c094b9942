#!/usr/bin/env python3
"""Python peer of host/benches/rrsps.rs: identify the eight RRSPS parameters (seed 004, eq. 26)
from a samples CSV (theta_a_deg,theta_c_deg,d_mm) with scipy.optimize.least_squares, same model,
same analytic Jacobian, same start (the Table 2 design values).

usage: OMP_NUM_THREADS=1 python3 bench/rrsps.py SAMPLES.csv
Prints the median wall time (ms) of the fit for method='lm' (MINPACK) and method='trf'.
"""
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
try:
    import numpy as np
    from scipy.optimize import least_squares
except ImportError:
    import subprocess
    subprocess.check_call([sys.executable, "-m", "pip", "install", "--quiet", "numpy", "scipy"])
    import numpy as np
    from scipy.optimize import least_squares

NAMES = ["s0_mm", "a0_mm", "theta_a0_deg", "s2_mm", "a2_mm", "theta_c0_deg", "a1_mm", "alpha12_deg"]
DESIGN = np.array([96.310, 352.114, np.radians(-55.0), 80.0, 30.0, np.radians(-161.592), 0.0,
                   np.radians(270.0)])


def model(p, ta, tc):
    """Eq. (8)/(26): d and its Jacobian (columns in NAMES order, angles in radians)."""
    s0, a0, tha0, s2, a2, thc0, a1, al = p
    t1 = ta - tha0 - np.pi / 2
    t2 = tc + thc0
    s1, c1, sn2, c2 = np.sin(t1), np.cos(t1), np.sin(t2), np.cos(t2)
    sa, ca = np.sin(al), np.cos(al)
    u = a1 * c1 + s2 * sa * s1 + a2 * c1 * c2 - a2 * ca * s1 * sn2 - a0
    v = a1 * s1 - s2 * sa * c1 + a2 * s1 * c2 + a2 * ca * c1 * sn2
    w = -s0 + s2 * ca + a2 * sa * sn2
    d = np.sqrt(u * u + v * v + w * w)
    inv = 1.0 / d
    J = np.empty((len(ta), 8))
    J[:, 0] = -w * inv
    J[:, 1] = -u * inv
    J[:, 2] = -(u * (-v) + v * (u + a0)) * inv
    J[:, 3] = (u * sa * s1 - v * sa * c1 + w * ca) * inv
    J[:, 4] = (u * (c1 * c2 - ca * s1 * sn2) + v * (s1 * c2 + ca * c1 * sn2) + w * sa * sn2) * inv
    J[:, 5] = (u * (-a2 * c1 * sn2 - a2 * ca * s1 * c2) + v * (-a2 * s1 * sn2 + a2 * ca * c1 * c2)
               + w * a2 * sa * c2) * inv
    J[:, 6] = (u * c1 + v * s1) * inv
    J[:, 7] = (u * (s2 * ca * s1 + a2 * sa * s1 * sn2) + v * (-s2 * ca * c1 - a2 * sa * c1 * sn2)
               + w * (-s2 * sa + a2 * ca * sn2)) * inv
    return d, J


def main():
    data = np.loadtxt(sys.argv[1], delimiter=",", skiprows=1)
    ta, tc, dm = np.radians(data[:, 0]), np.radians(data[:, 1]), data[:, 2]
    fun = lambda p: model(p, ta, tc)[0] - dm
    jac = lambda p: model(p, ta, tc)[1]
    for method in ("lm", "trf"):
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            r = least_squares(fun, DESIGN, jac=jac, method=method, x_scale="jac",
                              xtol=1e-12, ftol=1e-12, gtol=1e-12)
            times.append((time.perf_counter() - t0) * 1e3)
        times.sort()
        rms = np.sqrt(np.mean(r.fun ** 2)) * 1e3
        vals = np.array(r.x)
        for k in (2, 5, 7):
            vals[k] = np.degrees(vals[k])
        print(f"scipy least_squares {method}: {len(dm)} samples, median {times[len(times)//2]:.1f} ms "
              f"(min {times[0]:.1f}), nfev {r.nfev}, rms {rms:.3f} um")
        print("  params: " + " ".join(f"{n}={v:.6f}" for n, v in zip(NAMES, vals)))


if __name__ == "__main__":
    main()

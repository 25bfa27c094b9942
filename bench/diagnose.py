#!/usr/bin/env python3
"""Python peer of host/benches/diagnose.rs: the same circular-test diagnosis in plain numpy/scipy.

Same steps as host/src/diagnose.rs: baseline D - |p|; which set-up parameters the path determines
(rank of the columns u_x, u_y, u_z, 1); exact set-up fit D = |p + c| + e
(scipy.optimize.least_squares); the linearised candidate columns (seed 000 eq. 1: u . delta) of
every candidate effect at once as a numpy matrix and their Gram matrix; the isotropic-scale
identifiability test (scale_k -> scale_mismatch_ij); BIC forward selection on the Gram matrix;
exact refit of set-up + selected effects with scipy.optimize.least_squares (method 'lm', analytic
Jacobian); residual harmonics 1..8 against angle. Velocity by central differences, direction held
through standstills, all vectorised.

usage: OMP_NUM_THREADS=1 python3 bench/diagnose.py SAMPLES.csv [x=10,y=10]
Prints the median wall time (ms) over repeated runs (CSV reading not timed) and what it found.
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

RANK_TOL = 1e-7
PAIRS = {"xy": (0, 1), "yz": (1, 2), "zx": (2, 0)}
AX = "xyz"


def rank_and_nulls(g):
    d = np.sqrt(np.maximum(np.diag(g), 0.0))
    dead = d <= 1e-10 * d.max()
    s = np.where(dead, 1.0, d)
    a = g / np.outer(s, s)
    a[dead, :] = 0.0
    a[:, dead] = 0.0
    w, v = np.linalg.eigh(a)
    thr = RANK_TOL ** 2 * w.max()
    return int((w > thr).sum()), v[:, w <= thr]


def independent(g, order):
    kept = []
    for c in order:
        trial = kept + [c]
        r, _ = rank_and_nulls(g[np.ix_(trial, trial)])
        if r == len(trial):
            kept = trial
    return kept


def motion(t, p):
    v = np.empty_like(p)
    v[1:-1] = (p[2:] - p[:-2]) / (t[2:] - t[:-2])[:, None]
    v[0] = (p[1] - p[0]) / (t[1] - t[0])
    v[-1] = (p[-1] - p[-2]) / (t[-1] - t[-2])
    eps = np.abs(v).max() * 1e-9
    sgn = np.where(v > eps, 1.0, np.where(v < -eps, -1.0, 0.0))
    dirs = np.zeros_like(v)
    for k in range(3):
        s = sgn[:, k]
        idx = np.where(s != 0, np.arange(len(s)), 0)
        np.maximum.accumulate(idx, out=idx)
        held = s[idx]
        nz = np.flatnonzero(s)
        if len(nz):
            held[: nz[0]] = s[nz[0]]
        dirs[:, k] = held
    return v, dirs


def effect_columns(name, p, v, dirs, u, pitch):
    """Radial columns (um of D per unit parameter), the same units as host/src/model.rs."""
    kind, _, tail = name.rpartition("_")
    if name == "setup_offset":
        return [u[:, 0], u[:, 1], u[:, 2]]
    if name == "length_offset":
        return [np.ones(len(p))]
    if kind == "scale":
        k = AX.index(tail)
        return [1e-3 * u[:, k] * p[:, k]]
    if kind == "scale_mismatch":
        i, j = PAIRS[tail]
        return [0.5e-3 * (u[:, i] * p[:, i] - u[:, j] * p[:, j])]
    if kind == "scale2":
        k = AX.index(tail)
        return [1e-6 * u[:, k] * p[:, k] ** 2]
    if kind == "backlash":
        k = AX.index(tail)
        return [0.5 * u[:, k] * dirs[:, k]]
    if kind in ("cyclic", "interference"):
        k = AX.index(tail)
        w = 2 * np.pi * p[:, k] / pitch[k]
        g = u[:, k] if kind == "cyclic" else u[:, k] * v[:, k]
        return [g * np.sin(w), g * np.cos(w)]
    if kind == "squareness":
        i, j = PAIRS[tail]
        return [1e-3 * u[:, i] * p[:, j]]
    if kind == "servo_mismatch":
        i, j = PAIRS[tail]
        return [0.5 * (u[:, j] * v[:, j] - u[:, i] * v[:, i])]
    raise ValueError(name)


def delta_columns(name, p, v, dirs, pitch):
    """Position change (mm) per unit parameter, shape (n_params, m, 3), for the exact model."""
    m = len(p)
    kind, _, tail = name.rpartition("_")
    z = lambda: np.zeros((m, 3))  # noqa: E731
    if name == "setup_offset":
        out = []
        for k in range(3):
            c = z()
            c[:, k] = 1e-3
            out.append(c)
        return out
    if name == "length_offset":
        return []
    c = z()
    if kind == "scale":
        k = AX.index(tail)
        c[:, k] = 1e-6 * p[:, k]
    elif kind == "scale_mismatch":
        i, j = PAIRS[tail]
        c[:, i] = 0.5e-6 * p[:, i]
        c[:, j] = -0.5e-6 * p[:, j]
    elif kind == "scale2":
        k = AX.index(tail)
        c[:, k] = 1e-9 * p[:, k] ** 2
    elif kind == "backlash":
        k = AX.index(tail)
        c[:, k] = 0.5e-3 * dirs[:, k]
    elif kind in ("cyclic", "interference"):
        k = AX.index(tail)
        w = 2 * np.pi * p[:, k] / pitch[k]
        g = 1e-3 if kind == "cyclic" else 1e-3 * v[:, k]
        c2 = z()
        c[:, k] = g * np.sin(w)
        c2[:, k] = g * np.cos(w)
        return [c, c2]
    elif kind == "squareness":
        i, j = PAIRS[tail]
        c[:, i] = 1e-6 * p[:, j]
    elif kind == "servo_mismatch":
        i, j = PAIRS[tail]
        c[:, i] = -0.5e-3 * v[:, i]
        c[:, j] = 0.5e-3 * v[:, j]
    return [c]


def candidates(p, pitch):
    moving = [k for k in range(3) if np.ptp(p[:, k]) > 0]
    c = [f"scale_{AX[k]}" for k in moving]
    c += [f"scale_mismatch_{n}" for n, (i, j) in PAIRS.items() if i in moving and j in moving]
    for k in moving:
        c += [f"scale2_{AX[k]}", f"backlash_{AX[k]}"]
        if pitch[k]:
            c += [f"cyclic_{AX[k]}", f"interference_{AX[k]}"]
    for n, (i, j) in PAIRS.items():
        if i in moving and j in moving:
            c += [f"squareness_{n}", f"servo_mismatch_{n}"]
    return c


def diagnose(t, p, d, pitch):
    m = len(d)
    v, dirs = motion(t, p)
    r0 = np.linalg.norm(p, axis=1)
    u = p / r0[:, None]
    base = 1e3 * (d - r0)
    out = {"baseline_rms_um": np.sqrt(np.mean(base**2)), "baseline_pv_um": np.ptp(base)}
    # Set-up structure and exact set-up fit.
    sx = np.column_stack(effect_columns("setup_offset", p, v, dirs, u, pitch) + [np.ones(m)])
    free = independent(sx.T @ sx, [3, 0, 1, 2])

    def setup_res(q):
        full = np.zeros(4)
        full[free] = q
        pq = p + 1e-3 * full[:3]
        return 1e3 * (np.linalg.norm(pq, axis=1) - d) + full[3]

    def setup_jac(q):
        full = np.zeros(4)
        full[free] = q
        pq = p + 1e-3 * full[:3]
        uq = pq / np.linalg.norm(pq, axis=1)[:, None]
        return np.column_stack([uq, np.ones(m)])[:, free]

    fs = least_squares(setup_res, np.zeros(len(free)), jac=setup_jac, method="lm")
    setup = np.zeros(4)
    setup[free] = fs.x
    y = -setup_res(fs.x)
    # One matrix of all candidate columns, Gram, identifiability.
    names = ["setup_offset", "length_offset"] + candidates(p, pitch)
    cols, owner = [], []
    for e, n in enumerate(names):
        for c in effect_columns(n, p, v, dirs, u, pitch):
            cols.append(c)
            owner.append(e)
    x = np.column_stack(cols + [y])
    gram = x.T @ x
    ycol = gram.shape[0] - 1
    owner = np.array(owner)
    cols_of = lambda e: list(np.flatnonzero(owner == e))  # noqa: E731
    scale_cols = [cols_of(e)[0] for e, n in enumerate(names) if n.startswith("scale_") and
                  n[6:] in AX]
    iso = len(independent(gram, free + scale_cols)) < len(free + scale_cols)
    cand = [e for e, n in enumerate(names) if e >= 2 and not (
        (n.startswith("scale_mismatch") and not iso) or
        (n.startswith("scale_") and n[6:] in AX and iso))]
    # BIC forward selection on the Gram.
    yy = gram[ycol, ycol]

    def ssr_of(idx):
        g = gram[np.ix_(idx, idx)]
        r, _ = rank_and_nulls(g)
        if r < len(idx):
            return None
        b = gram[idx, ycol]
        return yy - b @ np.linalg.solve(g, b)

    bic = lambda s, k: m * np.log(max(s, 1e-300) / m) + k * np.log(m)  # noqa: E731
    current = list(free)
    ssr = ssr_of(current)
    best_bic = bic(ssr, len(current))
    chosen = []
    remaining = list(cand)
    while remaining and len(chosen) < 8:
        trials = []
        for e in list(remaining):
            s = ssr_of(current + cols_of(e))
            if s is None:
                remaining.remove(e)
                continue
            trials.append((bic(s, len(current) + len(cols_of(e))), e, s))
        if not trials:
            break
        b, e, s = min(trials)
        if b >= best_bic:
            break
        current += cols_of(e)
        chosen.append(e)
        best_bic, ssr = b, s
        remaining.remove(e)
    # Exact refit of set-up + chosen effects (analytic Jacobian, MINPACK lm).
    sel = [names[e] for e in chosen]
    dcols = [c for n in sel for c in delta_columns(n, p, v, dirs, pitch)]
    dstack = np.stack(dcols) if dcols else np.zeros((0, m, 3))

    def split(q):
        full = np.zeros(4)
        full[free] = q[: len(free)]
        return full, q[len(free):]

    def res(q):
        full, th = split(q)
        pq = p + 1e-3 * full[:3] + np.tensordot(th, dstack, axes=1)
        return 1e3 * (np.linalg.norm(pq, axis=1) - d) + full[3]

    def jac(q):
        full, th = split(q)
        pq = p + 1e-3 * full[:3] + np.tensordot(th, dstack, axes=1)
        uq = pq / np.linalg.norm(pq, axis=1)[:, None]
        js = np.column_stack([uq, np.ones(m)])[:, free]
        je = 1e3 * np.einsum("kmj,mj->mk", dstack, uq)
        return np.column_stack([js, je])

    q0 = np.concatenate([setup[free], np.zeros(len(dcols))])
    sol = least_squares(res, q0, jac=jac, method="lm")
    resid = res(sol.x)
    full, th = split(sol.x)
    out["final_rms_um"] = np.sqrt(np.mean(resid**2))
    out["setup_um"] = full
    vals, at = {}, 0
    for n in sel:
        k = len(delta_columns(n, p[:1], v[:1], dirs[:1], pitch))
        vals[n] = float(np.hypot(*th[at:at + 2])) if k == 2 else float(th[at])
        at += k
    out["effects"] = vals
    # Residual harmonics 1..8 against angle in the xy plane.
    ang = np.arctan2(p[:, 1], p[:, 0])
    h = np.column_stack([np.ones(m)] + [f(k * ang) for k in range(1, 9) for f in (np.cos, np.sin)])
    coef = np.linalg.lstsq(h, resid, rcond=None)[0]
    out["harmonics_um"] = np.hypot(coef[1::2], coef[2::2])
    return out


def main():
    path = sys.argv[1]
    pitch = [None, None, None]
    spec = sys.argv[2] if len(sys.argv) > 2 else "x=10,y=10"
    for part in spec.split(","):
        k, val = part.split("=")
        pitch[AX.index(k)] = float(val)
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    t, p, d = data[:, 0], data[:, 1:4], data[:, 4]
    times, out = [], None
    for _ in range(11):
        t0 = time.perf_counter()
        out = diagnose(t, p, d, pitch)
        times.append((time.perf_counter() - t0) * 1e3)
    times.sort()
    print(f"python diagnose {len(d)} samples: median {times[len(times) // 2]:.3f} ms, "
          f"min {times[0]:.3f} ms (11 runs)")
    found = " ".join(f"{k}={v:.3f}" for k, v in out["effects"].items())
    print(f"  found: setup_offset={np.linalg.norm(out['setup_um'][:3]):.3f} "
          f"length_offset={out['setup_um'][3]:.3f} {found}")
    print(f"  final rms {out['final_rms_um']:.4f} um (baseline {out['baseline_rms_um']:.3f})")


if __name__ == "__main__":
    main()

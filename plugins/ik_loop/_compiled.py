"""The compiled (numba) step of the matrix-field planner; imported only when numba is installed.

Module-level functions, so that numba's on-disk cache (``cache=True``) works: each new process
loads the compiled step instead of compiling it again (a closure would be recompiled every time).
The numpy reference and the documentation of the arguments are in :mod:`.fast`.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True)
def chol(A, n):  # type: ignore[no-untyped-def]
    L = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                L[i, i] = math.sqrt(s) if s > 0.0 else 1e-150
            else:
                L[i, j] = s / L[j, j]
    return L


@nb.njit(cache=True)
def chol_solve(L, b, n):  # type: ignore[no-untyped-def]
    y = np.empty(n)
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= L[k, i] * y[k]
        y[i] = s / L[i, i]
    return y


@nb.njit(cache=True)
def orient(R, Rg):  # type: ignore[no-untyped-def]
    d = Rg @ R.T
    a, b, c = d[0, 0], d[0, 1], d[0, 2]
    d_, e, f = d[1, 0], d[1, 1], d[1, 2]
    g, h, i = d[2, 0], d[2, 1], d[2, 2]
    tr = a + e + i
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        w, x, y, z = 0.25 * s, (h - f) / s, (c - g) / s, (d_ - b) / s
    elif a > e and a > i:
        s = 2.0 * math.sqrt(1.0 + a - e - i)
        w, x, y, z = (h - f) / s, 0.25 * s, (b + d_) / s, (c + g) / s
    elif e > i:
        s = 2.0 * math.sqrt(1.0 + e - a - i)
        w, x, y, z = (c - g) / s, (b + d_) / s, 0.25 * s, (f + h) / s
    else:
        s = 2.0 * math.sqrt(1.0 + i - a - e)
        w, x, y, z = (d_ - b) / s, (c + g) / s, (f + h) / s, 0.25 * s
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    out = np.empty(3)
    vn = math.sqrt(x * x + y * y + z * z)
    if vn < 1e-12:
        out[0], out[1], out[2] = 2.0 * x, 2.0 * y, 2.0 * z
    else:
        k = 2.0 * math.atan2(vn, w) / vn
        out[0], out[1], out[2] = x * k, y * k, z * k
    return out


@nb.njit(cache=True)
def step(
    S,
    J,
    p,
    R,
    p_goal,
    R_goal,
    q,
    lower,
    upper,
    qd_max,
    points,
    F,
    support,
    descendants,  # type: ignore[no-untyped-def]
    tool,
    prm,
    qd_out,
    diag,
):
    v_max, k_sig, k_p, k_w, w_max = (
        prm.speed_max,
        prm.sigmoid_gain,
        prm.position_gain,
        prm.orientation_gain,
        prm.angular_speed_max,
    )
    k_m, k_c, k_s, s_min = prm.manipulability_gain, prm.mid_joint_gain, prm.slowdown_gain, prm.slowdown_min
    lam_max, m0, dt = prm.damping_factor, prm.manipulability_threshold, prm.dt
    k_tool, fade_d = prm.tool_repulsion_gain, prm.tool_fade_distance
    n = q.shape[0]
    N = points.shape[0]
    # attraction
    v = np.zeros(6)
    e = p_goal - p
    err_p = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    if err_p > 1e-15:
        sc = k_p * v_max * math.atan(k_sig * err_p) / (0.5 * math.pi * err_p)
        for a in range(3):
            v[a] = e[a] * sc
    om = orient(R, R_goal)
    err_r = math.sqrt(om[0] * om[0] + om[1] * om[1] + om[2] * om[2])
    wn = k_w * err_r
    sc = k_w * (w_max / wn if wn > w_max else 1.0)
    for a in range(3):
        v[3 + a] = om[a] * sc
    # mid-joint
    x = np.empty(n)
    for k in range(n):
        span = upper[k] - lower[k]
        x[k] = -k_c * (q[k] - 0.5 * (lower[k] + upper[k])) / (span * span)
    # manipulability and its gradient, from S
    A = S @ S.T
    L = chol(A, 6)
    m = 1.0
    for i in range(6):
        m *= L[i, i]
    m = abs(m)
    if k_m > 0.0:
        for i in range(6):
            A[i, i] += 1e-12
        L2 = chol(A, 6)
        X = np.empty((6, n))
        for i in range(n):
            X[:, i] = chol_solve(L2, np.ascontiguousarray(S[:, i]), 6)
        a_ = np.zeros((3, n))
        b_ = np.zeros((3, n))
        for i in range(n):
            v0, v1, v2 = S[0, i], S[1, i], S[2, i]
            w0, w1, w2 = S[3, i], S[4, i], S[5, i]
            xv0, xv1, xv2 = X[0, i], X[1, i], X[2, i]
            xw0, xw1, xw2 = X[3, i], X[4, i], X[5, i]
            a_[0, i] = v1 * xv2 - v2 * xv1 + w1 * xw2 - w2 * xw1
            a_[1, i] = v2 * xv0 - v0 * xv2 + w2 * xw0 - w0 * xw2
            a_[2, i] = v0 * xv1 - v1 * xv0 + w0 * xw1 - w1 * xw0
            b_[0, i] = w1 * xv2 - w2 * xv1
            b_[1, i] = w2 * xv0 - w0 * xv2
            b_[2, i] = w0 * xv1 - w1 * xv0
        for k in range(n):
            g = 0.0
            for i in range(n):
                if descendants[k, i] != 0.0:
                    for c in range(3):
                        g += S[3 + c, k] * a_[c, i] + S[c, k] * b_[c, i]
            x[k] += k_m * m * g
    # repulsion
    rep2 = 0.0
    best, tool_i = -1.0, -1
    for i in range(N):
        f2 = F[i, 0] * F[i, 0] + F[i, 1] * F[i, 1] + F[i, 2] * F[i, 2]
        if f2 > rep2:
            rep2 = f2
    rep = math.sqrt(rep2)
    if rep > 0.0:
        for i in range(N):
            f0, f1, f2_ = F[i, 0], F[i, 1], F[i, 2]
            if f0 == 0.0 and f1 == 0.0 and f2_ == 0.0:
                continue
            p0, p1, p2 = points[i, 0], points[i, 1], points[i, 2]
            t0, t1, t2 = p1 * f2_ - p2 * f1, p2 * f0 - p0 * f2_, p0 * f1 - p1 * f0
            for k in range(n):
                if support[i, k] != 0.0:
                    x[k] += S[0, k] * f0 + S[1, k] * f1 + S[2, k] * f2_ + S[3, k] * t0 + S[4, k] * t1 + S[5, k] * t2
        if k_tool > 0.0:
            for t in range(tool.shape[0]):
                i = tool[t]
                f2 = F[i, 0] * F[i, 0] + F[i, 1] * F[i, 1] + F[i, 2] * F[i, 2]
                if f2 > best:
                    best, tool_i = f2, i
            if tool_i >= 0:
                fade = min(1.0, err_p / fade_d)
                for a in range(3):
                    v[a] += k_tool * fade * F[tool_i, a]
    # damped least squares and null space, one factorisation
    if prm.adaptive != 0.0:
        lam = 0.0 if m >= m0 else lam_max * math.sqrt(1.0 - (m / m0) ** 2)
    else:
        lam = lam_max
    B = J @ J.T
    for i in range(6):
        B[i, i] += lam * lam + 1e-18
    LB = chol(B, 6)
    y1 = chol_solve(LB, v, 6)
    y2 = chol_solve(LB, J @ x, 6)
    s = max(s_min, 1.0 / (1.0 + k_s * rep)) if k_s > 0.0 else 1.0
    ratio = 0.0
    for k in range(n):
        a1 = 0.0
        a2 = 0.0
        for r in range(6):
            a1 += J[r, k] * y1[r]
            a2 += J[r, k] * y2[r]
        qd_out[k] = s * a1 + x[k] - a2
        rr = abs(qd_out[k]) / qd_max[k]
        if rr > ratio:
            ratio = rr
    c = 1.0 / ratio if ratio > 1.0 else 1.0
    for k in range(n):
        val = qd_out[k] * c
        lo = (lower[k] - q[k]) / dt
        hi = (upper[k] - q[k]) / dt
        qd_out[k] = min(max(val, lo), hi)
    diag[0], diag[1], diag[2], diag[3], diag[4], diag[5] = err_p, err_r, rep, m, s, lam


@nb.njit(cache=True)
def positions(Rs, ts, joint, local, out):  # type: ignore[no-untyped-def]
    for i in range(joint.shape[0]):
        j = joint[i]
        for a in range(3):
            out[i, a] = Rs[j, a, 0] * local[i, 0] + Rs[j, a, 1] * local[i, 1] + Rs[j, a, 2] * local[i, 2] + ts[j, a]

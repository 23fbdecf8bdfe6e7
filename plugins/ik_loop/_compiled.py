"""The compiled (numba) step of the IK loop, its kinematics (control points, the goal frame's
Jacobian) and its integration; imported only when numba is installed.

Module-level functions, so that numba's on-disk cache (``cache=True``) works: each new process
loads the compiled step instead of compiling it again (a closure would be recompiled every time).
The numpy reference and the documentation of the arguments are in :mod:`.fast`.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True)
def chol(A, L):  # type: ignore[no-untyped-def]
    """Lower Cholesky factor of the 6x6 ``A`` into ``L`` (its upper triangle is not written)."""
    for i in range(6):
        for j in range(i + 1):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                L[i, i] = math.sqrt(s) if s > 0.0 else 1e-150
            else:
                L[i, j] = s / L[j, j]


@nb.njit(cache=True)
def chol_solve(L, Y):  # type: ignore[no-untyped-def]
    """``Y <- (L L^T)^-1 Y`` for ``Y`` (6, m), in place: forward then back substitution, the
    columns side by side (independent chains of divisions, which the CPU overlaps)."""
    m = Y.shape[1]
    for i in range(6):
        for c in range(m):
            s = Y[i, c]
            for k in range(i):
                s -= L[i, k] * Y[k, c]
            Y[i, c] = s / L[i, i]
    for i in range(5, -1, -1):
        for c in range(m):
            s = Y[i, c]
            for k in range(i + 1, 6):
                s -= L[k, i] * Y[k, c]
            Y[i, c] = s / L[i, i]


@nb.njit(cache=True)
def gram(M, out):  # type: ignore[no-untyped-def]
    """``out = M M^T`` (6x6) for ``M`` (6, n)."""
    for i in range(6):
        for j in range(i + 1):
            s = 0.0
            for k in range(M.shape[1]):
                s += M[i, k] * M[j, k]
            out[i, j] = s
            out[j, i] = s


@nb.njit(cache=True)
def orient(R, Rg):  # type: ignore[no-untyped-def]
    """The rotation vector ``log(Rg R^T)`` through a unit quaternion (see ``tasks.orientation_error``)."""
    d = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            d[r, c] = Rg[r, 0] * R[c, 0] + Rg[r, 1] * R[c, 1] + Rg[r, 2] * R[c, 2]
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
    vn = math.sqrt(x * x + y * y + z * z)
    if vn < 1e-12:
        return 2.0 * x, 2.0 * y, 2.0 * z
    k = 2.0 * math.atan2(vn, w) / vn
    return x * k, y * k, z * k


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
    n = q.shape[0]
    N = points.shape[0]
    A = np.empty((6, 6))  # S S^T, then J J^T + damping
    L = np.empty((6, 6))  # its Cholesky factor
    # attraction
    v = np.zeros(6)
    e0, e1, e2 = p_goal[0] - p[0], p_goal[1] - p[1], p_goal[2] - p[2]
    err_p = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    if err_p > 1e-15:
        sc = prm.position_gain * prm.speed_max * math.atan(prm.sigmoid_gain * err_p) / (0.5 * math.pi * err_p)
        v[0], v[1], v[2] = e0 * sc, e1 * sc, e2 * sc
    o0, o1, o2 = orient(R, R_goal)
    err_r = math.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
    k_w = prm.orientation_gain
    wn = k_w * err_r
    sc = k_w * (prm.angular_speed_max / wn if wn > prm.angular_speed_max else 1.0)
    v[3], v[4], v[5] = o0 * sc, o1 * sc, o2 * sc
    # mid-joint
    x = np.empty(n)
    for k in range(n):
        span = upper[k] - lower[k]
        x[k] = -prm.mid_joint_gain * (q[k] - 0.5 * (lower[k] + upper[k])) / (span * span)
    # manipulability and its gradient, from S
    gram(S, A)
    chol(A, L)
    m = 1.0
    for i in range(6):
        m *= L[i, i]
    m = abs(m)
    if prm.manipulability_gain > 0.0:
        for i in range(6):
            A[i, i] += 1e-12
        chol(A, L)
        X = np.empty((6, n))  # (S S^T)^-1 S
        for r in range(6):
            for i in range(n):
                X[r, i] = S[r, i]
        chol_solve(L, X)
        ab = np.empty((6, n))  # a_i = v_i x Xv_i + w_i x Xw_i, b_i = w_i x Xv_i
        for i in range(n):
            v0, v1, v2 = S[0, i], S[1, i], S[2, i]
            w0, w1, w2 = S[3, i], S[4, i], S[5, i]
            xv0, xv1, xv2 = X[0, i], X[1, i], X[2, i]
            xw0, xw1, xw2 = X[3, i], X[4, i], X[5, i]
            ab[0, i] = v1 * xv2 - v2 * xv1 + w1 * xw2 - w2 * xw1
            ab[1, i] = v2 * xv0 - v0 * xv2 + w2 * xw0 - w0 * xw2
            ab[2, i] = v0 * xv1 - v1 * xv0 + w0 * xw1 - w1 * xw0
            ab[3, i] = w1 * xv2 - w2 * xv1
            ab[4, i] = w2 * xv0 - w0 * xv2
            ab[5, i] = w0 * xv1 - w1 * xv0
        for k in range(n):
            g = 0.0
            for i in range(n):
                if descendants[k, i] != 0.0:
                    for c in range(3):
                        g += S[3 + c, k] * ab[c, i] + S[c, k] * ab[3 + c, i]
            x[k] += prm.manipulability_gain * m * g
    # repulsion
    rep2 = 0.0
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
        if prm.tool_repulsion_gain > 0.0:
            best, tool_i = -1.0, -1
            for t in range(tool.shape[0]):
                i = tool[t]
                f2 = F[i, 0] * F[i, 0] + F[i, 1] * F[i, 1] + F[i, 2] * F[i, 2]
                if f2 > best:
                    best, tool_i = f2, i
            if tool_i >= 0:
                fade = min(1.0, err_p / prm.tool_fade_distance)
                for a in range(3):
                    v[a] += prm.tool_repulsion_gain * fade * F[tool_i, a]
    # damped least squares and null space, one factorisation
    lam = prm.damping_factor
    if prm.adaptive != 0.0:
        m0 = prm.manipulability_threshold
        lam = 0.0 if m >= m0 else lam * math.sqrt(1.0 - (m / m0) ** 2)
    s = max(prm.slowdown_min, 1.0 / (1.0 + prm.slowdown_gain * rep)) if prm.slowdown_gain > 0.0 else 1.0
    gram(J, A)
    for i in range(6):
        A[i, i] += lam * lam + 1e-18
    chol(A, L)
    Y = np.empty((6, 2))  # (J J^T + lam^2)^-1 [v, J x]
    for r in range(6):
        t = 0.0
        for k in range(n):
            t += J[r, k] * x[k]
        Y[r, 0] = v[r]
        Y[r, 1] = t
    chol_solve(L, Y)
    for k in range(n):
        a1 = 0.0
        a2 = 0.0
        for r in range(6):
            a1 += J[r, k] * Y[r, 0]
            a2 += J[r, k] * Y[r, 1]
        qd_out[k] = s * a1 + x[k] - a2
    if prm.priority != 0.0:
        push(S, J, lam, points, F, support, err_p, prm, qd_out)
    ratio = 0.0
    for k in range(n):
        rr = abs(qd_out[k]) / qd_max[k]
        if rr > ratio:
            ratio = rr
    c = 1.0 / ratio if ratio > 1.0 else 1.0
    dt = prm.dt
    for k in range(n):
        val = qd_out[k] * c
        lo = (lower[k] - q[k]) / dt
        hi = (upper[k] - q[k]) / dt
        qd_out[k] = min(max(val, lo), hi)
    diag[0], diag[1], diag[2], diag[3], diag[4], diag[5] = err_p, err_r, rep, m, s, lam


@nb.njit(cache=True)
def push(S, J, lam, points, F, support, err_p, prm, qd):  # type: ignore[no-untyped-def]
    """The ``"priority"`` hierarchy's correction added to the null-space step ``qd`` in place
    (``tasks.push_correction``): the rows of the points with a non-zero activation and the
    weighted pose rows accumulated into the n x n normal matrix row by row (no stack formed),
    ``mu = lam^2 + (1 mm)^2``, one Cholesky factorisation."""
    n = qd.shape[0]
    near = min(1.0, err_p / prm.priority_fade_distance)
    if not near > 0.0:
        return
    span = prm.priority_full - prm.priority_onset
    H = np.empty((n, n))  # lower triangle of A^T A + mu I
    g = np.zeros(n)  # A^T b
    row = np.empty(n)
    active = False
    for i in range(points.shape[0]):
        f0, f1, f2 = F[i, 0], F[i, 1], F[i, 2]
        mag = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
        u = min(1.0, max(0.0, (mag / prm.speed_max - prm.priority_onset) / span))
        a = near * (u * u * (3.0 - 2.0 * u))
        if not a > 0.0:
            continue
        if not active:  # the pose rows, once
            active = True
            for k in range(n):
                for c in range(k + 1):
                    h = 0.0
                    for r in range(6):
                        h += (1.0 if r < 3 else prm.orientation_weight) * J[r, k] * J[r, c]
                    H[k, c] = h
        n0, n1, n2 = f0 / mag, f1 / mag, f2 / mag
        p0, p1, p2 = points[i, 0], points[i, 1], points[i, 2]
        t0, t1, t2 = p1 * n2 - p2 * n1, p2 * n0 - p0 * n2, p0 * n1 - p1 * n0
        speed = 0.0  # n_i^T J_i qd
        for k in range(n):
            row[k] = support[i, k] * (
                S[0, k] * n0 + S[1, k] * n1 + S[2, k] * n2 + S[3, k] * t0 + S[4, k] * t1 + S[5, k] * t2
            )
            speed += row[k] * qd[k]
        w = prm.priority_weight * a
        wb = w * a * max(0.0, mag - speed)
        for k in range(n):
            g[k] += row[k] * wb
            wr = w * row[k]
            for c in range(k + 1):
                H[k, c] += wr * row[c]
    if not active:
        return
    mu = lam * lam + 1e-6  # tasks.PRIORITY_FLOOR2
    for k in range(n):
        H[k, k] += mu
    # H = L L^T in place (lower triangle), then the two triangular solves on g
    for i in range(n):
        for j in range(i + 1):
            h = H[i, j]
            for k in range(j):
                h -= H[i, k] * H[j, k]
            if i == j:
                H[i, i] = math.sqrt(h) if h > 0.0 else 1e-150
            else:
                H[i, j] = h / H[j, j]
    for i in range(n):
        h = g[i]
        for k in range(i):
            h -= H[i, k] * g[k]
        g[i] = h / H[i, i]
    for i in range(n - 1, -1, -1):
        h = g[i]
        for k in range(i + 1, n):
            h -= H[k, i] * g[k]
        g[i] = h / H[i, i]
    for k in range(n):
        qd[k] += g[k]


@nb.njit(cache=True)
def kinematics(Rs, ts, joint, local, S, p, frame_cols, points, J):  # type: ignore[no-untyped-def]
    """Control-point positions ``points[i] = Rs[joint[i]] @ local[i] + ts[joint[i]]`` and the goal
    frame's Jacobian ``J`` (LOCAL_WORLD_ALIGNED, at ``p``) from the spatial one: column ``k`` is
    ``[S_v,k + S_w,k x p; S_w,k]`` where ``frame_cols[k]`` is non-zero, else 0 (what
    ``pinocchio.getFrameJacobian`` computes)."""
    for i in range(joint.shape[0]):
        j = joint[i]
        for a in range(3):
            points[i, a] = Rs[j, a, 0] * local[i, 0] + Rs[j, a, 1] * local[i, 1] + Rs[j, a, 2] * local[i, 2] + ts[j, a]
    p0, p1, p2 = p[0], p[1], p[2]
    for k in range(S.shape[1]):
        if frame_cols[k] != 0.0:
            w0, w1, w2 = S[3, k], S[4, k], S[5, k]
            J[0, k] = S[0, k] + (w1 * p2 - w2 * p1)
            J[1, k] = S[1, k] + (w2 * p0 - w0 * p2)
            J[2, k] = S[2, k] + (w0 * p1 - w1 * p0)
            J[3, k], J[4, k], J[5, k] = w0, w1, w2
        else:
            for r in range(6):
                J[r, k] = 0.0


@nb.njit(cache=True)
def advance(q, qd, dt, lower, upper, path, k):  # type: ignore[no-untyped-def]
    """``q <- clip(q + qd dt, lower, upper)`` in place (NaN stays NaN, as with ``np.clip``), and
    ``path[k] = q``."""
    for j in range(q.shape[0]):
        val = q[j] + qd[j] * dt
        if val < lower[j]:
            val = lower[j]
        elif val > upper[j]:
            val = upper[j]
        q[j] = val
        path[k, j] = val


@nb.njit(cache=True)
def segment_distance(P, i, j):  # type: ignore[no-untyped-def]
    """Distance [m] between segments ``P[i, 0]-P[i, 1]`` and ``P[j, 0]-P[j, 1]`` (the closest
    points' parameters clamped to the segments, then each recomputed from the other)."""
    d10, d11, d12 = P[i, 1, 0] - P[i, 0, 0], P[i, 1, 1] - P[i, 0, 1], P[i, 1, 2] - P[i, 0, 2]
    d20, d21, d22 = P[j, 1, 0] - P[j, 0, 0], P[j, 1, 1] - P[j, 0, 1], P[j, 1, 2] - P[j, 0, 2]
    r0, r1, r2 = P[i, 0, 0] - P[j, 0, 0], P[i, 0, 1] - P[j, 0, 1], P[i, 0, 2] - P[j, 0, 2]
    a = d10 * d10 + d11 * d11 + d12 * d12
    e = d20 * d20 + d21 * d21 + d22 * d22
    f = d20 * r0 + d21 * r1 + d22 * r2
    s = 0.0
    t = 0.0
    if a <= 1e-18:
        if e > 1e-18:
            t = min(1.0, max(0.0, f / e))
    else:
        c = d10 * r0 + d11 * r1 + d12 * r2
        if e <= 1e-18:
            s = min(1.0, max(0.0, -c / a))
        else:
            b = d10 * d20 + d11 * d21 + d12 * d22
            den = a * e - b * b
            if den > 0.0:
                s = min(1.0, max(0.0, (b * f - c * e) / den))
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = min(1.0, max(0.0, -c / a))
            elif t > 1.0:
                t = 1.0
                s = min(1.0, max(0.0, (b - c) / a))
    x0 = r0 + d10 * s - d20 * t
    x1 = r1 + d11 * s - d21 * t
    x2 = r2 + d12 * s - d22 * t
    return math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)


@nb.njit(cache=True)
def capsules_within(Rs, ts, body_joint, body_segment, radius, reach, first, second, limit, segment, out):  # type: ignore[no-untyped-def]
    """The pairs whose bounding capsules lie closer than ``limit`` [m] (a lower bound of the
    bodies' distance: the segments' distance less both radii, less a micrometre for rounding):
    their indices into ``out``, their number returned. Each body's segment, given in its joint's
    frame (``body_segment[b]``), is placed in the world into ``segment[b]`` on the way. A pair is
    first tested with the spheres around the capsules (centre the segment's middle, radius
    ``reach``: half its length plus the capsule's radius), which end most pairs in a few flops."""
    for b in range(body_joint.shape[0]):
        j = body_joint[b]
        for e in range(2):
            c0, c1, c2 = body_segment[b, e, 0], body_segment[b, e, 1], body_segment[b, e, 2]
            for a in range(3):
                segment[b, e, a] = Rs[j, a, 0] * c0 + Rs[j, a, 1] * c1 + Rs[j, a, 2] * c2 + ts[j, a]
    m = 0
    for k in range(first.shape[0]):
        i, j = first[k], second[k]
        d0 = 0.5 * (segment[i, 0, 0] + segment[i, 1, 0] - segment[j, 0, 0] - segment[j, 1, 0])
        d1 = 0.5 * (segment[i, 0, 1] + segment[i, 1, 1] - segment[j, 0, 1] - segment[j, 1, 1])
        d2 = 0.5 * (segment[i, 0, 2] + segment[i, 1, 2] - segment[j, 0, 2] - segment[j, 1, 2])
        r = limit + reach[i] + reach[j] + 1e-6
        if d0 * d0 + d1 * d1 + d2 * d2 >= r * r:
            continue
        if segment_distance(segment, i, j) - radius[i] - radius[j] - 1e-6 < limit:
            out[m] = k
            m += 1
    return m

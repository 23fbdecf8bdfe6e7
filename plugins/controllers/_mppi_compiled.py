"""The compiled (numba) parts of the ``mppi`` controller: forward kinematics of a chain of
revolute and prismatic joints, the rollouts and their costs, and the distance transform of a
block of an observed grid.

Module-level functions with ``cache=True``, declared in the ``planbench.kernels`` entry-point
group, so that a new process loads them from numba's cache instead of compiling them again.
What each argument means is in :mod:`.mppi`, which builds them.

Joint kinds (``kind``): 0 revolute about ``axis``, 1 prismatic along ``axis``. A joint's
placement in the world is its parent's, then its placement in the parent (``Rp``, ``tp``), then
its motion.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

INF = 1e20

# indices into the weights array ``w`` of :func:`rollout_costs` (kept in step with mppi.WEIGHTS)
W_POS, W_ROT, W_TERM_POS, W_TERM_ROT, W_OBS, OBS_MARGIN, W_COLL = 0, 1, 2, 3, 4, 5, 6
W_SELF, SELF_MARGIN, W_LIMIT, W_SMOOTH, GOAL_FADE, FADE_FLOOR = 7, 8, 9, 10, 11, 12


@nb.njit(cache=True)
def forward(q, parent, kind, axis, Rp, tp, iq, R, t):  # type: ignore[no-untyped-def]
    """World rotations ``R`` (nj, 3, 3) and positions ``t`` (nj, 3) of every joint at ``q``
    (joint 0, the universe, stays where the caller put it: the identity)."""
    nj = parent.shape[0]
    for j in range(1, nj):
        a = parent[j]
        # placement in the world of the joint's frame before its motion: R[a] Rp[j], R[a] tp[j] + t[a]
        for r in range(3):
            s = t[a, r]
            for c in range(3):
                s += R[a, r, c] * tp[j, c]
            t[j, r] = s
            for c in range(3):
                m = 0.0
                for k in range(3):
                    m += R[a, r, k] * Rp[j, k, c]
                R[j, r, c] = m
        x = q[iq[j]]
        ux, uy, uz = axis[j, 0], axis[j, 1], axis[j, 2]
        if kind[j] == 1:  # prismatic: move along the axis, in the joint's frame
            for r in range(3):
                t[j, r] += x * (R[j, r, 0] * ux + R[j, r, 1] * uy + R[j, r, 2] * uz)
            continue
        cs, sn = math.cos(x), math.sin(x)
        v = 1.0 - cs
        # Rodrigues' rotation about the unit axis u
        m00, m01, m02 = cs + ux * ux * v, ux * uy * v - uz * sn, ux * uz * v + uy * sn
        m10, m11, m12 = uy * ux * v + uz * sn, cs + uy * uy * v, uy * uz * v - ux * sn
        m20, m21, m22 = uz * ux * v - uy * sn, uz * uy * v + ux * sn, cs + uz * uz * v
        for r in range(3):
            a0, a1, a2 = R[j, r, 0], R[j, r, 1], R[j, r, 2]
            R[j, r, 0] = a0 * m00 + a1 * m10 + a2 * m20
            R[j, r, 1] = a0 * m01 + a1 * m11 + a2 * m21
            R[j, r, 2] = a0 * m02 + a1 * m12 + a2 * m22


@nb.njit(cache=True)
def place_points(R, t, cp_joint, cp_local, out):  # type: ignore[no-untyped-def]
    """World positions (P, 3) of points fixed in their joints' frames."""
    for i in range(cp_joint.shape[0]):
        j = cp_joint[i]
        for r in range(3):
            out[i, r] = (
                t[j, r] + R[j, r, 0] * cp_local[i, 0] + R[j, r, 1] * cp_local[i, 1] + R[j, r, 2] * cp_local[i, 2]
            )


@nb.njit(cache=True)
def field_at(dist, origin, res, x, y, z):  # type: ignore[no-untyped-def]
    """The distance [m] stored in the cell holding (x, y, z); ``INF`` beyond the block."""
    i = int(math.floor((x - origin[0]) / res))
    j = int(math.floor((y - origin[1]) / res))
    k = int(math.floor((z - origin[2]) / res))
    if i < 0 or j < 0 or k < 0 or i >= dist.shape[0] or j >= dist.shape[1] or k >= dist.shape[2]:
        return INF
    return dist[i, j, k]


@nb.njit(cache=True)
def rollout_costs(  # type: ignore[no-untyped-def]
    q0,
    V,
    dt,
    lo,
    hi,
    parent,
    kind,
    axis,
    Rp,
    tp,
    iq,
    cp_joint,
    cp_local,
    cp_radius,
    n_move,
    ee_joint,
    ee_R,
    ee_t,
    pairs,
    dist,
    forigin,
    fres,
    pg,
    Rg,
    qd_prev,
    w,
    cost,
    hit,
):
    """Roll every velocity sequence ``V[k]`` (K, T, n) out from ``q0`` (``q += dt V[k, s]``,
        clamped to ``[lo, hi]``) and score it into ``cost[k]``; ``hit[k]``: the first step at which a
        control point's sphere is inside an observed obstacle or two spheres of ``pairs`` overlap
        (``T`` when none). Only the first ``n_move`` points are checked against the field (the
    others are on the fixed base, for ``pairs``). An empty ``dist`` (shape 0) is a scene with no obstacle observed."""
    K, T, n = V.shape
    nj = parent.shape[0]
    P = cp_joint.shape[0]
    R = np.zeros((nj, 3, 3))
    t = np.zeros((nj, 3))
    for a in range(3):
        R[0, a, a] = 1.0
    pts = np.empty((P, 3))
    q = np.empty(n)
    have_field = dist.shape[0] > 0
    for k in range(K):
        for d in range(n):
            q[d] = q0[d]
        c = 0.0
        first = T
        for s in range(T):
            for d in range(n):
                v = V[k, s, d]
                x = q[d] + dt * v
                q[d] = min(max(x, lo[d]), hi[d])
                # joint limits: the velocity [rad/s] the limit cut off (commanded into the limit)
                cut = (x - q[d]) / dt
                c += w[W_LIMIT] * cut * cut
                # smoothness: change of velocity from the step before (the last command at s = 0)
                dv = v - (qd_prev[d] if s == 0 else V[k, s - 1, d])
                c += w[W_SMOOTH] * dv * dv
            forward(q, parent, kind, axis, Rp, tp, iq, R, t)
            place_points(R, t, cp_joint, cp_local, pts)
            # the goal: position distance [m] and the angle of the rotation error [rad]
            ej = ee_joint
            ex = t[ej, 0] + R[ej, 0, 0] * ee_t[0] + R[ej, 0, 1] * ee_t[1] + R[ej, 0, 2] * ee_t[2] - pg[0]
            ey = t[ej, 1] + R[ej, 1, 0] * ee_t[0] + R[ej, 1, 1] * ee_t[1] + R[ej, 1, 2] * ee_t[2] - pg[1]
            ez = t[ej, 2] + R[ej, 2, 0] * ee_t[0] + R[ej, 2, 1] * ee_t[1] + R[ej, 2, 2] * ee_t[2] - pg[2]
            pos = math.sqrt(ex * ex + ey * ey + ez * ez)
            tr = 0.0  # trace(Rg^T R_ee), R_ee = R[ej] ee_R
            for r in range(3):
                for cc in range(3):
                    m = 0.0
                    for kk in range(3):
                        m += R[ej, r, kk] * ee_R[kk, cc]
                    tr += Rg[r, cc] * m
            rot = math.acos(min(max(0.5 * (tr - 1.0), -1.0), 1.0))  # the rotation's angle [rad]
            c += w[W_POS] * pos + w[W_ROT] * rot
            if s == T - 1:
                c += w[W_TERM_POS] * pos + w[W_TERM_ROT] * rot
            # observed obstacles: the distance of each control point's sphere
            collided = False
            if have_field:
                om = w[OBS_MARGIN]
                # near the goal the arm must come close to what is there: the clearance cost fades
                fade = 1.0
                if w[GOAL_FADE] > 0.0 and pos < w[GOAL_FADE]:
                    fade = max(pos / w[GOAL_FADE], w[FADE_FLOOR])
                for i in range(n_move):
                    gap = field_at(dist, forigin, fres, pts[i, 0], pts[i, 1], pts[i, 2]) - cp_radius[i]
                    if gap < 0.0:
                        collided = True
                        c += w[W_COLL]
                    elif gap < om:
                        u = 1.0 - gap / om
                        c += fade * w[W_OBS] * u * u
            # the arm itself: pairs of spheres on links that may touch
            sm = w[SELF_MARGIN]
            for p in range(pairs.shape[0]):
                a, b = pairs[p, 0], pairs[p, 1]
                dx = pts[a, 0] - pts[b, 0]
                dy = pts[a, 1] - pts[b, 1]
                dz = pts[a, 2] - pts[b, 2]
                gap = math.sqrt(dx * dx + dy * dy + dz * dz) - cp_radius[a] - cp_radius[b]
                if gap < 0.0:
                    collided = True
                    c += w[W_COLL]
                elif gap < sm:
                    u = 1.0 - gap / sm
                    c += w[W_SELF] * u * u
            if collided and first == T:
                first = s
        cost[k] = c
        hit[k] = first


@nb.njit(cache=True)
def _edt_line(f, n, d, v, z):  # type: ignore[no-untyped-def]
    """Squared distance transform of one line ``f[:n]`` into ``d[:n]`` (the lower envelope of
    parabolas, Felzenszwalb and Huttenlocher); ``v``, ``z``: work space (n and n + 1)."""
    k = -1
    for q in range(n):
        if f[q] >= INF:
            continue
        if k < 0:
            k = 0
            v[0] = q
            z[0] = -INF
            z[1] = INF
            continue
        p = v[k]
        s = ((f[q] + q * q) - (f[p] + p * p)) / (2.0 * (q - p))
        while s <= z[k]:
            k -= 1
            p = v[k]
            s = ((f[q] + q * q) - (f[p] + p * p)) / (2.0 * (q - p))
        k += 1
        v[k] = q
        z[k] = s
        z[k + 1] = INF
    if k < 0:  # nothing on the line
        for q in range(n):
            d[q] = INF
        return
    k = 0
    for q in range(n):
        while z[k + 1] < q:
            k += 1
        p = v[k]
        d[q] = (q - p) * (q - p) + f[p]


@nb.njit(cache=True)
def distance_block(occupied, res, cap, out):  # type: ignore[no-untyped-def]
    """``out`` (the block's shape, float32): the distance [m] from each cell's centre to the nearest
    occupied cell's centre less half a cell (about the distance to that cell's surface; 0 in an
    occupied cell), ``cap`` [m] where it is more than ``cap``. Exact Euclidean transform, cut at
    ``cap``: a binary pass along x (two sweeps), then the lower envelopes along y and z, skipping
    lines with nothing within ``cap``."""
    nx, ny, nz = occupied.shape
    far = int(math.ceil(cap / res)) + 2  # cells: beyond this along x nothing counts
    m = max(ny, nz)
    f = np.empty(m)
    d = np.empty(m)
    v = np.zeros(m, dtype=np.int64)
    z = np.empty(m + 1)
    g = np.empty((nx, ny, nz))
    big = float(far * far)
    # along x: cells to the nearest occupied cell on the same x line, forward then backward
    for j in range(ny):
        for k in range(nz):
            g[0, j, k] = 0.0 if occupied[0, j, k] else far
    for i in range(1, nx):
        for j in range(ny):
            for k in range(nz):
                g[i, j, k] = 0.0 if occupied[i, j, k] else min(g[i - 1, j, k] + 1.0, far)
    for i in range(nx - 2, -1, -1):
        for j in range(ny):
            for k in range(nz):
                x = g[i + 1, j, k] + 1.0
                if x < g[i, j, k]:
                    g[i, j, k] = x
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                x = g[i, j, k]
                g[i, j, k] = INF if x >= far else x * x
    # along y, then z: lower envelopes of parabolas (squared distances)
    for i in range(nx):
        for k in range(nz):
            empty = True
            for j in range(ny):
                f[j] = g[i, j, k]
                if f[j] < INF:
                    empty = False
            if empty:
                continue
            _edt_line(f, ny, d, v, z)
            for j in range(ny):
                g[i, j, k] = d[j] if d[j] < big else INF
    for i in range(nx):
        for j in range(ny):
            empty = True
            for k in range(nz):
                f[k] = g[i, j, k]
                if f[k] < INF:
                    empty = False
            if empty:
                for k in range(nz):
                    out[i, j, k] = cap
                continue
            _edt_line(f, nz, d, v, z)
            for k in range(nz):
                x = d[k]
                r = 0.0 if x <= 0.0 else (math.sqrt(x) - 0.5) * res if x < INF else cap
                out[i, j, k] = min(r, cap)


@nb.njit(cache=True)
def grow_into(cells, radius, out):  # type: ignore[no-untyped-def]
    """Set ``out`` (bool, ``cells``' shape) in every cell whose centre lies within ``radius`` cells
    of a ``True`` cell of ``cells`` (a ball of cells around each)."""
    nx, ny, nz = cells.shape
    r = int(math.floor(radius))
    r2 = radius * radius
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                if not cells[i, j, k]:
                    continue
                for a in range(max(i - r, 0), min(i + r + 1, nx)):
                    da = (a - i) * (a - i)
                    for b in range(max(j - r, 0), min(j + r + 1, ny)):
                        db = da + (b - j) * (b - j)
                        if db > r2:
                            continue
                        for cc in range(max(k - r, 0), min(k + r + 1, nz)):
                            if db + (cc - k) * (cc - k) <= r2:
                                out[a, b, cc] = True


@nb.njit(cache=True)
def moving_cells(occupied, known, free_since, last_free, marked, t, window, min_free, out):  # type: ignore[no-untyped-def]
    """Mark in ``out`` the cells occupied now that count as a moving obstacle's, and update what
    is kept per cell (views of the whole grid's arrays, float32): ``free_since``, when the cell's
    current run of frames seeing it free began (``inf``: not free now); ``last_free``, the last
    frame that saw it free; ``marked``, when it last became occupied after a run of at least
    ``min_free`` s free that ended within ``window`` s. A cell counts while occupied and marked
    within ``window`` s. ``known``: which cells this frame saw (an unseen cell keeps its state).
    Returns how many count."""
    nx, ny, nz = occupied.shape
    count = 0
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                if occupied[i, j, k]:
                    fs = free_since[i, j, k]
                    lf = last_free[i, j, k]
                    if fs < INF and lf - fs >= min_free and t - lf <= window:
                        marked[i, j, k] = t
                    free_since[i, j, k] = np.inf
                    if t - marked[i, j, k] <= window:
                        out[i, j, k] = True
                        count += 1
                elif known[i, j, k]:
                    if free_since[i, j, k] == np.inf:
                        free_since[i, j, k] = t
                    last_free[i, j, k] = t
    return count


@nb.njit(cache=True)
def drop_near(cells, origin, res, centres, radii, margin):  # type: ignore[no-untyped-def]
    """Clear the ``True`` cells of ``cells`` (a block, its corner at ``origin`` [m]) whose centre
    lies within ``radii[i] + margin`` [m] of a sphere's centre ``centres[i]``; how many are left."""
    nx, ny, nz = cells.shape
    left = 0
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                if not cells[i, j, k]:
                    continue
                x = origin[0] + (i + 0.5) * res
                y = origin[1] + (j + 0.5) * res
                z = origin[2] + (k + 0.5) * res
                for p in range(centres.shape[0]):
                    dx, dy, dz = x - centres[p, 0], y - centres[p, 1], z - centres[p, 2]
                    r = radii[p] + margin
                    if dx * dx + dy * dy + dz * dz <= r * r:
                        cells[i, j, k] = False
                        break
                if cells[i, j, k]:
                    left += 1
    return left

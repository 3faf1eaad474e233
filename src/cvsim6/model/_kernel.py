"""Compiled (numba) kernel of the batch solver; see :mod:`cvsim6.model.solver` for the method.

Layout: per-lane quantities are arrays with the lane (parameter set) as the LAST,
contiguous axis, e.g. ``V[6, L]``. All lanes take grid step n together ("lockstep"):
the loop over lanes runs straight-line scalar code, so independent lanes overlap in
the CPU pipeline (and vectorize where LLVM manages). A lane whose step contains a
valve switch is finished by a scalar handler that splits the step at the switch.

Each lane's arithmetic depends on its own parameters only, so a row's result is
bit-identical whatever batch it is simulated in.

Units: volumes mL, pressures mmHg, time s, conductances mL/(s·mmHg).
"""
from __future__ import annotations

import math

import llvmlite.binding as _llvm
import numba
import numpy as np

# The lane loop of the step reads ~40 and writes 12 array rows; LLVM's default
# budget of 8 runtime alias checks makes it give up vectorizing that loop ("too many
# memory checks needed"). A larger budget lets it emit AVX code (about 3x faster).
# Rows never overlap, so the checks always pass; results are IEEE-identical to the
# scalar path (no fast-math), hence independent of a row's position in a batch.
_llvm.set_option("", "-runtime-memory-check-threshold=4096")
_llvm.set_option("", "-vectorize-memory-check-threshold=4096")

GAMMA = 1.0 - 1.0 / math.sqrt(2.0)
MAX_SWITCHES_PER_STEP = 6
V_TOTAL = 5000.0

# rows of the per-lane constants K
_KT, _KTS, _KELD, _KELS, _KERD, _KERS, _KC1, _KC2, _KC4, _KC5, _KPTH, _KRA, _KH0 = range(13)
_NK = 13
# rows of the per-lane accumulators S (4 quantities: P_a, P_r, P_pa, V_l; 4 means:
# P_a, P_v, P_pa, P_pv)
_SMAX0, _SMIN0, _SINT0, _SLAST0, _SQP0, _SQP1 = 0, 4, 8, 12, 16, 20
_STP0, _STP1, _SSWP0, _SSWP1, _SNWIN, _SMINVOL, _SNSW, _SNCHAT = 24, 25, 26, 27, 28, 29, 30, 31
_NS = 32
#: A row is flagged for valve chatter only if more than this fraction of its steps
#: chattered (a valve at pressure equilibrium toggling within one step is handled
#: and harmless: such rows agree with the reference to ~1e-4).
CHATTER_FRACTION = 0.01


@numba.njit(cache=True, error_model="numpy")
def activation(tc, T, Ts):
    """Activation a(tc) in [0, 1] of appendix A, tc in [0, T] (s)."""
    if tc <= 0.0 or tc > 1.5 * Ts or tc >= T:
        return 0.0
    if tc <= Ts:
        return 0.5 * (1.0 - math.cos(math.pi * tc / Ts))
    return 0.5 * (1.0 + math.cos(2.0 * math.pi * (tc - Ts) / Ts))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _eliminate(d, c, f, r, D_next, r_next, w, d5, r5):
    """One elimination step of :func:`_cyclic_solve`, pivot row k (diagonal ``d``, super-diagonal
    ``-c``, last-column fill ``f``, right-hand side ``r``): clear column k from row k+1
    (diagonal ``D_next`` before elimination, right-hand side ``r_next``) and from row 5 (entry
    ``w``; its diagonal ``d5`` and right-hand side ``r5`` so far). Returns the pivot's inverse,
    row k+1's new diagonal, fill and right-hand side, row 5's multiplier ``m5`` (its next entry
    is ``m5 * c_{k+1}``, less the ``c_4`` coupling at the end) and its new ``d5``, ``r5``.
    Inlined, like its caller: the arithmetic is that of the written-out elimination."""
    i = 1.0 / d
    m = -c * i
    m5 = w * i
    return i, D_next + m * c, -m * f, r_next - m * r, m5, d5 - m5 * f, r5 - m5 * r


@numba.njit(cache=True, error_model="numpy", inline="always")
def _cyclic_solve(C0, C3, c0, c1, c2, c3, c4, c5, D1, D2, D4, D5, r0, r1, r2, r3, r4, r5):
    """Solve one implicit stage of :func:`_step_range`: the symmetric cyclic tridiagonal 6x6
    system in ``x`` (mmHg), diagonal ``C_i + c_{i-1} + c_i`` (``D1, D2, D4, D5`` precomputed, the
    ventricles' from ``C0``, ``C3``), off-diagonals ``-c_i``, right-hand side ``r``. Elimination
    that tracks the fill-in of the last column (diagonally dominant: no pivoting); inlined, so
    the lane loop stays straight-line code."""
    # row i keeps: diagonal d_i, super-diagonal -c_i, last-column fill l_i;
    # w is row 5's entry in the column being eliminated
    i0 = 1.0 / (C0 + c5 + c0)
    m = -c0 * i0
    d1 = D1 + m * c0
    f1 = m * c5
    r1 = r1 - m * r0
    m5 = -c5 * i0
    d5 = D5 + m5 * c5
    r5 = r5 - m5 * r0
    w = m5 * c0
    i1, d2, f2, r2, m5, d5, r5 = _eliminate(d1, c1, f1, r1, D2, r2, w, d5, r5)
    w = m5 * c1
    i2, d3, f3, r3, m5, d5, r5 = _eliminate(d2, c2, f2, r2, C3 + c2 + c3, r3, w, d5, r5)
    w = m5 * c2
    i3, d4, f4, r4, m5, d5, r5 = _eliminate(d3, c3, f3, r3, D4, r4, w, d5, r5)
    w = -c4 + m5 * c3
    i4 = 1.0 / d4
    e45 = -c4 + f4  # row 4: super-diagonal and fill share column 5
    m5 = w * i4
    d5 -= m5 * e45
    r5 -= m5 * r4
    x5 = r5 / d5
    x4 = (r4 - e45 * x5) * i4
    x3 = (r3 + c3 * x4 - f3 * x5) * i3
    x2 = (r2 + c2 * x3 - f2 * x5) * i2
    x1 = (r1 + c1 * x2 - f1 * x5) * i1
    x0 = (r0 + c0 * x1 + c5 * x5) * i0
    return x0, x1, x2, x3, x4, x5


@numba.njit(cache=True, error_model="numpy")
def _step_range(l0, l1, V, H, A1, A2, aeff, K, W, E, Vo, xo):
    """One SDIRK2 step for lanes l0..l1-1 from ``V[:, l]`` with step ``H[l]`` (s).

    ``l0``, ``l1`` are unsigned so that numba emits no negative-index wraparound,
    which would keep LLVM from vectorizing the lane loop.

    ``A1[l]``, ``A2[l]``: activation at the stage times ``tau + gamma h`` and ``tau + h``.
    Writes ``Vo[:, l]`` (mL) and ``xo[:, l]`` (``x = P - off``, mmHg) at ``tau + h``;
    the method is stiffly accurate (the second stage is the new state).

    Each implicit stage ``Y = B + gamma h f(t, Y)``, for fixed valve states, is in
    ``x`` the symmetric cyclic tridiagonal 6x6 system
    ``(C_i + g (a_{i-1} + a_i)) x_i - g a_{i-1} x_{i-1} - g a_i x_{i+1} = rhs_i``
    (``g = gamma h``, ``a`` effective conductances, ``W`` unstressed volumes,
    ``e_k = off_k - off_{k+1}``), solved by elimination that tracks the fill-in of
    the last column (:func:`_cyclic_solve`, inlined: the lane loop compiles to
    straight-line, vectorizable code).
    """
    f = (1.0 - GAMMA) / GAMMA
    for l in range(l0, l1):
        hg = GAMMA * H[l]
        Eld, Els, Erd, Ers = K[_KELD, l], K[_KELS, l], K[_KERD, l], K[_KERS, l]
        C1, C2, C4, C5 = K[_KC1, l], K[_KC2, l], K[_KC4, l], K[_KC5, l]
        v0, v1, v2, v3, v4, v5 = V[0, l], V[1, l], V[2, l], V[3, l], V[4, l], V[5, l]
        W0, W1, W2, W3, W4, W5 = W[0, l], W[1, l], W[2, l], W[3, l], W[4, l], W[5, l]
        c0, c1, c2 = hg * aeff[0, l], hg * aeff[1, l], hg * aeff[2, l]
        c3, c4, c5 = hg * aeff[3, l], hg * aeff[4, l], hg * aeff[5, l]
        q0 = c5 * E[5, l] - c0 * E[0, l]
        q1 = c0 * E[0, l] - c1 * E[1, l]
        q2 = c1 * E[1, l] - c2 * E[2, l]
        q3 = c2 * E[2, l] - c3 * E[3, l]
        q4 = c3 * E[3, l] - c4 * E[4, l]
        q5 = c4 * E[4, l] - c5 * E[5, l]
        D1 = C1 + c0 + c1
        D2 = C2 + c1 + c2
        D4 = C4 + c3 + c4
        D5 = C5 + c4 + c5
        b0, b1, b2, b3, b4, b5 = v0, v1, v2, v3, v4, v5
        C0 = C3 = C0p = C3p = 0.0
        x0 = x1 = x2 = x3 = x4 = x5 = 0.0
        for st in range(2):
            act = A1[l] if st == 0 else A2[l]
            C0 = 1.0 / (Eld + (Els - Eld) * act)
            C3 = 1.0 / (Erd + (Ers - Erd) * act)
            if st == 1:
                b0 = v0 + f * (W0 + C0p * x0 - v0)
                b1 = v1 + f * (W1 + C1 * x1 - v1)
                b2 = v2 + f * (W2 + C2 * x2 - v2)
                b3 = v3 + f * (W3 + C3p * x3 - v3)
                b4 = v4 + f * (W4 + C4 * x4 - v4)
                b5 = v5 + f * (W5 + C5 * x5 - v5)
            C0p = C0
            C3p = C3
            r0 = b0 - W0 + q0
            r1 = b1 - W1 + q1
            r2 = b2 - W2 + q2
            r3 = b3 - W3 + q3
            r4 = b4 - W4 + q4
            r5 = b5 - W5 + q5
            x0, x1, x2, x3, x4, x5 = _cyclic_solve(C0, C3, c0, c1, c2, c3, c4, c5, D1, D2, D4, D5,
                                                   r0, r1, r2, r3, r4, r5)
        xo[0, l] = x0
        xo[1, l] = x1
        xo[2, l] = x2
        xo[3, l] = x3
        xo[4, l] = x4
        xo[5, l] = x5
        Vo[0, l] = W0 + C0 * x0
        Vo[1, l] = W1 + C1 * x1
        Vo[2, l] = W2 + C2 * x2
        Vo[3, l] = W3 + C3 * x3
        Vo[4, l] = W4 + C4 * x4
        Vo[5, l] = W5 + C5 * x5


@numba.njit(cache=True, error_model="numpy", inline="always")
def _step_one(l, V, h, act1, act2, aeff, K, W, E, Vo, xo, H, A1, A2):
    """:func:`_step_range` for lane l alone, with step h and activations act1, act2."""
    H[l] = h
    A1[l] = act1
    A2[l] = act2
    _step_range(np.uint64(l), np.uint64(l + 1), V, H, A1, A2, aeff, K, W, E, Vo, xo)


@numba.njit(cache=True, error_model="numpy", inline="always")
def parabola_vertex(t0, q0, t1, q1, t2, q2):
    """Value at the vertex of the parabola through three points if the vertex lies
    in [t0, t2], else ``q1``."""
    d1 = (q1 - q0) / (t1 - t0)
    d2 = (q2 - q1) / (t2 - t1)
    a2 = (d2 - d1) / (t2 - t0)
    if a2 == 0.0:
        return q1
    # q(t) = q1 + b (t - t1) + a2 (t - t1)^2
    b = d1 + a2 * (t1 - t0)
    ts = -b / (2.0 * a2)
    if ts < t0 - t1 or ts > t2 - t1:
        return q1
    return q1 + b * ts + a2 * ts * ts


@numba.njit(cache=True, error_model="numpy")
def _lane_setup(p, l, K, W, E, G, V, x, s, aeff):
    """Constants, initial state (appendix A 8x8 system) and valve states of lane l."""
    Hr, pth, rsys = p[0], p[1], p[2]
    Cld, Cls, Ca, Cv, Crd, Crs, Cpa, Cpv = p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10]
    Rlin, Rlout, Ra, Rrin, Rrout, Rpv = p[11], p[12], p[13], p[14], p[15], p[16]
    T = 60.0 / Hr
    Ts = rsys * T
    K[_KT, l] = T
    K[_KTS, l] = Ts
    K[_KELD, l] = 1.0 / Cld
    K[_KELS, l] = 1.0 / Cls
    K[_KERD, l] = 1.0 / Crd
    K[_KERS, l] = 1.0 / Crs
    K[_KC1, l] = Ca
    K[_KC2, l] = Cv
    K[_KC4, l] = Cpa
    K[_KC5, l] = Cpv
    K[_KPTH, l] = pth
    K[_KRA, l] = Ra
    off = (pth, pth / 3.0, 0.0, pth, pth, pth)
    for i in range(6):
        W[i, l] = p[17 + i]
        E[i, l] = off[i] - off[(i + 1) % 6]
    G[0, l] = 1.0 / Rlout
    G[1, l] = 1.0 / Ra
    G[2, l] = 1.0 / Rrin
    G[3, l] = 1.0 / Rrout
    G[4, l] = 1.0 / Rpv
    G[5, l] = 1.0 / Rlin
    # appendix A: unknowns [P_l_dia, P_l_sys, P_r_dia, P_r_sys, P_a, P_v, P_pa, P_pv]
    Td = T - Ts
    M = np.zeros((8, 8))
    rhs = np.zeros(8)
    svc = -Cld * pth + Cls * pth
    M[0, 0], M[0, 1], M[0, 2], M[0, 3] = Cld, -Cls, -Crd, Crs
    rhs[0] = -(svc - (-Crd * pth + Crs * pth))
    durs = (Ts, T, Td, Ts, T, Td)
    Rs = (Rlout, Ra, Rrin, Rrout, Rpv, Rlin)
    ups = (1, 4, 5, 3, 6, 7)
    downs = (4, 5, 2, 6, 7, 0)
    for j in range(6):
        M[j + 1, 0] = Cld
        M[j + 1, 1] = -Cls
        M[j + 1, ups[j]] -= durs[j] / Rs[j]
        M[j + 1, downs[j]] += durs[j] / Rs[j]
        rhs[j + 1] = -svc
    V0tot = p[17] + p[18] + p[19] + p[20] + p[21] + p[22]
    M[7, 0], M[7, 2], M[7, 4], M[7, 5], M[7, 6], M[7, 7] = Cld, Crd, Ca, Cv, Cpa, Cpv
    rhs[7] = V_TOTAL - V0tot + pth * (Cld + Crd + Cpa + Cpv) + Ca * pth / 3.0
    sol = np.linalg.solve(M, rhs)
    Pinit = (sol[0], sol[4], sol[5], sol[2], sol[6], sol[7])
    Cinit = (Cld, Ca, Cv, Crd, Cpa, Cpv)
    for i in range(6):
        x[i, l] = Pinit[i] - off[i]
        V[i, l] = W[i, l] + Cinit[i] * x[i, l]
    for k in range(6):
        s[k, l] = 1
        if k == 0 or k == 2 or k == 3 or k == 5:
            s[k, l] = 1 if Pinit[k] - Pinit[(k + 1) % 6] > 0.0 else 0
        aeff[k, l] = s[k, l] * G[k, l]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _dp(x, E, k, l):
    """Pressure difference (mmHg) across flow k of lane l."""
    return x[k, l] - x[(k + 1) % 6, l] + E[k, l]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _accumulate(l, t, x, V, K, S, is_switch):
    """Add the node (t, x[:, l], V[:, l]) of lane l to its output-window statistics."""
    pth = K[_KPTH, l]
    Pa = x[1, l] + pth / 3.0
    Pv = x[2, l]
    Ppa = x[4, l] + pth
    Ppv = x[5, l] + pth
    q = (Pa, x[3, l] + pth, Ppa, V[0, l])
    nwin = S[_SNWIN, l]
    if nwin > 0:
        dt = t - S[_STP1, l]
        S[_SINT0 + 0, l] += 0.5 * dt * (S[_SLAST0 + 0, l] + Pa)
        S[_SINT0 + 1, l] += 0.5 * dt * (S[_SLAST0 + 1, l] + Pv)
        S[_SINT0 + 2, l] += 0.5 * dt * (S[_SLAST0 + 2, l] + Ppa)
        S[_SINT0 + 3, l] += 0.5 * dt * (S[_SLAST0 + 3, l] + Ppv)
    S[_SLAST0 + 0, l] = Pa
    S[_SLAST0 + 1, l] = Pv
    S[_SLAST0 + 2, l] = Ppa
    S[_SLAST0 + 3, l] = Ppv
    for j in range(4):
        v = q[j]
        if v > S[_SMAX0 + j, l]:
            S[_SMAX0 + j, l] = v
        if v < S[_SMIN0 + j, l]:
            S[_SMIN0 + j, l] = v
        # parabola through the last three nodes, where it can matter: the middle one
        # is a discrete extremum, or the first one is a valve switch (the one-sided
        # extremum just after a valve opens). The middle node must not be a switch.
        if nwin >= 2 and S[_SSWP1, l] == 0.0:
            q0 = S[_SQP0 + j, l]
            q1 = S[_SQP1 + j, l]
            if S[_SSWP0, l] != 0.0 or (q1 - q0) * (v - q1) <= 0.0:
                pv = parabola_vertex(S[_STP0, l], q0, S[_STP1, l], q1, t, v)
                if pv > S[_SMAX0 + j, l]:
                    S[_SMAX0 + j, l] = pv
                if pv < S[_SMIN0 + j, l]:
                    S[_SMIN0 + j, l] = pv
        S[_SQP0 + j, l] = S[_SQP1 + j, l]
        S[_SQP1 + j, l] = v
    S[_STP0, l] = S[_STP1, l]
    S[_STP1, l] = t
    S[_SSWP0, l] = S[_SSWP1, l]
    S[_SSWP1, l] = 1.0 if is_switch else 0.0
    S[_SNWIN, l] = nwin + 1


@numba.njit(cache=True, error_model="numpy", inline="always")
def _record(l, t, V, s, rec_t, rec_V, rec_s, nrec):
    """Store lane 0's node while the recording buffers have room."""
    if l == 0 and nrec[0] < rec_t.shape[0]:
        i = nrec[0]
        rec_t[i] = t
        for k in range(6):
            rec_V[i, k] = V[k, l]
            rec_s[i, k] = s[k, l]
        nrec[0] = i + 1


@numba.njit(cache=True, error_model="numpy", inline="always")
def _node(l, t, V, x, s, K, S, in_win, is_switch, rec_t, rec_V, rec_s, nrec):
    """Everything done at an accepted node: record, volume check, window statistics."""
    _record(l, t, V, s, rec_t, rec_V, rec_s, nrec)
    for i in range(6):
        if V[i, l] < S[_SMINVOL, l]:
            S[_SMINVOL, l] = V[i, l]
    if in_win:
        _accumulate(l, t, x, V, K, S, is_switch)


@numba.njit(cache=True, error_model="numpy")
def _switch_step(l, n, cyc, in_win, V, x, Vn, xn, s, aeff, K, W, E, G, S, Vm, xm, Vb, xb,
                 Hs, As1, As2, rec_t, rec_V, rec_s, nrec):
    """Finish grid step n of lane l when it contains valve switches.

    On entry ``Vn, xn`` hold the step taken with the old valve states. Each switch is
    located by regula falsi (Illinois) on the valve's pressure difference under the
    old states, the step is ended there, the valve flipped and the rest of the step
    retaken. On exit ``V, x`` hold the state at the grid node. Returns 1 on valve
    chatter (more than MAX_SWITCHES_PER_STEP switches in one step), else 0.
    """
    T, Ts, h0 = K[_KT, l], K[_KTS, l], K[_KH0, l]
    tau = n * h0
    tau_end = (n + 1) * h0
    nsw = 0
    chatter = 0
    while True:
        h = tau_end - tau
        kmin = -1
        thmin = 2.0
        for k in (0, 2, 3, 5):
            dp1 = _dp(xn, E, k, l)
            if (s[k, l] == 1 and dp1 < 0.0) or (s[k, l] == 0 and dp1 > 0.0):
                dp0 = _dp(x, E, k, l)
                den = dp0 - dp1
                th = dp0 / den if den != 0.0 else 0.0
                th = min(max(th, 0.0), 1.0)
                if th < thmin:
                    thmin = th
                    kmin = k
        if kmin < 0:
            break
        if nsw >= MAX_SWITCHES_PER_STEP:
            chatter = 1
            break
        k = kmin
        lo, hi = 0.0, 1.0
        flo = _dp(x, E, k, l)
        fhi = _dp(xn, E, k, l)
        th = thmin
        side = 0
        for i in range(6):
            Vb[i, l] = V[i, l]
            xb[i, l] = x[i, l]
        for _ in range(8):
            if th * h < 1e-12:
                th = 0.0
                for i in range(6):
                    Vb[i, l] = V[i, l]
                    xb[i, l] = x[i, l]
                break
            hs = th * h
            _step_one(l, V, hs, activation(tau + GAMMA * hs, T, Ts), activation(tau + hs, T, Ts),
                      aeff, K, W, E, Vm, xm, Hs, As1, As2)
            fm = _dp(xm, E, k, l)
            for i in range(6):
                Vb[i, l] = Vm[i, l]
                xb[i, l] = xm[i, l]
            if abs(fm) < 1e-9 or (hi - lo) * h < 1e-13:
                break
            if (fm > 0.0) == (flo > 0.0):
                lo, flo = th, fm
                if side == -1:
                    fhi *= 0.5
                side = -1
            else:
                hi, fhi = th, fm
                if side == 1:
                    flo *= 0.5
                side = 1
            den = flo - fhi
            th = lo + (hi - lo) * (flo / den) if den != 0.0 else 0.5 * (lo + hi)
        for i in range(6):
            V[i, l] = Vb[i, l]
            x[i, l] = xb[i, l]
        tau = tau + th * h
        s[k, l] = 1 - s[k, l]
        aeff[k, l] = s[k, l] * G[k, l]
        nsw += 1
        _node(l, cyc * T + tau, V, x, s, K, S, in_win, True, rec_t, rec_V, rec_s, nrec)
        h = tau_end - tau
        _step_one(l, V, h, activation(tau + GAMMA * h, T, Ts), activation(tau_end, T, Ts),
                  aeff, K, W, E, Vn, xn, Hs, As1, As2)
    for i in range(6):
        V[i, l] = Vn[i, l]
        x[i, l] = xn[i, l]
    S[_SNSW, l] += nsw
    return chatter


@numba.njit(cache=True, error_model="numpy")
def _lane_outputs(l, p, nwin, x, K, S, o):
    """The 16 outputs of lane l (registry order and units) from its statistics."""
    tw = nwin * K[_KT, l]
    mean_Pa = S[_SINT0 + 0, l] / tw
    mean_Pv = S[_SINT0 + 1, l] / tw
    mean_Ppa = S[_SINT0 + 2, l] / tw
    mean_Ppv = S[_SINT0 + 3, l] / tw
    co = (mean_Pa - mean_Pv) / K[_KRA, l] * 60.0 / 1000.0  # mL/s -> L/min
    o[0] = p[0]
    o[1] = S[_SMAX0 + 0, l]
    o[2] = S[_SMIN0 + 0, l]
    o[3] = S[_SMAX0 + 1, l]
    o[4] = S[_SMIN0 + 1, l]
    o[5] = S[_SMAX0 + 2, l]
    o[6] = S[_SMIN0 + 2, l]
    o[7] = x[3, l] + K[_KPTH, l]
    o[8] = mean_Ppv
    o[9] = mean_Pv
    o[10] = S[_SMIN0 + 3, l]
    o[11] = S[_SMAX0 + 3, l]
    o[12] = (o[11] - o[10]) / o[11]
    o[13] = co
    o[14] = (mean_Pa - mean_Pv) / co * 80.0  # mmHg·min/L -> dyn·s/cm^5
    o[15] = (mean_Ppa - mean_Ppv) / co * 80.0


@numba.njit(cache=True, error_model="numpy")
def _lane_status(o, min_volume, V, l):
    for j in range(16):
        if not math.isfinite(o[j]):
            return 1
    if min_volume < 0.0:
        return 2
    if not (0.0 < o[12] < 1.0 and o[13] > 0.0):
        return 4
    vt = V[0, l] + V[1, l] + V[2, l] + V[3, l] + V[4, l] + V[5, l]
    if abs(vt - V_TOTAL) > 1e-6 * V_TOTAL:
        return 5
    return 0


@numba.njit(cache=True, error_model="numpy")
def lockstep(params, nsteps, ncycles, nwin, out, status, rec_t, rec_V, rec_s):
    """Integrate all rows of ``params`` (L, 23) in lockstep.

    Fills ``out`` (L, 16) and ``status`` (L,) (codes of ``cvsim6.model.solver.STATUS_REASONS``).
    Records lane 0's nodes (t, V, valve states) into ``rec_*`` while room remains
    and returns how many were recorded.
    """
    L = params.shape[0]
    K = np.empty((_NK, L))
    W = np.empty((6, L))
    E = np.empty((6, L))
    G = np.empty((6, L))
    V = np.empty((6, L))
    x = np.empty((6, L))
    Vn = np.empty((6, L))
    xn = np.empty((6, L))
    Vm = np.empty((6, L))
    xm = np.empty((6, L))
    Vb = np.empty((6, L))
    xb = np.empty((6, L))
    s = np.empty((6, L), dtype=np.int64)
    aeff = np.empty((6, L))
    S = np.zeros((_NS, L))
    flag = np.zeros(L, dtype=np.bool_)
    Hs = np.empty(L)
    As1 = np.empty(L)
    As2 = np.empty(L)
    nrec = np.zeros(1, dtype=np.int64)
    for l in range(L):
        _lane_setup(params[l], l, K, W, E, G, V, x, s, aeff)
        K[_KH0, l] = K[_KT, l] / nsteps
        for j in range(4):
            S[_SMAX0 + j, l] = -1e300
            S[_SMIN0 + j, l] = 1e300
        S[_SMINVOL, l] = 1e300
    _record(0, 0.0, V, s, rec_t, rec_V, rec_s, nrec)
    # activation at the two stage times of every grid step (the same in every cycle)
    A1 = np.empty((nsteps, L))
    A2 = np.empty((nsteps, L))
    for n in range(nsteps):
        for l in range(L):
            h0 = K[_KH0, l]
            A1[n, l] = activation(n * h0 + GAMMA * h0, K[_KT, l], K[_KTS, l])
            A2[n, l] = activation((n + 1) * h0, K[_KT, l], K[_KTS, l])
    first_win = ncycles - nwin
    for cyc in range(ncycles):
        in_win = cyc >= first_win
        for n in range(nsteps):
            _step_range(np.uint64(0), np.uint64(L), V, K[_KH0], A1[n], A2[n], aeff, K, W, E, Vn, xn)
            for l in range(L):
                bad = False
                for k in (0, 2, 3, 5):
                    dp = _dp(xn, E, k, l)
                    if (s[k, l] == 1 and dp < 0.0) or (s[k, l] == 0 and dp > 0.0):
                        bad = True
                flag[l] = bad
            # the node t = (ncycles - nwin) T opens the output window
            for l in range(L):
                if flag[l]:
                    if _switch_step(l, n, cyc, in_win, V, x, Vn, xn, s, aeff, K, W, E, G, S,
                                    Vm, xm, Vb, xb, Hs, As1, As2, rec_t, rec_V, rec_s, nrec):
                        S[_SNCHAT, l] += 1.0
                else:
                    for i in range(6):
                        V[i, l] = Vn[i, l]
                        x[i, l] = xn[i, l]
            # the grid node ending this step, in every lane
            last = n == nsteps - 1
            _record(0, (cyc + 1) * K[_KT, 0] if last else cyc * K[_KT, 0] + (n + 1) * K[_KH0, 0],
                     V, s, rec_t, rec_V, rec_s, nrec)
            for l in range(L):
                m = S[_SMINVOL, l]
                for i in range(6):
                    m = min(m, V[i, l])
                S[_SMINVOL, l] = m
            # the node t = (ncycles - nwin) T opens the output window
            if in_win or (cyc == first_win - 1 and last):
                for l in range(L):
                    t_abs = (cyc + 1) * K[_KT, l] if last else cyc * K[_KT, l] + (n + 1) * K[_KH0, l]
                    _accumulate(l, t_abs, x, V, K, S, False)
    for l in range(L):
        _lane_outputs(l, params[l], nwin, x, K, S, out[l])
        if status[l] == 0:
            status[l] = _lane_status(out[l], S[_SMINVOL, l], V, l)
        if status[l] == 0 and S[_SNCHAT, l] > CHATTER_FRACTION * ncycles * nsteps:
            status[l] = 3
    return nrec[0]


@numba.njit(cache=True, error_model="numpy")
def batch(params, nsteps, ncycles, nwin, out, status):
    """:func:`lockstep` without recording."""
    lockstep(params, nsteps, ncycles, nwin, out, status,
             np.empty(0), np.empty((0, 6)), np.empty((0, 6), dtype=np.int64))

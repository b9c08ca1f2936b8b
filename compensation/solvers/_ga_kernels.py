"""Compiled (numba) generation step of the batched GA: selection, crossover, mutation, ball
repair and fitness inheritance for every point of a chunk in one pass, no temporaries.

The operators are those documented in :mod:`compensation.solvers.batched_ga`; this module
only holds the loops. Random input comes from the caller (raw 32-bit words from a numpy
Generator), so the kernels hold no random state. ``nogil=True``: chunks run in parallel
threads.
"""
from __future__ import annotations

import numpy as np
from numba import njit

U24 = np.float32(2.0 ** -24)
TWO_M31 = 2.0 ** -31


@njit(cache=True, nogil=True, error_model="numpy")
def breed(pop, fit, words, odd, M, pm, step, ball, new_pop, new_fit, fresh_at, fresh_pt, fresh_d):
    """One generation for m points with populations of P individuals.

    pop (m, P, 3) float32 offsets μm, fit (m, P) float32, words (m, K, 4) uint32 with K = P - 1
    offspring per point, odd (m, K) int8 (0: normal crossover pool, 1: pool of one, 2: empty
    pool). Writes new_pop (m, P, 3) and new_fit (m, P): slot 0 the elite, slots 1.. the
    offspring; an offspring equal to one of its parents (no mutation) inherits that parent's
    fitness, the others are listed for evaluation: fresh_at (flat index into new_fit),
    fresh_pt (point), fresh_d (3, ·) the offsets as columns. Returns the number listed.
    fresh_* need room for m·K + 1 entries (each offspring is written, then kept or not).
    """
    m, P = fit.shape
    K = P - 1
    one = np.float32(1.0)
    two_pm = np.float32(2.0) / pm
    tiny = np.float32(1e-30)
    ranked = np.empty(P, dtype=np.int64)
    F = 0
    for i in range(m):
        # steady-state selection: individuals ranked by fitness, descending (ties by index);
        # the first M are the mating parents, the first is the elite (keep_elitism = 1)
        for j in range(P):
            ranked[j] = j  # (a NaN fitness would leave gaps; callers map NaN to -inf)
        row = fit[i]
        for j in range(P):
            fj = row[j]
            r = np.int32(0)
            for h in range(P):
                r += np.int32(row[h] > fj)
            for h in range(j):
                r += np.int32(row[h] == fj)
            ranked[r] = j
        e = ranked[0]
        new_fit[i, 0] = fit[i, e]
        for g in range(3):
            new_pop[i, 0, g] = pop[i, e, g]
        for k in range(K):
            # first parent, cut point, second parent from one 31-bit word (mixed radix by
            # multiplication: each digit takes the integer part, the rest carries on)
            v = np.float64(words[i, k, 0] & 0x7FFFFFFF) * TWO_M31 * M
            first = np.int64(v)
            v = (v - first) * 3.0
            cut = np.int64(v)
            v = (v - cut) * (M - 1)
            second = np.int64(v)
            if second >= first:
                second += 1
            o = odd[i, k]
            if o == 2:  # no candidate in the pool: the child is parent k mod M
                i1 = ranked[k % M]
                i2 = i1
            else:
                i1 = ranked[first]
                i2 = i1 if o == 1 else ranked[second]  # one candidate: mates with itself
            # branch-free from here on (the branches would be unpredictable)
            j0 = i2 + (i1 - i2) * (cut >= 1)
            j1 = i2 + (i1 - i2) * (cut >= 2)
            c0 = pop[i, j0, 0]
            c1 = pop[i, j1, 1]
            c2 = pop[i, i2, 2]
            u0 = np.float32(words[i, k, 1] & 0xFFFFFF) * U24
            u1 = np.float32(words[i, k, 2] & 0xFFFFFF) * U24
            u2 = np.float32(words[i, k, 3] & 0xFFFFFF) * U24
            m0, m1, m2 = u0 < pm, u1 < pm, u2 < pm
            c0 += np.float32(m0) * ((u0 * two_pm - one) * step)
            c1 += np.float32(m1) * ((u1 * two_pm - one) * step)
            c2 += np.float32(m2) * ((u2 * two_pm - one) * step)
            r2 = c0 * c0 + c1 * c1 + c2 * c2
            s = min(one, ball / np.sqrt(max(r2, tiny)))  # ball repair: radial projection
            c0 *= s
            c1 *= s
            c2 *= s
            new_pop[i, k + 1, 0] = c0
            new_pop[i, k + 1, 1] = c1
            new_pop[i, k + 1, 2] = c2
            quiet = not (m0 | m1 | m2)
            same2 = quiet & (c0 == pop[i, i2, 0]) & (c1 == pop[i, i2, 1]) & (c2 == pop[i, i2, 2])
            same1 = quiet & (c0 == pop[i, i1, 0]) & (c1 == pop[i, i1, 1]) & (c2 == pop[i, i1, 2])
            new_fit[i, k + 1] = fit[i, i2] if same2 else fit[i, i1]  # inherited (fresh: overwritten)
            fresh_at[F] = i * P + k + 1
            fresh_pt[F] = i
            fresh_d[0, F] = c0
            fresh_d[1, F] = c1
            fresh_d[2, F] = c2
            F += not (same1 | same2)
    return F


@njit(cache=True, nogil=True, error_model="numpy")
def scatter(new_fit_flat, fresh_at, values, F):
    """new_fit_flat[fresh_at[:F]] = values[:F]."""
    for j in range(F):
        new_fit_flat[fresh_at[j]] = values[j]

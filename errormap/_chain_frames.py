"""The serial chain's cumulative frames (:meth:`errormap.chain.Chain.frames`) in one compiled pass over the poses
(numba; imported when frames are first computed, so that reading the package loads no compiler).

Every number is the one the array loop it replaced gave: the same products, sums and differences in the same order,
each rounded once (no fused multiply-add: numba leaves contraction off without ``fastmath``), the cosines and sines
computed by numpy beforehand as before."""
import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def chain_frames(v, cs, sn, kind_r, axis, F):
    """Fill F (n, m + 1, 4, 4) with the frames before each of the m ETs and after the last, per pose.

    v (n, m) the ET values; cs, sn (n, m) their cosines and sines (read at the rotations only); kind_r (m,) True for a
    rotation about ``axis`` (m,) (0, 1, 2: x, y, z), else a translation along it."""
    n, m = v.shape
    T = np.empty((3, 4))
    for i in range(n):
        for r in range(3):
            for c in range(4):
                T[r, c] = 1.0 if r == c else 0.0
        for k in range(m + 1):
            if k > 0:
                a = axis[k - 1]
                if kind_r[k - 1]:
                    b, c2 = (a + 1) % 3, (a + 2) % 3
                    co, si = cs[i, k - 1], sn[i, k - 1]
                    for r in range(3):
                        tb, tc = T[r, b], T[r, c2]
                        T[r, b] = tb * co + tc * si
                        T[r, c2] = tc * co - tb * si
                else:
                    d = v[i, k - 1]
                    for r in range(3):
                        T[r, 3] = T[r, 3] + T[r, a] * d
            for r in range(3):
                for c in range(4):
                    F[i, k, r, c] = T[r, c]
            F[i, k, 3, 0] = 0.0
            F[i, k, 3, 1] = 0.0
            F[i, k, 3, 2] = 0.0
            F[i, k, 3, 3] = 1.0


@njit(cache=True, nogil=True, error_model="numpy")
def chain_columns(F, kind_r, axis, lin, ang):
    """Fill lin, ang (n, m, 3) from the frames F (n, m + 1, 4, 4) (:meth:`errormap.chain.Chain._columns`): per ET its
    axis in the world a (+ 0.0: a zero is +0), at a rotation a × (p − o) and a, at a translation a and 0; p the tool
    point, o the ET's origin. The cross product's products and differences as ``np.cross`` forms them."""
    n, m1 = F.shape[0], F.shape[1]
    m = m1 - 1
    for i in range(n):
        p0, p1, p2 = F[i, m, 0, 3], F[i, m, 1, 3], F[i, m, 2, 3]
        for k in range(m):
            c = axis[k]
            a0, a1, a2 = F[i, k, 0, c] + 0.0, F[i, k, 1, c] + 0.0, F[i, k, 2, c] + 0.0
            if kind_r[k]:
                b0, b1, b2 = p0 - F[i, k, 0, 3], p1 - F[i, k, 1, 3], p2 - F[i, k, 2, 3]
                lin[i, k, 0] = a1 * b2 - a2 * b1
                lin[i, k, 1] = a2 * b0 - a0 * b2
                lin[i, k, 2] = a0 * b1 - a1 * b0
                ang[i, k, 0], ang[i, k, 1], ang[i, k, 2] = a0, a1, a2
            else:
                lin[i, k, 0], lin[i, k, 1], lin[i, k, 2] = a0, a1, a2
                ang[i, k, 0], ang[i, k, 1], ang[i, k, 2] = 0.0, 0.0, 0.0

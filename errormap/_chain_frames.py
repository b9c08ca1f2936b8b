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

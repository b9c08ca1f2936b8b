"""The squared-exponential marginal likelihood's two loops over the pairs of training points (numba; :func:`training.gp.
_gp_nll`, which imports this module when a fit runs, so that reading the package loads no compiler)."""
import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def _se_lower(XT, inv_l2, atom_of, term_atoms, sf2, k_diag, K, E):
    """K's diagonal (``k_diag``) and strict lower triangle, and each pair's atom exponentials, column by column (the
    innermost loops run over a column's rows: contiguous, vectorised).

    XT (dv, n) virtual columns, inv_l2 (dv,), atom_of (dv,), term_atoms (T, A), sf2 (T,); K (n, n) Fortran-ordered,
    written; E (A, m), written: pair p = the p-th of :class:`training.gp._Pairs`."""
    dv, n = XT.shape
    T, A = term_atoms.shape
    S = np.empty((A, n))
    p0 = 0
    for j in range(n):
        K[j, j] = k_diag
        L = n - j - 1
        S[:, :L] = 0.0
        for c in range(dv):
            a, f, xj = atom_of[c], inv_l2[c], XT[c, j]
            for r in range(L):
                diff = XT[c, j + 1 + r] - xj
                S[a, r] += f * (diff * diff)
        for a in range(A):
            for r in range(L):
                E[a, p0 + r] = np.exp(-0.5 * S[a, r])
        for r in range(L):
            K[j + 1 + r, j] = 0.0
        for t in range(T):
            for r in range(L):
                S[0, r] = sf2[t]   # S is free now: the term's product
            for a in range(A):
                if term_atoms[t, a]:
                    for r in range(L):
                        S[0, r] *= E[a, p0 + r]
            for r in range(L):
                K[j + 1 + r, j] += S[0, r]
        p0 += L


@njit(cache=True, nogil=True, error_model="numpy")
def _se_pair_sums(XT, atom_of, term_atoms, sf2, E, alpha, Kinv, g):
    """Over the pairs (i > j), with w = α_i α_j − K⁻¹_ij: g[c] = Σ w Δ_c² Σ_{t ∋ atom of c} K_t and
    g[dv + t] = Σ w K_t (g (dv + T,), written). Kinv (n, n) Fortran-ordered, its lower triangle read."""
    dv, n = XT.shape
    T, A = term_atoms.shape
    M = np.empty((A, n))
    w = np.empty(n)
    kt = np.empty(n)
    g[:] = 0.0
    p0 = 0
    for j in range(n):
        L = n - j - 1
        for r in range(L):
            w[r] = alpha[j + 1 + r] * alpha[j] - Kinv[j + 1 + r, j]
        M[:, :L] = 0.0
        for t in range(T):
            for r in range(L):
                kt[r] = sf2[t]
            for a in range(A):
                if term_atoms[t, a]:
                    for r in range(L):
                        kt[r] *= E[a, p0 + r]
            acc = 0.0
            for r in range(L):
                acc += w[r] * kt[r]
            g[dv + t] += acc
            for a in range(A):
                if term_atoms[t, a]:
                    for r in range(L):
                        M[a, r] += kt[r]
        for c in range(dv):
            a, xj = atom_of[c], XT[c, j]
            acc = 0.0
            for r in range(L):
                diff = XT[c, j + 1 + r] - xj
                acc += w[r] * M[a, r] * (diff * diff)
            g[c] += acc
        p0 += L

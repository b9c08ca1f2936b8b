"""The chain identification's normal equations, solved by their block structure (never a dense Jacobian).

The Gauss–Newton Jacobian of :class:`errormap.identification.ChainIdentification` is block-sparse: one sweep
station's nine ball coordinates (a *block*: 3 balls × xyz) see that station's own component errors (its
*locals*, 6 at most, free only there) and a few *globals* (the tracker pose, the constants, the first-station
values of the parked axes, the values tied across stations). The normal matrix is therefore block-diagonal in
the locals with a border of globals; the gauge's linear conditions ``C x = 0`` (k rows) join the border as
Lagrange multipliers (KKT). Per step, every block's (L, L) local matrix ``D_b`` is inverted and the border is
solved through its Schur complement ``S = E − Σ_b B_bᵀ D_b⁻¹ B_b`` ((g + k)², g ≈ 40): CPU and memory linear
in the stations. The covariance over the free parameters is the KKT inverse's parameter block,
``blkdiag(D⁻¹) + Z S⁻¹ Zᵀ`` (``Z = [−D⁻¹B; I]``), the only (unknowns)² array, written once.

Everything is column-scaled as the dense solve was (columns of unit norm). A layout the blocks cannot decide —
a column no ball sees, a local matrix or Schur complement numerically singular — raises :class:`Undecided`, and
the caller falls back to the dense pivoted QR that names the unobservable parameters.
"""
from __future__ import annotations

import numpy as np
from scipy.sparse.linalg import LinearOperator, eigsh

LOCAL_EIG_FLOOR = 1e-10
"""A column-scaled local matrix ``D_b`` (unit diagonal) with an eigenvalue below this is treated as singular."""
SCHUR_RCOND_FLOOR = 1e-12
"""A column-scaled Schur complement whose smallest/largest singular value is below this is treated as singular
(the squared-condition analogue of the dense pivoted QR's 1e-9 rank tolerance, with margin)."""
CONDITION_TOL = 1e-10
"""Relative accuracy of the Lanczos estimates of the extreme eigenvalues behind ``condition``."""


class Undecided(Exception):
    """The block solve cannot decide the rank (the dense pivoted QR must)."""


class BlockLayout:
    """Where every Jacobian entry goes. ``fcols``: per sweep (m, Q) the free parameter of each compact column
    (−1: none); ``nfree``: free parameters. Attributes: ``nb`` blocks, ``L`` locals per block (padded), ``ng``
    globals, ``loc`` (nb, L) free index of each local (−1: pad), ``glob`` (ng,) free index of each global."""

    def __init__(self, fcols: list, nfree: int):
        b0 = np.cumsum([0] + [f.shape[0] for f in fcols])
        self.nb = int(b0[-1])
        ent_b = np.concatenate([np.repeat(np.arange(f.shape[0]) + o, f.shape[1]) for f, o in zip(fcols, b0)])
        ent_f = np.concatenate([f.ravel() for f in fcols])
        ok = ent_f >= 0
        pairs = np.unique(ent_b[ok] * nfree + ent_f[ok])
        if pairs.size != ok.sum():
            raise Undecided("a parameter enters one station block twice")
        touched = np.bincount(pairs % nfree, minlength=nfree)
        if (touched == 0).any():
            raise Undecided("a parameter no ball sees")
        self.is_local = touched == 1
        self.glob = np.flatnonzero(~self.is_local)
        self.ng = self.glob.size
        gpos = np.full(nfree, -1)
        gpos[self.glob] = np.arange(self.ng)
        lb = pairs // nfree
        lf = pairs % nfree
        lmask = self.is_local[lf]
        lb, lf = lb[lmask], lf[lmask]                       # sorted by block, then by free index
        counts = np.bincount(lb, minlength=self.nb)
        self.L = int(max(counts.max(initial=0), 1))
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        lpos = np.arange(lb.size) - start[lb]
        self.loc = np.full((self.nb, self.L), -1)
        self.loc[lb, lpos] = lf
        self.block_of, self.pos_of = np.full(nfree, -1), np.full(nfree, -1)
        self.block_of[lf], self.pos_of[lf] = lb, lpos
        self.gpos = gpos
        self.scatter = []                                    # per sweep: (i, q, b, pos) locals, (i, q, b, g) globals
        for f, o in zip(fcols, b0):
            i, q = np.nonzero(f >= 0)
            fv = f[i, q]
            loc = self.is_local[fv]
            self.scatter.append(((i[loc], q[loc], self.block_of[fv[loc]], self.pos_of[fv[loc]]),
                                 (i[~loc], q[~loc], i[~loc] + o, gpos[fv[~loc]])))

    def assemble(self, vals: list) -> tuple:
        """``vals`` per sweep (m, 9, Q) → ``JL`` (nb, 9, L), ``JG`` (nb, 9, ng)."""
        JL = np.zeros((self.nb, 9, self.L))
        JG = np.zeros((self.nb, 9, self.ng))
        for v, ((i, q, b, p), (gi, gq, gb, g)) in zip(vals, self.scatter):
            JL[b, :, p] = v[i, :, q]
            JG[gb, :, g] = v[gi, :, gq]
        return JL, JG


class BlockNormal:
    """The column-scaled KKT system of one linearisation. ``JL``/``JG`` from :meth:`BlockLayout.assemble`;
    ``C`` (k, nfree) the gauge's conditions on the free parameters (independent rows)."""

    def __init__(self, lay: BlockLayout, JL, JG, C):
        self.lay = lay
        pad = lay.loc < 0
        sL = np.sqrt(np.einsum("bri,bri->bi", JL, JL))
        sG = np.sqrt(np.einsum("bri,bri->i", JG, JG))
        if (sL[~pad] == 0).any() or (sG == 0).any():
            raise Undecided("a parameter with a zero Jacobian column")
        sL[pad] = 1.0
        self.sL, self.sG = sL, sG
        self.JL, self.JG = JL / sL[:, None, :], JG / sG
        D = np.einsum("bri,brj->bij", self.JL, self.JL)
        D[pad] = 0.0
        D[..., np.arange(lay.L), np.arange(lay.L)] += pad   # pads: identity, no coupling
        if np.linalg.eigvalsh(D)[:, 0].min() < LOCAL_EIG_FLOOR:
            raise Undecided("a station's own parameters are not determined by its balls")
        s_free = np.ones(lay.gpos.size)
        s_free[lay.loc[~pad]] = sL[~pad]
        s_free[lay.glob] = sG
        Cs = np.asarray(C, float) / s_free if np.size(C) else np.zeros((0, s_free.size))
        if Cs.shape[0]:
            Cs = Cs / np.linalg.norm(Cs, axis=1, keepdims=True)
        self.k = Cs.shape[0]
        CL = np.where(pad[..., None], 0.0, Cs.T[np.maximum(lay.loc, 0)])            # (nb, L, k)
        self._CL, self._Cg = CL, Cs[:, lay.glob]
        B = np.concatenate([np.einsum("bri,brg->big", self.JL, self.JG), CL], axis=2)  # (nb, L, ng + k)
        E = np.zeros((lay.ng + self.k, lay.ng + self.k))
        E[:lay.ng, :lay.ng] = np.einsum("brg,brh->gh", self.JG, self.JG)
        E[lay.ng:, :lay.ng] = Cs[:, lay.glob]
        E[:lay.ng, lay.ng:] = Cs[:, lay.glob].T
        self.Dinv = np.linalg.inv(D)
        self.W = self.Dinv @ B                                                        # (nb, L, ng + k)
        S = E - np.einsum("bij,bik->jk", B, self.W)
        sv = np.linalg.svd(S, compute_uv=False)
        if sv[-1] < SCHUR_RCOND_FLOOR * sv[0]:
            raise Undecided("the bordered system is singular")
        self.Sinv = np.linalg.inv(S)
        self.Sinv = (self.Sinv + self.Sinv.T) / 2
        self.pad = pad

    def _unscale(self, xL, xG) -> np.ndarray:
        lay = self.lay
        x = np.zeros(lay.gpos.size)
        x[lay.loc[~self.pad]] = (xL / self.sL)[~self.pad]
        x[lay.glob] = xG / self.sG
        return x

    def solve(self, r) -> np.ndarray:
        """The constrained least-squares step (nfree,) for the residual ``r`` (nb·9,)."""
        rb = np.asarray(r, float).reshape(self.lay.nb, 9)
        gL = np.einsum("bri,br->bi", self.JL, rb)
        gG = np.concatenate([np.einsum("brg,br->g", self.JG, rb), np.zeros(self.k)])
        y = self.Sinv @ (gG - np.einsum("bij,bi->j", self.W, gL))
        xL = np.einsum("bij,bj->bi", self.Dinv, gL) - self.W @ y
        return self._unscale(xL, y[:self.lay.ng])

    def leverage(self) -> np.ndarray:
        """The constrained fit's hat-matrix diagonal (nb·9,) of every ball coordinate."""
        a = np.einsum("bri,bij,brj->br", self.JL, self.Dinv, self.JL)
        u = np.concatenate([self.JG, np.zeros(self.JG.shape[:2] + (self.k,))], axis=2)
        u = u - np.einsum("bij,bri->brj", self.W, self.JL)
        return (a + np.einsum("brj,jk,brk->br", u, self.Sinv, u)).reshape(-1)

    def covariance(self, free_theta, var: float) -> np.ndarray:
        """``var`` times the KKT inverse's parameter block, mapped to the parameters ``free_theta`` (N,) (their
        free index, −1: held at zero; tied ones share one): (N, N)."""
        lay, ng = self.lay, self.lay.ng
        f = np.asarray(free_theta)
        Z = np.zeros((f.size, ng + self.k))
        is_loc = (f >= 0) & lay.is_local[np.maximum(f, 0)]
        is_glb = (f >= 0) & ~is_loc
        if np.unique(f[is_loc]).size != is_loc.sum():
            raise Undecided("a station's own parameter stands for two")
        b, p = lay.block_of[f[is_loc]], lay.pos_of[f[is_loc]]
        Z[is_loc] = -self.W[b, p] / self.sL[b, p][:, None]
        g = lay.gpos[f[is_glb]]
        Z[np.flatnonzero(is_glb), g] = 1.0 / self.sG[g]
        cov = (Z @ (var * self.Sinv)) @ Z.T
        rows = np.full((lay.nb, lay.L), -1)                    # N-index of each local (each local is one θ)
        rows[b, p] = np.flatnonzero(is_loc)
        ok = rows >= 0
        pair = ok[:, :, None] & ok[:, None, :]
        R = np.broadcast_to(rows[:, :, None], pair.shape)[pair]
        Cc = np.broadcast_to(rows[:, None, :], pair.shape)[pair]
        cov[R, Cc] += (var * self.Dinv / (self.sL[:, :, None] * self.sL[:, None, :]))[pair]
        return cov

    def condition(self) -> float:
        """Condition of the column-scaled Jacobian on the gauge's subspace: √(λmax(P·JᵀJ·P)·λmax(M)), M the
        scaled KKT inverse's parameter block (λmax(M) = 1/λmin), P the projector on ``C x = 0``; Lanczos
        (:func:`scipy.sparse.linalg.eigsh`) with a fixed start vector."""
        lay, nb, L, ng = self.lay, self.lay.nb, self.lay.L, self.lay.ng
        n = nb * L + ng
        keep = np.concatenate([(~self.pad).ravel().astype(float), np.ones(ng)])
        Q = None
        if self.k:
            Cfull = np.concatenate([self._CL.reshape(nb * L, self.k).T, self._Cg], axis=1)
            Q = np.linalg.qr(Cfull.T)[0].T

        def proj(v):
            v = v * keep
            return v if Q is None else v - Q.T @ (Q @ v)

        def hess(v):
            v = proj(v)
            vL, vG = v[:nb * L].reshape(nb, L), v[nb * L:]
            Jv = np.einsum("bri,bi->br", self.JL, vL) + self.JG @ vG
            return proj(np.concatenate([np.einsum("bri,br->bi", self.JL, Jv).ravel(),
                                        np.einsum("brg,br->g", self.JG, Jv)]))

        def minv(v):
            v = v * keep
            vL, vG = v[:nb * L].reshape(nb, L), v[nb * L:]
            u = self.Sinv @ (np.concatenate([vG, np.zeros(self.k)]) - np.einsum("bij,bi->j", self.W, vL))
            out = np.concatenate([(np.einsum("bij,bj->bi", self.Dinv, vL) - self.W @ u).ravel(), u[:ng]])
            return out * keep

        v0 = keep / np.linalg.norm(keep)
        top = [float(eigsh(LinearOperator((n, n), matvec=op, dtype=float), k=1, which="LA", v0=v0,
                           tol=CONDITION_TOL, return_eigenvectors=False)[0]) if n > 2 else
               float(np.linalg.eigvalsh(np.column_stack([op(e) for e in np.eye(n)]))[-1]) for op in (hess, minv)]
        return float(np.sqrt(top[0] * top[1]))

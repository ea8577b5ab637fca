"""Parameter blocks, residual blocks and the normal equations they sum into.

The bundle adjustment is written as residual blocks over named parameter blocks, so a
new kind of residual (gyroscope, accelerometer, a clock offset, a rolling-shutter line
delay: docs/formats.md#motion-datasets) plugs in with its own residual function, Jacobian and
parameter blocks, and the solver stays as it is:

- `ParameterBlocks` is the registry: every parameter block (family, index, size, held),
  the column of each estimated one, and the family the Schur step eliminates (the
  frame poses in the rig problem): its blocks come last, all of one size, and a residual
  row touches at most one of them, so J^T J is block-diagonal there.
- A residual block (`ResidualBlock`) gives its residuals, and its Jacobian as
  `JacobianChunk`s: rows, their derivatives over kept columns (shared by every row of
  the chunk, one dense product, or per row) and over one eliminated block per row.
- `sum_normal_equations` adds the chunks of every block into `NormalEquations`
  (J^T W J and J^T W r split into kept and eliminated parts) without ever holding the
  whole Jacobian; `NormalEquations.solve` does the Schur step.

A block never sees the solver's weights: the solver whitens each chunk with the rows'
square-root weights (corner noise, robust loss), so a block is a pure function of x.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Protocol

import numpy as np
import scipy.sparse as sp
from threadpoolctl import threadpool_limits


@dataclass(frozen=True)
class ParameterBlock:
    """One named group of unknowns: family (e.g. 'frame'), index within its family, size
    (its number of columns when estimated), held (kept at its value: no columns)."""

    family: str
    index: int
    size: int
    held: bool = False


@dataclass(frozen=True)
class ParameterBlocks:
    """The registry: every parameter block in column order (held ones take none),
    `starts` family -> (n,) first column of each of its blocks (-1: held), `size` the
    number of columns, `eliminated` the family the Schur step removes (or None), whose
    columns start at `split` and come in blocks of `elim_size`. Build with `register`."""

    blocks: tuple
    starts: dict
    size: int
    eliminated: str | None
    split: int
    elim_size: int

    def slices(self, family: str) -> tuple:
        """Per block of `family` (by index) its column slice, None when held."""
        sizes = {b.index: b.size for b in self.blocks if b.family == family}
        starts = self.starts.get(family, ())  # a family with no blocks (a rig without frames)
        return tuple(None if s < 0 else slice(int(s), int(s) + sizes[i]) for i, s in enumerate(starts))


def register(blocks: list[ParameterBlock], eliminated: str | None = None) -> ParameterBlocks:
    """The registry of `blocks` (a family's indices 0..n-1, each once): columns in the
    order given, the eliminated family's blocks moved last (it must be all one size and
    have none held: the Schur step inverts each of its blocks)."""
    kept = [b for b in blocks if b.family != eliminated]
    elim = [b for b in blocks if b.family == eliminated]
    if elim and (len({b.size for b in elim}) != 1 or any(b.held for b in elim)):
        raise ValueError(f"eliminated family {eliminated!r}: blocks must be one size and none held")
    counts: dict = {}
    for b in blocks:
        counts[b.family] = counts.get(b.family, 0) + 1
    starts = {f: np.full(n, -1, dtype=np.int64) for f, n in counts.items()}
    k = 0
    for b in kept + elim:
        if not b.held:
            starts[b.family][b.index] = k
            k += b.size
    split = int(starts[eliminated][0]) if elim else k
    return ParameterBlocks(tuple(kept + elim), starts, k, eliminated, split, elim[0].size if elim else 0)


@dataclass(frozen=True)
class JacobianChunk:
    """The (unweighted) Jacobian of some rows of one residual block. rows (m,): the rows,
    in the block's residual order, each of D residuals (a corner's u, v: D = 2);
    J_a (m, D, K) over the kept parameters at columns cols_a: (K,) when every row has the
    same (distinct) columns (summed as one dense product: a run of one camera and one
    board), or (m, K) per row; -1 marks a held column. J_e (m, D, E) over the eliminated block e (m,)
    of each row (rows of one block adjacent, for speed), or both None."""

    rows: np.ndarray
    J_a: np.ndarray
    cols_a: np.ndarray
    J_e: np.ndarray | None = None
    e: np.ndarray | None = None


class ResidualBlock(Protocol):
    """A kind of residual over the parameter vector x: n_rows rows of dim (D) residuals."""

    dim: int
    n_rows: int

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """(m, D) residuals at x (unweighted)."""

    def jacobian_chunks(self, x: np.ndarray) -> Iterator[JacobianChunk]:
        """Its Jacobian at x, every row in exactly one chunk."""


@dataclass
class NormalEquations:
    """J^T W J and J^T W r split into the kept part (a) and the block-diagonal eliminated
    part (d), built once per iteration (sum_normal_equations, or from_jacobian from a
    whole Jacobian); solve() then costs one small dense solve per damping value.
    g_a (n_a,), g_d (E F,), H_aa (n_a, n_a), H_ad (n_a, E F), H_dd (F, E, E)."""

    g_a: np.ndarray
    g_d: np.ndarray
    H_aa: np.ndarray
    H_ad: np.ndarray
    H_dd: np.ndarray

    @classmethod
    def zeros(cls, n_a: int, n_blocks: int, size: int) -> "NormalEquations":
        """All-zero sums for n_a kept columns and n_blocks eliminated blocks of `size`."""
        n_d = n_blocks * size
        return cls(np.zeros(n_a), np.zeros(n_d), np.zeros((n_a, n_a)), np.zeros((n_a, n_d)),
                   np.zeros((n_blocks, size, size)))

    @classmethod
    def from_jacobian(cls, J: sp.csr_matrix, r: np.ndarray, w: np.ndarray, split: int,
                      size: int = 6) -> "NormalEquations":
        """From the whole sparse Jacobian (rows, columns), eliminated blocks of `size` from
        column `split` on: the plain construction, kept as the reference the chunked sums
        are tested against."""
        sw = np.sqrt(w)
        J = sp.csr_matrix(J)
        # row scaling straight on the CSR values (a diagonal matrix product copies twice)
        Jw = sp.csr_matrix((J.data * np.repeat(sw, np.diff(J.indptr)), J.indices, J.indptr), shape=J.shape).tocsc()
        rw = sw * r
        Ja = Jw[:, :split]
        Jd = Jw[:, split:]
        return cls(Ja.T @ rw, Jd.T @ rw, (Ja.T @ Ja).toarray(), (Ja.T @ Jd).toarray(), _diagonal_blocks(Jd.T @ Jd, size))

    def solve(self, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """Solve (H + lam diag(H)) dx = -g with the eliminated blocks removed by their
        Schur complement; returns (dx, the Schur complement S)."""
        H_aa = self.H_aa.copy()
        d = np.diag_indices_from(H_aa)
        H_aa[d] = H_aa[d] * (1.0 + lam) + 1e-12
        blocks = self.H_dd.copy()
        diag = np.einsum("fii->fi", blocks)
        diag *= 1.0 + lam
        diag += 1e-12  # a frame left without observations stays put instead of blowing up
        if lam > 0:
            Hinv = np.linalg.inv(blocks)
        else:
            # Marginalising (covariance): a frame left with 1-3 corners is rank-deficient; its
            # pseudo-inverse lets those corners inform nothing, instead of an inverse of noise.
            Hinv = np.linalg.pinv(blocks, rcond=1e-10, hermitian=True)
        nF, E = Hinv.shape[:2]
        n_a = len(H_aa)
        # batched matmul per eliminated block (einsum without BLAS was the slowest line here)
        T = np.matmul(self.H_ad.reshape(n_a, nF, E).transpose(1, 0, 2), Hinv).transpose(1, 0, 2).reshape(n_a, E * nF)
        S = H_aa - T @ self.H_ad.T
        rhs = -(self.g_a - T @ self.g_d)
        dx_a = np.linalg.solve(S, rhs) if n_a else np.zeros(0)
        g_d2 = -(self.g_d + self.H_ad.T @ dx_a)
        dx_d = np.matmul(Hinv, g_d2.reshape(nF, E, 1)).ravel()
        return np.concatenate([dx_a, dx_d]), S


def _diagonal_blocks(H_dd: sp.spmatrix, size: int) -> np.ndarray:
    """(F, size, size) diagonal blocks of the eliminated part of J^T J."""
    nF = H_dd.shape[0] // size
    blocks = np.zeros((nF, size, size))
    coo = H_dd.tocoo()
    same = (coo.row // size) == (coo.col // size)
    np.add.at(blocks, (coo.row[same] // size, coo.row[same] % size, coo.col[same] % size), coo.data[same])
    return blocks


def outer_rows(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(m, i, j) A[m]^T B[m] for A (m, D, i), B (m, D, j): written out over the D rows,
    because numpy's stacked matmul of tiny matrices took 10 us a corner (60-camera dome)."""
    out = A[:, 0, :, None] * B[:, 0, None, :]
    for d in range(1, A.shape[1]):
        out += A[:, d, :, None] * B[:, d, None, :]
    return out


def _add_eliminated(ne: NormalEquations, D: np.ndarray, e: np.ndarray, rw: np.ndarray) -> tuple:
    """Add whitened eliminated-block rows D (m, D, E) of blocks e (m,) to H_dd, g_d.
    Returns (run starts, block of each run) for the coupling sums."""
    starts = np.concatenate([[0], np.flatnonzero(np.diff(e)) + 1])
    ue = e[starts]
    E = D.shape[2]
    if len(ue) > 1 and np.any(np.diff(ue) <= 0):  # a block in two runs: += on fancy indices would drop one
        np.add.at(ne.H_dd, ue, np.add.reduceat(outer_rows(D, D), starts))
        np.add.at(ne.g_d.reshape(-1, E), ue, np.add.reduceat(np.einsum("mki,mk->mi", D, rw), starts))
    else:
        ne.H_dd[ue] += np.add.reduceat(outer_rows(D, D), starts)
        ne.g_d.reshape(-1, E)[ue] += np.add.reduceat(np.einsum("mki,mk->mi", D, rw), starts)
    return starts, ue


def _add_shared(ne: NormalEquations, A: np.ndarray, ca: np.ndarray, rw: np.ndarray, D, runs) -> None:
    """Kept columns ca (K,) shared by every row, whitened A (m, D, K): one dense product."""
    A2 = A.reshape(-1, len(ca))
    ne.H_aa[np.ix_(ca, ca)] += A2.T @ A2
    ne.g_a[ca] += A2.T @ rw.ravel()
    if D is None:
        return
    starts, ue = runs
    X = np.add.reduceat(outer_rows(A, D), starts)  # (runs, K, E)
    H_ad = ne.H_ad.reshape(len(ne.g_a), -1, D.shape[2])
    if len(ue) > 1 and np.any(np.diff(ue) <= 0):
        np.add.at(H_ad, (ca[:, None], ue[None, :]), X.transpose(1, 0, 2))
    else:
        H_ad[ca[:, None], ue[None, :]] += X.transpose(1, 0, 2)


def _add_per_row(ne: NormalEquations, A: np.ndarray, cols: np.ndarray, rw: np.ndarray, D, e) -> None:
    """Kept columns cols (m, K) per row (-1 held), whitened A (m, D, K): scattered sums
    (np.add.at), for blocks whose rows touch different parameters (e.g. spline knots)."""
    held = cols < 0
    A = np.where(held[:, None, :], 0.0, A)  # a held column adds zeros, to column 0
    c = np.where(held, 0, cols)
    np.add.at(ne.H_aa, (c[:, :, None], c[:, None, :]), outer_rows(A, A))
    np.add.at(ne.g_a, c, np.einsum("mki,mk->mi", A, rw))
    if D is not None:
        H_ad = ne.H_ad.reshape(len(ne.g_a), -1, D.shape[2])
        np.add.at(H_ad, (c, e[:, None]), outer_rows(A, D))


def add_chunk(ne: NormalEquations, chunk: JacobianChunk, sw: np.ndarray, rw: np.ndarray) -> None:
    """Add one chunk to `ne`; sw (m, D) the rows' square-root weights, rw (m, D) their
    weighted residuals."""
    D = None if chunk.J_e is None else chunk.J_e * sw[:, :, None]
    runs = None if D is None else _add_eliminated(ne, D, chunk.e, rw)
    cols = chunk.cols_a
    if cols.shape[-1] == 0:
        return
    A = chunk.J_a * sw[:, :, None]
    if cols.ndim == 1:
        keep = cols >= 0
        if not keep.all():
            A, cols = A[:, :, keep], cols[keep]
            if len(cols) == 0:
                return
        _add_shared(ne, A, cols, rw, D, runs)
    else:
        _add_per_row(ne, A, cols, rw, D, chunk.e)


def sum_normal_equations(blocks: list, params: ParameterBlocks, x: np.ndarray, e: np.ndarray,
                         w: np.ndarray) -> NormalEquations:
    """J^T W J and J^T W e at x over every residual block in order: e (n,) the residuals
    of all blocks concatenated (each block's rows, row-major), w (n,) their weights.
    Chunk by chunk: memory is the chunk's, never the whole Jacobian's."""
    n_blocks = (params.size - params.split) // params.elim_size if params.elim_size else 0
    ne = NormalEquations.zeros(params.split, n_blocks, params.elim_size)
    sw_all, rw_all = np.sqrt(w), np.sqrt(w) * e
    offset = 0
    # One BLAS thread for the per-chunk products: they are small (a run's 2m x ~21
    # columns), and OpenBLAS's threads on them cost 10-100x their arithmetic in
    # synchronisation, worst on a busy machine (docs/accuracy.md, A 60-camera dome).
    with threadpool_limits(1, user_api="blas"):
        for block in blocks:
            n = block.n_rows * block.dim
            sw = sw_all[offset:offset + n].reshape(-1, block.dim)
            rw = rw_all[offset:offset + n].reshape(-1, block.dim)
            for chunk in block.jacobian_chunks(x):
                add_chunk(ne, chunk, sw[chunk.rows], rw[chunk.rows])
            offset += n
    return ne


def sparse_jacobian(blocks: list, params: ParameterBlocks, x: np.ndarray) -> sp.csr_matrix:
    """The whole sparse Jacobian (every block's residuals in order, params.size columns),
    from the same chunks: for tests and small problems."""
    rows, cols, vals = [], [], []
    offset = 0
    for block in blocks:
        for ch in block.jacobian_chunks(x):
            m, dim = ch.J_a.shape[:2]
            r0 = offset + ch.rows[:, None] * dim + np.arange(dim)  # (m, D)
            ca = np.broadcast_to(ch.cols_a, (m, ch.cols_a.shape[-1]))
            parts = [(ch.J_a, ca)]
            if ch.J_e is not None:
                E = ch.J_e.shape[2]
                parts.append((ch.J_e, params.split + ch.e[:, None] * E + np.arange(E)))
            for J, c in parts:
                rr = np.broadcast_to(r0[:, :, None], J.shape)
                cc = np.broadcast_to(c[:, None, :], J.shape)
                keep = cc >= 0
                rows.append(rr[keep])
                cols.append(cc[keep])
                vals.append(J[keep])
        offset += block.n_rows * block.dim
    if not vals:
        return sp.csr_matrix((offset, params.size))
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(offset, params.size))

"""Fitting K code columns at once: closed-form multi-output ridge, or liblinear per column.

Both return the same :class:`CodeFit`: for every column k a hyperplane on the d' kept columns of
the (front-end transformed) map, written as ``margin_k(x) = (x − μ)·w_k + c_k`` — μ the map's
column means — so that the estimator can quantise w and fold μ into a bias afterwards
(``bias_k = c_k − μ·w_k`` computed from the *stored* weights, as :mod:`btel.learning.linear` does).

**Ridge** (``solver='ridge'``, the default of :class:`btel.methods.codes.estimator.CodeLocalizer`):
all K columns solve one least-squares problem with a shared regulariser,

    W = argmin ‖X_c W − C_c‖² + α‖W‖²,   X_c = X − μ (rows), C_c = C − c̄ (codes ±1, centred),

in closed form from the eigendecomposition of the smaller Gram matrix: the primal
``X_cᵀX_c = V Λ Vᵀ`` (d' × d') when the map has more rows than kept columns, giving
``W = V (Λ + α)⁻¹ Vᵀ X_cᵀ C_c``; the dual (kernel) ``X_c X_cᵀ = U Λ Uᵀ`` (n × n) otherwise, giving
``W = X_cᵀ U (Λ + α)⁻¹ Uᵀ C_c``. The codes are generated chunk by chunk, so X_cᵀC is accumulated
without holding the (n, K) code matrix (a million places × 1024 columns would be 1 GB); the
column groups are independent tasks on threads, processes or a Dask cluster
(:func:`btel.learning.distributed.fit_backend`), like BTEL's classifier fits.

Regularisation rule (fixed in advance, the same on every map): ``α = ρ · tr(X_cᵀX_c) / rank`` —
ρ = :data:`RELATIVE_ALPHA` (0.1) times the mean non-zero eigenvalue of the centred Gram matrix, so the
rule is invariant to the scale of the descriptors. Why 0.1 and not the value generalised
cross-validation picks, with the study's table: ``docs/decisions/codes-ridge.md``.

**liblinear** (``solver='liblinear'``): one linear SVM per column on the column's sign
(:func:`btel.learning.training.fit_tasks`, standardised columns folded into the weights), the K fits in
parallel as BTEL's bit classifiers are. Slower (an iterative fit per column) and it needs both
signs in a column; kept as the solver BTE-C uses, for comparison.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .codebook import Codebook
from ...learning.distributed import fit_backend
from ...learning.linear import ColumnStats
from ...core.threads import blas_threads as limit_blas
from ...learning.training import Task, fit_tasks

__all__ = ["CodeFit", "RELATIVE_ALPHA", "ridge_alpha", "fit_ridge_codes", "fit_liblinear_codes"]

#: ρ of the regularisation rule α = ρ · mean non-zero eigenvalue of the centred Gram matrix.
RELATIVE_ALPHA = 0.1
#: Rows of the map read at a time at most (bounds the float64 temporaries on large, memory-mapped maps) ...
_CHUNK_ROWS = 32768
#: ... and at most this many values in one float64 temporary (rows × kept columns, rows × code columns):
#: 32 MB, so wide maps and large K (a budget of megabytes) stay bounded too.
_CHUNK_VALUES = 1 << 22


def _chunk_rows(width: int) -> int:
    """Rows per chunk for temporaries of ``width`` float64 columns."""
    return max(1, min(_CHUNK_ROWS, _CHUNK_VALUES // max(int(width), 1)))


@dataclass
class CodeFit:
    """K fitted code columns on d' kept descriptor columns.

    Attributes
    ----------
    weights : ndarray of shape (K, d'), float64
    offsets : ndarray of shape (K,), float64
        c_k: ``margin_k(x) = (x − center)·w_k + c_k``.
    center : ndarray of shape (d',), float64
        μ, the map's mean of the kept columns.
    alpha : float
        The ridge regularisation used (NaN for liblinear).
    n_unconverged : int
        liblinear fits that stopped at max_iter (0 for ridge).
    """

    weights: np.ndarray
    offsets: np.ndarray
    center: np.ndarray
    alpha: float
    n_unconverged: int = 0


def _row_codes(codebook: Codebook, places: np.ndarray | None, start: int, stop: int,
               columns: np.ndarray | slice | None = None) -> np.ndarray:
    """Codewords (float64) of map rows start:stop (row i is place i when ``places`` is None)."""
    where = np.arange(start, stop) if places is None else places[start:stop]
    return codebook.codewords(where, columns).astype(np.float64)


def _kept(rows: Any, cols: np.ndarray) -> np.ndarray:
    """The kept columns of a block of map rows, float64 (an ndarray, a memory map or lazily scaled rows)."""
    return np.asarray(rows)[:, cols].astype(np.float64)


def _column_sums(X: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(μ, XᵀX) of the kept columns, float64, accumulated over row chunks."""
    d = cols.size
    total, gram = np.zeros(d), np.zeros((d, d))
    step = _chunk_rows(d)
    for a in range(0, X.shape[0], step):
        block = _kept(X[a : a + step], cols)
        total += block.sum(axis=0)
        gram += block.T @ block
    return total / X.shape[0], gram


def _cross_products(X: np.ndarray, cols: np.ndarray, codebook: Codebook, places: np.ndarray | None,
                    group: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(XᵀC, Σ C) for one group of code columns, (d', g) and (g,) float64, over row chunks."""
    cross, sums = np.zeros((cols.size, group.size)), np.zeros(group.size)
    step = _chunk_rows(max(cols.size, group.size))
    for a in range(0, X.shape[0], step):
        b = min(X.shape[0], a + step)
        block = _kept(X[a:b], cols)
        codes = _row_codes(codebook, places, a, b, group)
        cross += block.T @ codes
        sums += codes.sum(axis=0)
    return cross, sums


def ridge_alpha(eigenvalues: np.ndarray, alpha: float | None) -> float:
    """α: the given value, or the rule ρ · (mean non-zero eigenvalue) (module docstring)."""
    if alpha is not None:
        return float(alpha)
    lam = np.maximum(np.asarray(eigenvalues, dtype=np.float64), 0.0)
    top = float(lam.max()) if lam.size else 0.0
    if top <= 0:  # a constant map: any positive α gives the zero solution
        return 1.0
    rank = int(np.sum(lam > 1e-10 * top))
    return RELATIVE_ALPHA * float(lam.sum()) / max(rank, 1)


def _groups(n_codes: int, n_jobs: int | None) -> list[np.ndarray]:
    """Column groups: one per worker (at least 64 columns each, so BLAS products stay large)."""
    workers = 1 if n_jobs in (None, 1) else max(2, abs(int(n_jobs)) if n_jobs != -1 else 8)
    n_groups = max(1, min(workers, n_codes // 64))
    return [g for g in np.array_split(np.arange(n_codes), n_groups) if g.size]


def fit_ridge_codes(X: np.ndarray, cols: np.ndarray, codebook: Codebook, places: np.ndarray | None, *,
                    alpha: float | None = None, n_jobs: int | None = None, backend: str | None = None,
                    scheduler: str | None = None) -> CodeFit:
    """Closed-form multi-output ridge of every code column on the kept columns (module docstring).

    Parameters
    ----------
    X : ndarray of shape (n_rows, d), float32 (may be memory-mapped), or ScaledRows
        Read in row blocks only: lazily L2-normalised rows are scaled block by block.
    cols : ndarray of shape (d',), int
        Kept columns.
    codebook : Codebook
    places : ndarray of shape (n_rows,), int64, or None (row i is place i)
    alpha : float, optional
        α itself; None applies the rule.

    Returns
    -------
    CodeFit
    """
    n_rows, d_sel, K = X.shape[0], cols.size, codebook.n_codes
    if n_rows <= d_sel:  # dual (kernel) form: the n × n Gram matrix is the smaller one
        Xs = _kept(X, cols)
        center = Xs.mean(axis=0)
        Xs -= center
        lam, U = np.linalg.eigh(Xs @ Xs.T)
        a = ridge_alpha(lam, alpha)
        C = _row_codes(codebook, places, 0, n_rows)
        code_mean = C.mean(axis=0)
        C -= code_mean
        A = U @ ((U.T @ C) / (np.maximum(lam, 0.0) + a)[:, None])
        return CodeFit(weights=(Xs.T @ A).T, offsets=code_mean, center=center, alpha=a)
    # Primal form: d' × d' Gram and d' × K cross products, accumulated over row chunks.
    from joblib import Parallel, delayed  # fit-only: a loaded model never imports joblib

    groups = _groups(K, n_jobs)
    blas_threads = None if n_jobs in (None, 1) else 1
    calls = [delayed(_column_sums)(X, cols)] + [delayed(_cross_products)(X, cols, codebook, places, g)
                                                for g in groups]
    with fit_backend(backend, scheduler, scatter=[X]), limit_blas(blas_threads):
        results = Parallel(n_jobs=n_jobs, prefer="threads")(calls)
    center, gram = results[0]
    cross = np.concatenate([r[0] for r in results[1:]], axis=1)
    code_mean = np.concatenate([r[1] for r in results[1:]]) / n_rows
    gram -= n_rows * np.outer(center, center)
    cross -= n_rows * np.outer(center, code_mean)  # X_cᵀ C_c = XᵀC − n μ c̄ᵀ
    lam, V = np.linalg.eigh(gram)
    a = ridge_alpha(lam, alpha)
    W = V @ ((V.T @ cross) / (np.maximum(lam, 0.0) + a)[:, None])
    return CodeFit(weights=W.T, offsets=code_mean, center=center, alpha=a)


def fit_liblinear_codes(X: np.ndarray, cols: np.ndarray, codebook: Codebook, places: np.ndarray | None, *,
                        C: float = 1.0, max_iter: int = 1000, random_state: int | None = 0,
                        n_jobs: int | None = None, backend: str | None = None,
                        scheduler: str | None = None) -> CodeFit:
    """One linear SVM per code column (liblinear, squared hinge) on the kept columns, in parallel.

    A column with a single sign over the map (possible for a long period on a short map) gets zero
    weights and offset ±1: it predicts its constant value.

    Returns
    -------
    CodeFit
    """
    n_rows, K = X.shape[0], codebook.n_codes
    codes = np.concatenate([codebook.codewords(np.arange(a, min(n_rows, a + _CHUNK_ROWS)) if places is None
                                               else places[a : a + _CHUNK_ROWS])
                            for a in range(0, n_rows, _CHUNK_ROWS)])
    stats = ColumnStats.of(X)
    center = stats.mean[cols]
    weights = np.zeros((K, cols.size))
    offsets = np.zeros(K)
    varying = [k for k in range(K) if np.unique(codes[:, k]).size == 2]
    for k in set(range(K)) - set(varying):
        offsets[k] = float(codes[0, k])
    tasks = [Task(labels=(codes[:, k] > 0).astype(np.int64), columns=cols) for k in varying]
    # solver='liblinear': this option is liblinear per column by name (btel's Newton/L-BFGS solvers
    # reach the same optimum of the same objective; the closed-form ridge is the default anyway).
    parts, summary = fit_tasks(X, tasks, cols.size, stats, sparsity=1.0, n_jobs=n_jobs, backend=backend,
                               scheduler=scheduler, classifier="svm", C=float(C), solver="liblinear",
                               max_iter=int(max_iter), random_state=random_state, dtype=np.dtype(np.float64))
    for k, (w, bias, _) in zip(varying, parts):
        weights[k] = w[0]
        offsets[k] = float(bias[0]) + float(w[0] @ center)  # fit_linear's bias is c − w·μ
    return CodeFit(weights=weights, offsets=offsets, center=center, alpha=float("nan"),
                   n_unconverged=int(summary.n_unconverged))


"""Linear classifiers on selected, standardised columns, with the scaling folded in (SPEC §3).

Descriptors are standardised with training statistics (μ, σ) before a classifier is trained,
and the scaling is folded into the hyperplane so it costs no storage:
``w' = w/σ`` and ``c' = c − Σ w'·μ``. The bias is computed from the *stored* (possibly float16)
weights, so rounding the weights does not shift the decision boundary by ``Σ (w' − w16)·μ``.

:class:`Hyperplanes` is a stack of K such classifiers, each on its own d' columns; it computes
all K margins of a batch of queries with one matrix product.

Solvers (``solver``; :data:`SOLVERS`). Every classifier minimises liblinear's primal objective
(the bias is the weight of a constant feature 1, so it is regularised too, as scikit-learn's
``intercept_scaling=1`` does): for ``'svm'`` ``½‖w‖² + ½b² + C Σ sᵢ max(0, 1 − yᵢ(w·xᵢ + b))²``,
for ``'logistic'`` ``½‖w‖² + ½b² + C Σ sᵢ log(1 + exp(−yᵢ(w·xᵢ + b)))`` (sᵢ: sample weights).
Classifiers that read the same rows and columns are solved together on one standardised copy.

- ``'newton'``: Newton's method with an exact line search (for the squared hinge the modified
  finite Newton method of Keerthi & DeCoste, JMLR 2005: it reaches the exact optimum once the set
  of margin violators stops changing). Each step solves one linear system of size
  min(rows, d' + 1): in the primal (d' + 1 ≤ rows) with the (d'+1)² Gram matrix of the rows, or in
  the kernel form with the rows × rows Gram matrix, which is computed once and shared by every
  classifier and step. For the SVM without sample weights, the inverse of ``I/(2C) + K`` is
  shared too and each step factors only min(#violators, #others) rows. Converges to a relative
  gradient norm of :data:`NEWTON_TOL` in 5–40 steps. The form is chosen by a flop count
  (:func:`newton_uses_kernel`: the kernel form when rows ≲ 2·d'). Used by ``'auto'`` when that
  system has at most :data:`NEWTON_MAX_SYSTEM` unknowns.
- ``'lbfgs'``: limited-memory BFGS over all classifiers of a group at once (two matrix products
  per step for all of them, a per-classifier history and exact line search along the step).
  Cheap steps, but on ill-conditioned maps (N ≈ d) it needs thousands of them; used by
  ``'auto'`` for the larger shapes.
- ``'liblinear'``: scikit-learn's ``LinearSVC`` / ``LogisticRegression(solver='liblinear')``,
  dual coordinate descent when rows < 3·d' (the behaviour before the solvers were added; its
  dual solver draws random numbers, see :class:`btel.BTELocalizer`).

On Nordland HOG (N = 3576, d' = d = 3780, 12 bits) liblinear stopped every bit at 1000
iterations with a summed objective 40 % above the optimum that Newton's method reaches
(``benchmarks/bench_fit.py`` measures both, with time).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
from sklearn.exceptions import ConvergenceWarning
from sklearn.linear_model import LogisticRegression
from sklearn.svm import LinearSVC

from ..exceptions import InvalidParameterError, ModelFileError

__all__ = ["ColumnStats", "fit_linear", "fit_linear_group", "standardised_columns", "Hyperplanes", "CLASSIFIERS",
           "SOLVERS", "default_C", "choose_solver", "default_max_iter", "linear_objective", "solve_linear",
           "newton_uses_kernel"]

CLASSIFIERS = ("svm", "logistic")
#: Accepted ``solver`` values ('auto' picks by shape: :func:`choose_solver`).
SOLVERS = ("auto", "newton", "lbfgs", "liblinear")
#: Relative gradient norm ‖∇f(w)‖ ≤ tol·‖∇f(0)‖ at which Newton and L-BFGS stop.
NEWTON_TOL = 1e-5
LBFGS_TOL = 1e-5
#: Largest linear system (min(rows, d' + 1)) for which 'auto' uses Newton's method.
NEWTON_MAX_SYSTEM = 4096
#: Iteration caps when max_iter is None: Newton steps, L-BFGS steps, liblinear iterations.
_DEFAULT_MAX_ITER = {"newton": 100, "lbfgs": 2000, "liblinear": 1000}
#: Optional hook ``trace(solver, iteration, objective (K,), violators (K,))`` called at every
#: Newton / L-BFGS iteration (benchmarks/bench_fit.py records objective against time with it).
TRACE = None


def default_C(classifier: str) -> float:
    """C when the user gives none: 1.0 for the SVM, 4.0 for logistic (the authors' earlier code)."""
    return 4.0 if classifier == "logistic" else 1.0


@dataclass(frozen=True)
class ColumnStats:
    """Training mean and standard deviation of every column (float64, shape (d,))."""

    mean: np.ndarray
    scale: np.ndarray

    @classmethod
    def of(cls, X: np.ndarray, chunk_rows: int = 65536) -> "ColumnStats":
        """Column statistics of X, accumulated in float64 over row chunks (memory-mapped X is fine)."""
        n, d = X.shape
        total = np.zeros(d)
        total_sq = np.zeros(d)
        for start in range(0, n, chunk_rows):
            block = np.asarray(X[start : start + chunk_rows], dtype=np.float64)
            total += block.sum(axis=0)
            total_sq += (block**2).sum(axis=0)
        mean = total / n
        var = np.maximum(total_sq / n - mean**2, 0.0)
        scale = np.sqrt(var)
        # A constant column carries no information; σ = 1 keeps it finite (its BCSS is 0, so it is
        # only ever selected when d' exceeds the number of informative columns).
        floor = 1e-6 * max(float(np.median(scale)), 1e-12)
        scale[scale < floor] = 1.0
        return cls(mean=mean, scale=scale)


def standardised_columns(
    X: np.ndarray, cols: np.ndarray, mean: np.ndarray, scale: np.ndarray, *, chunk_rows: int = 65536,
    dtype: np.dtype = np.dtype(np.float64),
) -> np.ndarray:
    """``(X[:, cols] − mean) / scale`` as a new array (float64 by default), built in row chunks.

    The one (n, d') float64 array liblinear needs is the only large allocation: gathering,
    converting and standardising the whole block at once held three such arrays
    (1.3 GB at N = 1M, d' = 64) per concurrent fit. X may be memory-mapped.
    """
    n = X.shape[0]
    out = np.empty((n, cols.size), dtype=dtype)
    full = cols.size == X.shape[1] and np.array_equal(cols, np.arange(X.shape[1]))
    # Row chunks of at most ~4M values: the float64 temporaries stay at 32 MB per chunk.
    step = max(1, min(int(chunk_rows), (1 << 22) // max(cols.size, 1)))
    for start in range(0, n, step):
        rows = X[start : start + step]
        block = np.array(rows if full else rows[:, cols], dtype=np.float64)
        block -= mean
        block /= scale
        out[start : start + step] = block
    return out


def _use_dual(n_samples: int, n_features: int) -> bool:
    """liblinear's dual solver unless there are at least 3 samples per feature.

    scikit-learn's ``dual="auto"`` switches at n_samples = n_features; on standardised HOG
    (n = 3576) the primal Newton solver took 40–50 s per fit at d' ≈ 1800–2300 against 4–6 s for
    the dual, while at d' ≤ n/3 the primal was 2–8× faster (measured per bit and one-vs-rest task).
    """
    return n_samples < 3 * n_features


def _make_classifier(classifier: str, C: float, max_iter: int, random_state: int | None, dual: bool):
    if classifier == "svm":
        return LinearSVC(C=C, loss="squared_hinge", dual=dual, max_iter=max_iter, random_state=random_state)
    if classifier == "logistic":
        return LogisticRegression(C=C, solver="liblinear", tol=0.01, dual=dual, max_iter=max_iter,
                                  random_state=random_state)
    raise InvalidParameterError(f"classifier must be one of {CLASSIFIERS}; got {classifier!r}.")


def newton_uses_kernel(n_rows: int, n_columns: int, n_classifiers: int = 1, *, shared: bool = True) -> bool:
    """Whether Newton's method solves in the kernel form (rows × rows) rather than the primal ((d'+1)²).

    By a flop count for ~20 steps: the kernel form costs the Gram matrix and its inverse once per
    group (n²d' + n³) plus a factorisation of m rows per classifier and step; the primal form the
    (d'+1)² Gram matrix of m rows plus its factorisation per classifier and step. m is about n/2
    for the squared hinge with the shared inverse (``shared``: the smaller of the margin violators
    and the others), n otherwise (logistic, sample weights).
    """
    n, d, K, steps = float(n_rows), float(n_columns), float(n_classifiers), 20.0
    m = n / 2 if shared else n
    kernel = n * n * d + n**3 + K * steps * m**3 / 3
    primal = n * d * d + K * steps * (m * d * d + d**3 / 3)
    return kernel < primal


def choose_solver(solver: str, n_rows: int, n_columns: int, n_classifiers: int = 1) -> str:
    """The solver 'auto' means for ``n_classifiers`` classifiers on ``n_rows`` rows and d' = ``n_columns``.

    Newton's method when its linear system — rows in the kernel form, d' + 1 in the primal
    (:func:`newton_uses_kernel`) — has at most :data:`NEWTON_MAX_SYSTEM` unknowns (a factorisation
    of 4096² costs ~23 GFLOP), otherwise L-BFGS.
    """
    if solver not in SOLVERS:
        raise InvalidParameterError(f"solver must be one of {SOLVERS}; got {solver!r}.")
    if solver != "auto":
        return solver
    size = n_rows if newton_uses_kernel(n_rows, n_columns, n_classifiers) else n_columns + 1
    return "newton" if size <= NEWTON_MAX_SYSTEM else "lbfgs"


def default_max_iter(solver: str) -> int:
    """Iteration cap of a solver when ``max_iter`` is None (Newton 100, L-BFGS 2000, liblinear 1000)."""
    return _DEFAULT_MAX_ITER[solver]


def _loss_terms(classifier: str, margins: np.ndarray, Y: np.ndarray, weights: np.ndarray | None, C: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Loss per classifier (K,), its first and (generalised) second derivative in each margin (n, K).

    ``Y`` holds ±1 labels; ``weights`` the per-row sample weights (None: 1).
    """
    z = Y * margins
    sw = 1.0 if weights is None else weights
    if classifier == "svm":
        r = np.maximum(1.0 - z, 0.0)
        return C * np.einsum("ik,ik->k", sw * r, r), (-2.0 * C) * (sw * r) * Y, (2.0 * C) * (sw * (r > 0))
    loss = np.logaddexp(0.0, -z)
    sigma = np.exp(-np.logaddexp(0.0, z))  # σ(−z), without overflow
    return C * (sw * loss).sum(axis=0), (-C) * (sw * sigma) * Y, C * (sw * (sigma * (1.0 - sigma)))


def linear_objective(Xs: np.ndarray, labels: np.ndarray, coef: np.ndarray, intercept: np.ndarray, *, C: float,
                     classifier: str = "svm", sample_weight: np.ndarray | None = None) -> np.ndarray:
    """liblinear's primal objective of each classifier (module docstring), shape (K,), float64.

    Parameters
    ----------
    Xs : ndarray of shape (n, d'), the standardised columns the classifiers were trained on
    labels : ndarray of shape (n, K), {0, 1} (or (n,) for one classifier)
    coef : ndarray of shape (K, d')
    intercept : ndarray of shape (K,)
    sample_weight : ndarray of shape (n, K) or (n,), optional
    """
    Y = 2.0 * np.asarray(labels, dtype=np.float64).reshape(len(Xs), -1) - 1.0
    W = np.atleast_2d(np.asarray(coef, dtype=np.float64))
    b = np.atleast_1d(np.asarray(intercept, dtype=np.float64))
    sw = None if sample_weight is None else np.asarray(sample_weight, dtype=np.float64).reshape(len(Xs), -1)
    margins = np.asarray(Xs, dtype=np.float64) @ W.T + b
    loss = _loss_terms(classifier, margins, Y, sw, C)[0]
    return 0.5 * ((W * W).sum(axis=1) + b * b) + loss


def _line_search(classifier: str, margins: np.ndarray, step_margins: np.ndarray, Y: np.ndarray,
                 weights: np.ndarray | None, C: float, wp: np.ndarray, pp: np.ndarray, t0: float = 1.0
                 ) -> np.ndarray:
    """Exact line search: the t ≥ 0 minimising φ(t) = ½‖w + t p‖² + loss(m + t q), per classifier.

    φ is convex (piecewise quadratic for the squared hinge), so its slope is increasing: Newton's
    method in t, safeguarded by bisection on a bracket [lo, hi] with φ'(lo) < 0 < φ'(hi) (plain
    Newton steps can cycle between the pieces of a piecewise quadratic). Needs only the margins
    (n, K) and the margin change q = X p, no product with X.
    """
    K = margins.shape[1]

    def slope_and_curvature(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        _, d1, d2 = _loss_terms(classifier, margins + t * step_margins, Y, weights, C)
        slope = wp + t * pp + np.einsum("ik,ik->k", d1, step_margins)
        return slope, pp + np.einsum("ik,ik->k", d2 * step_margins, step_margins)

    lo = np.zeros(K)
    slope0, _ = slope_and_curvature(lo)
    hi = np.full(K, float(t0))
    slope_hi, _ = slope_and_curvature(hi)
    for _ in range(60):  # widen the bracket until φ'(hi) ≥ 0
        short = slope_hi < 0
        if not short.any():
            break
        lo = np.where(short, hi, lo)
        hi = np.where(short, 2.0 * hi, hi)
        slope_hi, _ = slope_and_curvature(hi)
    t = np.where(slope0 >= 0, 0.0, hi)  # not a descent direction: no step
    done = slope0 >= 0
    for _ in range(100):
        slope, curvature = slope_and_curvature(t)
        lo = np.where(slope < 0, t, lo)
        hi = np.where(slope > 0, t, hi)
        newton = t - slope / np.maximum(curvature, 1e-300)
        inside = (newton > lo) & (newton < hi)
        t_next = np.where(inside, newton, 0.5 * (lo + hi))
        done |= (slope == 0) | (np.abs(t_next - t) <= 1e-12 * np.maximum(t, 1e-300)) | (hi - lo <= 1e-12 * hi)
        t = np.where(done, t, t_next)
        if done.all():
            break
    return t


class _Problem:
    """Shared pieces of one group of classifiers: the standardised rows, labels and weights."""

    def __init__(self, Xs: np.ndarray, labels: np.ndarray, C: float, classifier: str,
                 sample_weight: np.ndarray | None) -> None:
        self.Xs = Xs
        self.Y = 2.0 * np.asarray(labels, dtype=np.float64) - 1.0  # (n, K) ±1
        self.C = float(C)
        self.classifier = classifier
        self.weights = None if sample_weight is None else np.asarray(sample_weight, dtype=np.float64)

    def terms(self, margins: np.ndarray, cols: np.ndarray | slice = slice(None)):
        w = None if self.weights is None else self.weights[:, cols]
        return _loss_terms(self.classifier, margins, self.Y[:, cols], w, self.C)

    def matmul(self, V: np.ndarray) -> np.ndarray:
        """X̃ v for the columns of V (d' + 1, k): the margins' change, float64 (n, k)."""
        return np.asarray(self.Xs @ V[:-1].astype(self.Xs.dtype, copy=False), dtype=np.float64) + V[-1]

    def rmatmul(self, R: np.ndarray) -> np.ndarray:
        """X̃ᵀ r for the columns of R (n, k): shape (d' + 1, k), float64."""
        top = np.asarray(self.Xs.T @ R.astype(self.Xs.dtype, copy=False), dtype=np.float64)
        return np.vstack([top, R.sum(axis=0, keepdims=True)])

    def line_search(self, V, margins, step_margins, P, cols, t0=1.0):
        w = None if self.weights is None else self.weights[:, cols]
        wp = np.einsum("ik,ik->k", V, P)
        pp = np.einsum("ik,ik->k", P, P)
        return _line_search(self.classifier, margins, step_margins, self.Y[:, cols], w, self.C, wp, pp, t0)


def _newton(problem: _Problem, tol: float, max_iter: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Newton's method with exact line search for every classifier of the group (module docstring).

    Returns (V (d' + 1, K) with the bias last, iterations (K,), converged (K,)).
    """
    Xs = problem.Xs
    n, d = Xs.shape
    K = problem.Y.shape[1]
    V = np.zeros((d + 1, K))
    margins = np.zeros((n, K))
    shareable = problem.classifier == "svm" and problem.weights is None
    kernel = newton_uses_kernel(n, d, K, shared=shareable)
    shared_inverse = kernel and shareable
    gram = None
    if kernel:
        # K̃ = X̃X̃ᵀ (the bias feature adds 1): one product for every classifier and step.
        gram = Xs @ Xs.T
        gram += 1.0
    full_primal = None
    if not kernel and problem.classifier == "svm" and problem.weights is None:
        full_primal = _augmented_gram(Xs, None, None)  # X̃ᵀX̃, to subtract the few non-violators from
    inverse = None
    if shared_inverse:
        # R = I/(2C) + K̃ and its inverse: a step solves R_AA x = r on the violators A, through
        # R_AA (|A| small) or through R⁻¹ and the Schur complement of the others (|A| large).
        inverse = gram.copy()
        inverse[np.diag_indices_from(inverse)] += 1.0 / (2.0 * problem.C)
        inverse = _spd_inverse(inverse)
    n_iter = np.zeros(K, dtype=np.int64)
    active = np.ones(K, dtype=bool)
    g0 = None
    for it in range(max_iter + 1):
        loss, d1, d2 = problem.terms(margins)
        if TRACE is not None:
            TRACE("newton", it, 0.5 * (V * V).sum(axis=0) + loss, (d2 > 0).sum(axis=0))
        G = V + problem.rmatmul(d1)
        gnorm = np.sqrt((G * G).sum(axis=0))
        if g0 is None:
            # Relative to the gradient at w = 0, with an absolute floor: rows that no hyperplane
            # can separate (duplicate frames with both labels) have a zero gradient at w = 0.
            g0 = tol * gnorm + 1e-12 * (1.0 + problem.C * n)
        active &= gnorm > g0
        if not active.any() or it == max_iter:
            break
        a = np.flatnonzero(active)
        P = np.empty((d + 1, a.size))
        if kernel:
            U = problem.matmul(G[:, a])  # X̃ g, (n, ka)
            if inverse is not None:
                coeffs = _solve_submatrices(gram, inverse, d2[:, a] > 0, 1.0 / (2.0 * problem.C), U)
            else:
                coeffs = np.zeros((n, a.size))
            for j, k in enumerate(a):
                rows = np.flatnonzero(d2[:, k] > 0)
                if rows.size == 0 or inverse is not None:
                    continue
                else:
                    root = np.sqrt(d2[rows, k])
                    system = gram[np.ix_(rows, rows)]
                    system *= root[:, None]
                    system *= root[None, :]
                    system[np.diag_indices_from(system)] += 1.0
                    coeffs[rows, j] = root * sla.cho_solve(sla.cho_factor(system, overwrite_a=True, check_finite=False),
                                                           root * U[rows, j], check_finite=False)
            # p = −g + X̃ᵀ (D⁻¹ + K̃_AA)⁻¹ X̃_A g  (Woodbury)
            P = -G[:, a] + problem.rmatmul(coeffs)
        else:
            for j, k in enumerate(a):
                rows = np.flatnonzero(d2[:, k] > 0)
                if full_primal is not None and rows.size > n // 2:
                    # Most rows violate the margin: subtract the few others from X̃ᵀX̃.
                    others = np.flatnonzero(d2[:, k] == 0)
                    H = (2.0 * problem.C) * (full_primal - _augmented_gram(Xs, others, None))
                else:
                    H = _augmented_gram(Xs, rows, d2[rows, k])
                H[np.diag_indices_from(H)] += 1.0
                P[:, j] = -sla.cho_solve(sla.cho_factor(H, overwrite_a=True, check_finite=False), G[:, k],
                                         check_finite=False)
        step_margins = problem.matmul(P)
        t = problem.line_search(V[:, a], margins[:, a], step_margins, P, a, t0=1.0)
        V[:, a] += t * P
        margins[:, a] += t * step_margins
        n_iter[a] += 1
    return V, n_iter, ~active


def _augmented_gram(Xs: np.ndarray, rows: np.ndarray | None, weights: np.ndarray | None) -> np.ndarray:
    """X̃ᵀ diag(weights) X̃ over ``rows`` of Xs (bias feature 1 appended), (d' + 1)², float64.

    Rows are gathered a chunk at a time (at most ~4M values), so no copy of the active rows is
    made (at N = 1M, d' = 64 one would be 512 MB per classifier).
    """
    n, d = Xs.shape
    index = np.arange(n) if rows is None else np.asarray(rows)
    out = np.zeros((d + 1, d + 1))
    step = max(1, (1 << 22) // max(d + 1, 1))
    for start in range(0, index.size, step):
        chunk = index[start : start + step]
        aug = np.empty((chunk.size, d + 1))
        aug[:, :d] = Xs[chunk] if rows is not None else Xs[start : start + step]
        aug[:, d] = 1.0
        if weights is not None:
            out += (aug * weights[start : start + step, None]).T @ aug
        else:
            out += aug.T @ aug
    return out


def _spd_inverse(matrix: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive definite matrix (Cholesky, then LAPACK potri), both triangles."""
    factor = sla.cho_factor(matrix, lower=True, overwrite_a=True, check_finite=False)[0]
    inverse, info = sla.lapack.dpotri(factor, lower=True)
    if info != 0:  # pragma: no cover - the matrix is ridge + Gram, positive definite
        raise np.linalg.LinAlgError(f"dpotri failed (info {info})")
    lower = np.tril(inverse)
    return lower + np.tril(lower, -1).T


def _solve_submatrices(gram: np.ndarray, inverse: np.ndarray, masks: np.ndarray, ridge: float,
                       rhs: np.ndarray) -> np.ndarray:
    """For each column j: x with (ridge·I + K̃)_AA x = rhs_A on A = rows where ``masks[:, j]``, 0 elsewhere.

    ``inverse`` is R⁻¹ of the whole R = ridge·I + K̃. Each column factors whichever is smaller:
    R_AA itself, or (R⁻¹)_BB for the complement B, using
    (R_AA)⁻¹ = (R⁻¹)_AA − (R⁻¹)_AB ((R⁻¹)_BB)⁻¹ (R⁻¹)_BA; the products with R⁻¹ are done for all
    columns at once on zero-padded right-hand sides (no large submatrix is copied).

    Returns
    -------
    ndarray of shape (n, K), float64
    """
    n, K = masks.shape
    out = np.zeros((n, K))
    large = masks.sum(axis=0) > n // 2
    padded = np.where(masks, rhs, 0.0)
    first = inverse @ padded[:, large]                   # (R⁻¹)_{·A} r_A for the large sets
    corrections = np.zeros((n, int(large.sum())))
    for j, k in enumerate(np.flatnonzero(large)):
        others = np.flatnonzero(~masks[:, k])
        if others.size:
            block = inverse[np.ix_(others, others)]
            corrections[others, j] = sla.cho_solve(sla.cho_factor(block, overwrite_a=True, check_finite=False),
                                                   first[others, j], check_finite=False)
    if large.any():
        out[:, large] = np.where(masks[:, large], first - inverse @ corrections, 0.0)
    for k in np.flatnonzero(~large):
        rows = np.flatnonzero(masks[:, k])
        if rows.size == 0:
            continue
        system = gram[np.ix_(rows, rows)]
        system[np.diag_indices_from(system)] += ridge
        out[rows, k] = sla.cho_solve(sla.cho_factor(system, overwrite_a=True, check_finite=False), rhs[rows, k],
                                     check_finite=False)
    return out


def _lbfgs(problem: _Problem, tol: float, max_iter: int, memory: int = 10
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """L-BFGS for every classifier of the group at once: shared matrix products, own histories.

    Returns (V (d' + 1, K) with the bias last, iterations (K,), converged (K,)).
    """
    n, d = problem.Xs.shape
    K = problem.Y.shape[1]
    V = np.zeros((d + 1, K))
    margins = np.zeros((n, K))
    S = np.zeros((memory, d + 1, K))
    Yh = np.zeros((memory, d + 1, K))
    rho = np.zeros((memory, K))
    _, d1, _ = problem.terms(margins)
    G = V + problem.rmatmul(d1)
    threshold = tol * np.sqrt((G * G).sum(axis=0)) + 1e-12 * (1.0 + problem.C * n)  # as in _newton
    active = np.ones(K, dtype=bool)
    n_iter = np.zeros(K, dtype=np.int64)
    for it in range(max_iter):
        active &= np.sqrt((G * G).sum(axis=0)) > threshold
        if not active.any():
            break
        a = np.flatnonzero(active)
        q = G[:, a].copy()
        used = [(it - 1 - j) % memory for j in range(min(memory, it))]
        alphas = []
        for j in used:
            alpha = rho[j, a] * np.einsum("ik,ik->k", S[j][:, a], q)
            q -= alpha * Yh[j][:, a]
            alphas.append(alpha)
        if used:
            newest = used[0]
            yy = np.einsum("ik,ik->k", Yh[newest][:, a], Yh[newest][:, a])
            scale = np.where((rho[newest, a] > 0) & (yy > 0), 1.0 / np.maximum(rho[newest, a] * yy, 1e-300), 1.0)
            q *= scale
        else:
            q /= np.maximum(np.sqrt((q * q).sum(axis=0)), 1e-300)
        for j, alpha in zip(reversed(used), reversed(alphas)):
            beta = rho[j, a] * np.einsum("ik,ik->k", Yh[j][:, a], q)
            q += S[j][:, a] * (alpha - beta)
        P = -q
        step_margins = problem.matmul(P)
        t = problem.line_search(V[:, a], margins[:, a], step_margins, P, a, t0=1.0)
        V[:, a] += t * P
        margins[:, a] += t * step_margins
        _, d1, _ = problem.terms(margins[:, a], a)
        G_new = V[:, a] + problem.rmatmul(d1)
        s_vec, y_vec = t * P, G_new - G[:, a]
        sy = np.einsum("ik,ik->k", s_vec, y_vec)
        slot = it % memory
        S[slot][:, a], Yh[slot][:, a] = s_vec, y_vec
        rho[slot, a] = np.where(sy > 1e-300, 1.0 / np.where(sy > 1e-300, sy, 1.0), 0.0)
        G[:, a] = G_new
        n_iter[a] += 1
        if TRACE is not None:
            loss_all = problem.terms(margins)[0]
            TRACE("lbfgs", it + 1, 0.5 * (V * V).sum(axis=0) + loss_all, np.zeros(K, dtype=np.int64))
    converged = np.sqrt((G * G).sum(axis=0)) <= threshold
    return V, n_iter, converged


def _liblinear(problem_Xs: np.ndarray, labels: np.ndarray, C: float, classifier: str,
               sample_weight: np.ndarray | None, max_iter: int, random_state: int | None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """scikit-learn's liblinear classifiers, one per label column (dual when rows < 3·d')."""
    n, d = problem_Xs.shape
    K = labels.shape[1]
    V = np.zeros((d + 1, K))
    n_iter = np.zeros(K, dtype=np.int64)
    for k in range(K):
        model = _make_classifier(classifier, C, max_iter, random_state, _use_dual(n, d))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            model.fit(problem_Xs, labels[:, k], sample_weight=None if sample_weight is None else sample_weight[:, k])
        V[:d, k] = model.coef_.ravel()
        V[d, k] = float(np.ravel(model.intercept_)[0])
        n_iter[k] = int(np.max(model.n_iter_))
    return V, n_iter, n_iter < max_iter


@dataclass
class LinearSolution:
    """Classifiers of one group on standardised columns (before folding the scaling in).

    Attributes
    ----------
    coef : ndarray of shape (K, d'), float64
    intercept : ndarray of shape (K,), float64
    n_iter : ndarray of shape (K,), int64
    converged : ndarray of shape (K,), bool
    objective : ndarray of shape (K,), float64
        liblinear's primal objective at the solution (module docstring).
    solver : str
    """

    coef: np.ndarray
    intercept: np.ndarray
    n_iter: np.ndarray
    converged: np.ndarray
    objective: np.ndarray
    solver: str


def solve_linear(Xs: np.ndarray, labels: np.ndarray, *, C: float, classifier: str = "svm", solver: str = "auto",
                 sample_weight: np.ndarray | None = None, max_iter: int | None = None,
                 random_state: int | None = None, tol: float | None = None) -> LinearSolution:
    """Fit K binary classifiers that share the standardised rows ``Xs`` (module docstring).

    Parameters
    ----------
    Xs : ndarray of shape (n, d'), float64 (float32 is accepted by 'lbfgs')
    labels : ndarray of shape (n, K), {0, 1}; 1 = positive margin
    solver : {'auto', 'newton', 'lbfgs', 'liblinear'}
    sample_weight : ndarray of shape (n, K), optional
    max_iter : int, optional
        Iteration cap (None: :func:`default_max_iter` of the solver).
    tol : float, optional
        Relative gradient norm to stop at (Newton, L-BFGS; None: :data:`NEWTON_TOL`, :data:`LBFGS_TOL`).
    """
    labels = np.asarray(labels).reshape(Xs.shape[0], -1)
    name = choose_solver(solver, Xs.shape[0], Xs.shape[1], labels.shape[1])
    cap = default_max_iter(name) if max_iter is None else int(max_iter)
    sw = None if sample_weight is None else np.asarray(sample_weight, dtype=np.float64).reshape(Xs.shape[0], -1)
    if name == "liblinear":
        V, n_iter, converged = _liblinear(np.asarray(Xs, dtype=np.float64), labels, C, classifier, sw, cap,
                                          random_state)
    else:
        problem = _Problem(Xs if name == "lbfgs" else np.asarray(Xs, dtype=np.float64), labels, C, classifier, sw)
        solve = _newton if name == "newton" else _lbfgs
        V, n_iter, converged = solve(problem, (NEWTON_TOL if name == "newton" else LBFGS_TOL) if tol is None else tol,
                                     cap)
    coef, intercept = V[:-1].T.copy(), V[-1].copy()
    objective = linear_objective(Xs, labels, coef, intercept, C=C, classifier=classifier, sample_weight=sw)
    return LinearSolution(coef, intercept, n_iter, np.asarray(converged, dtype=bool), objective, name)


def _label_columns(labels: np.ndarray) -> np.ndarray:
    """{0,1} columns of one classifier's labels: one for two classes (positive = the larger), else one-vs-rest."""
    classes = np.unique(labels)
    if classes.size < 2:
        raise InvalidParameterError("a classifier needs rows of at least two classes.")
    if classes.size == 2:
        return (labels == classes[1]).astype(np.int8)[:, None]
    return (labels[:, None] == classes[None, :]).astype(np.int8)


def fit_linear_group(
    X: np.ndarray,
    labels: list[np.ndarray],
    columns: np.ndarray,
    stats: ColumnStats,
    *,
    classifier: str = "svm",
    C: float = 1.0,
    solver: str = "auto",
    max_iter: int | None = None,
    random_state: int | None = None,
    dtype: np.dtype = np.dtype(np.float32),
    sample_weight: list[np.ndarray | None] | None = None,
) -> list[tuple[np.ndarray, np.ndarray, int, int, float]]:
    """Several classifiers on the same rows and columns: one standardised copy, one solve.

    Parameters
    ----------
    X : ndarray of shape (n_samples, n_features_in)
    labels : list of ndarray of shape (n_samples,), int
        One entry per classifier (two classes → one hyperplane, more → one-vs-rest hyperplanes).
    columns : ndarray of shape (d',), int
    sample_weight : list of (ndarray of shape (n_samples,) or None), optional

    Returns
    -------
    list of (weights (k, d') ``dtype`` with the scaling folded in, bias (k,) float32, hyperplanes
    that stopped at the cap, iterations, objective), one per entry of ``labels``.
    """
    cols = np.asarray(columns, dtype=np.intp)
    mu = stats.mean[cols]
    sigma = stats.scale[cols]
    n_classifiers = sum(1 if np.unique(y).size <= 2 else np.unique(y).size for y in labels)
    name = choose_solver(solver, X.shape[0], cols.size, n_classifiers)
    Xs = standardised_columns(X, cols, mu, sigma, dtype=np.dtype(np.float32 if name == "lbfgs" else np.float64))
    blocks = [_label_columns(np.asarray(y)) for y in labels]
    widths = [blk.shape[1] for blk in blocks]
    Y = np.concatenate(blocks, axis=1)
    weights = None
    if sample_weight is not None and any(w is not None for w in sample_weight):
        per_column = []
        for w, width in zip(sample_weight, widths):
            row_weights = np.ones(X.shape[0]) if w is None else np.asarray(w, dtype=np.float64)
            per_column.append(np.repeat(row_weights[:, None], width, axis=1))
        weights = np.concatenate(per_column, axis=1)
    solution = solve_linear(Xs, Y, C=C, classifier=classifier, solver=name, sample_weight=weights,
                            max_iter=max_iter, random_state=random_state)
    del Xs
    out = []
    first = 0
    for width in widths:
        part = slice(first, first + width)
        first += width
        w = (solution.coef[part] / sigma).astype(dtype)
        # Bias from the stored weights: c' = c − Σ w_stored·μ.
        bias = (solution.intercept[part] - w.astype(np.float64) @ mu).astype(np.float32)
        out.append((w, np.atleast_1d(bias), int((~solution.converged[part]).sum()),
                    int(solution.n_iter[part].max()), float(solution.objective[part].sum())))
    return out


def fit_linear(
    X: np.ndarray,
    labels: np.ndarray,
    columns: np.ndarray,
    stats: ColumnStats,
    *,
    classifier: str = "svm",
    C: float = 1.0,
    solver: str = "auto",
    max_iter: int | None = None,
    random_state: int | None = None,
    dtype: np.dtype = np.dtype(np.float32),
    sample_weight: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Train one (binary or one-vs-rest) linear classifier on ``X[:, columns]``, standardised.

    Parameters
    ----------
    X : ndarray of shape (n_samples, n_features_in)
    labels : ndarray of shape (n_samples,), int
        Two classes give one hyperplane (positive margin = the larger label); more give one per
        class (one-vs-rest), in sorted class order.
    columns : ndarray of shape (d',), int
    stats : ColumnStats
        Training statistics of all n_features_in columns.
    solver : {'auto', 'newton', 'lbfgs', 'liblinear'}
        See the module docstring.
    max_iter : int, optional
        Iteration cap (None: the solver's default, :func:`default_max_iter`).
    dtype : numpy dtype
        Stored weight dtype (float32 or float16).
    sample_weight : ndarray of shape (n_samples,), optional
        Per-row weight in the loss (multi-exemplar training).

    Returns
    -------
    weights : ndarray of shape (n_hyperplanes, d'), dtype ``dtype`` — scaling folded in
    bias : ndarray of shape (n_hyperplanes,), float32
    converged : bool
        False when the solver stopped at its iteration cap.
    """
    w, b, unconverged, _, _ = fit_linear_group(
        X, [labels], columns, stats, classifier=classifier, C=C, solver=solver, max_iter=max_iter,
        random_state=random_state, dtype=dtype, sample_weight=[sample_weight])[0]
    return w, b, unconverged == 0


@dataclass
class Hyperplanes:
    """A stack of K linear classifiers, classifier k reading columns ``columns[k]``.

    Attributes
    ----------
    weights : ndarray of shape (K, d'), float32 or float16
    bias : ndarray of shape (K,), float32
    columns : ndarray of shape (K, d') or (1, d'), uint16/uint32, or None
        Columns read by each classifier; one shared row when all K read the same columns (the
        one-vs-rest region classifier); None when every classifier reads all d columns
        (d' = d: no indices stored).
    n_features_in : int
        d, the descriptor dimension.
    """

    weights: np.ndarray
    bias: np.ndarray
    columns: np.ndarray | None
    n_features_in: int
    _dense: np.ndarray | None = field(default=None, repr=False, compare=False)
    _dense_blocks: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def empty(cls, n_selected: int, n_features_in: int, dtype: np.dtype, index_dtype: np.dtype | None):
        return cls(
            weights=np.zeros((0, n_selected), dtype=dtype),
            bias=np.zeros(0, dtype=np.float32),
            columns=None if index_dtype is None else np.zeros((0, n_selected), dtype=index_dtype),
            n_features_in=n_features_in,
        )

    @classmethod
    def stack(cls, parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]], n_features_in: int,
              n_selected: int, dtype: np.dtype, index_dtype: np.dtype | None,
              *, shared_columns: bool = False) -> "Hyperplanes":
        """Stack (weights (k, d'), bias (k,), columns (d',)) triples, one per fitted classifier.

        ``index_dtype`` None means d' = d and no columns are stored. With ``shared_columns``
        (every part reads the same columns: the one-vs-rest region classifier) the columns are
        stored once, as one row.
        """
        if not parts:
            return cls.empty(n_selected, n_features_in, dtype, index_dtype)
        weights = np.concatenate([w for w, _, _ in parts]).astype(dtype)
        bias = np.concatenate([b for _, b, _ in parts]).astype(np.float32)
        columns = None
        if index_dtype is not None:
            if shared_columns or len(parts) == 1:
                columns = parts[0][2].reshape(1, -1).astype(index_dtype)
            else:
                columns = np.concatenate(
                    [np.broadcast_to(c, (w.shape[0], c.shape[0])) for w, _, c in parts]
                ).astype(index_dtype)
        return cls(weights=weights, bias=bias, columns=columns, n_features_in=n_features_in)

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str, n_features_in: int) -> "Hyperplanes":
        """Hyperplanes read from a model file's (shape-checked) arrays ``{prefix}weights`` etc.

        Raises :class:`~btel.exceptions.ModelFileError` for NaN/inf weights or biases and for
        column indices outside [0, d).
        """
        weights, bias = arrays[f"{prefix}weights"], arrays[f"{prefix}bias"]
        columns = arrays.get(f"{prefix}columns")
        if not (np.isfinite(weights).all() and np.isfinite(bias).all()):
            raise ModelFileError(f"the model file's {prefix}weights or {prefix}bias contain NaN or infinite values.")
        if columns is not None and columns.size and int(columns.max()) >= n_features_in:
            raise ModelFileError(f"the model file's {prefix}columns index past d = {n_features_in}.")
        return cls(weights, bias, columns, n_features_in)

    def __len__(self) -> int:
        return int(self.weights.shape[0])

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """The stored arrays, named ``{prefix}weights`` etc."""
        out = {f"{prefix}weights": self.weights, f"{prefix}bias": self.bias}
        if self.columns is not None:
            out[f"{prefix}columns"] = self.columns
        return out

    def dense(self) -> np.ndarray:
        """All K hyperplanes scattered into one (d, K) float32 matrix (a runtime cache, not stored).

        One BLAS product ``Q @ dense`` then gives every margin: faster than K gathers.
        """
        if self._dense is None:
            K, d_sel = self.weights.shape
            dense = np.zeros((self.n_features_in, K), dtype=np.float32)
            if self.columns is None:
                dense[:, :] = self.weights.T
            else:
                rows = np.broadcast_to(self.columns, (K, d_sel)).astype(np.intp)
                dense[rows, np.repeat(np.arange(K), d_sel).reshape(K, d_sel)] = self.weights
            self._dense = dense
        return self._dense

    def margins(self, Q: np.ndarray, rows: slice | np.ndarray | None = None) -> np.ndarray:
        """Margins of the queries under classifiers ``rows`` (all by default).

        Returns
        -------
        ndarray of shape (n_queries, n_rows), float32
        """
        dense = self.dense()
        bias = self.bias
        if isinstance(rows, slice):
            # One region's tree: a contiguous copy of its columns (cached). Slicing the (d, K)
            # matrix instead strides over all K columns: 3× slower for one query at K = 320.
            key = rows.indices(dense.shape[1])
            if key not in self._dense_blocks:
                self._dense_blocks[key] = np.ascontiguousarray(dense[:, rows])
            dense = self._dense_blocks[key]
            bias = bias[rows]
        elif rows is not None:
            dense = dense[:, rows]
            bias = bias[rows]
        # A dense (d, K) product beats gathering each classifier's d' columns even for a single
        # query (measured: 6 µs against 11 µs at d = 4096, K = 20, d' = 410, the matrix in cache).
        return Q @ dense + bias

    def margins_per_row(self, Q: np.ndarray, row_of_query: np.ndarray) -> np.ndarray:
        """Margin of query i under its own classifier ``row_of_query[i]`` (shape (n,), float32).

        Gathers only that classifier's d' columns: O(n·d'), for when K is large (BTE-F).
        """
        rows = np.asarray(row_of_query, dtype=np.intp)
        w = self.weights[rows].astype(np.float32)
        Q = np.asarray(Q)  # ScaledRows: multiplied out (columns are gathered, not a product)
        if self.columns is None:
            q = Q
        else:
            cols = self.columns[rows if self.columns.shape[0] > 1 else np.zeros_like(rows)]
            q = np.take_along_axis(Q, cols.astype(np.intp), axis=1)
        return np.einsum("ij,ij->i", q, w) + self.bias[rows]

"""Newton's method and L-BFGS on liblinear's primal objective, for a group of classifiers at once.

The objective and the choice between these solvers are in :mod:`btel.learning.solvers`; here are
the iterations. Both work on a :class:`Problem` — the standardised rows X̃ (bias feature 1
appended), the ±1 labels of K classifiers and their sample weights — and return the stacked
solutions V (d' + 1, K), bias last.

- :func:`newton`: Newton's method with an exact line search (for the squared hinge the modified
  finite Newton method of Keerthi & DeCoste, JMLR 2005: it reaches the exact optimum once the set
  of margin violators stops changing). Each step solves one linear system of size
  min(rows, d' + 1): in the primal with the (d'+1)² Gram matrix of the rows, or in the kernel form
  with the rows × rows Gram matrix, computed once and shared by every classifier and step
  (:func:`newton_uses_kernel` picks by a flop count). For the SVM without sample weights the
  inverse of ``I/(2C) + K`` is shared too and each step factors only min(#violators, #others) rows.
- :func:`lbfgs`: limited-memory BFGS over all classifiers of the group (two matrix products per
  step for all of them, a per-classifier history, exact line search along the step).
"""

from __future__ import annotations

import numpy as np

__all__ = ["Problem", "loss_terms", "newton", "lbfgs", "newton_uses_kernel"]


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



def loss_terms(classifier: str, margins: np.ndarray, Y: np.ndarray, weights: np.ndarray | None, C: float
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
        _, d1, d2 = loss_terms(classifier, margins + t * step_margins, Y, weights, C)
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


class Problem:
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
        return loss_terms(self.classifier, margins, self.Y[:, cols], w, self.C)

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


def newton(problem: Problem, tol: float, max_iter: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Newton's method with exact line search for every classifier of the group (module docstring).

    Returns (V (d' + 1, K) with the bias last, iterations (K,), converged (K,)).
    """
    import scipy.linalg as sla  # fit-only: a loaded model never imports SciPy

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
    import scipy.linalg as sla

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
    import scipy.linalg as sla

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


def lbfgs(problem: Problem, tol: float, max_iter: int, memory: int = 10
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
    threshold = tol * np.sqrt((G * G).sum(axis=0)) + 1e-12 * (1.0 + problem.C * n)  # as in newton
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
    converged = np.sqrt((G * G).sum(axis=0)) <= threshold
    return V, n_iter, converged

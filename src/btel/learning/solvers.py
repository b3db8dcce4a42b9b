"""Solving K linear classifiers that share rows and columns: the objective and the solvers.

Every classifier minimises liblinear's primal objective (the bias is the weight of a constant
feature 1, so it is regularised too, as scikit-learn's ``intercept_scaling=1`` does): for
``'svm'`` ``½‖w‖² + ½b² + C Σ sᵢ max(0, 1 − yᵢ(w·xᵢ + b))²``, for ``'logistic'``
``½‖w‖² + ½b² + C Σ sᵢ log(1 + exp(−yᵢ(w·xᵢ + b)))`` (sᵢ: sample weights). Classifiers that read
the same rows and columns are solved together on one standardised copy (:func:`solve_linear`).

Solvers (``solver``; :data:`SOLVERS`):

- ``'newton'``: Newton's method with an exact line search (:func:`btel.learning.primal.newton`);
  it reaches the exact optimum of the squared hinge once the set of margin violators stops
  changing, to a relative gradient norm of :data:`NEWTON_TOL` in 5–40 steps. Each step solves a
  linear system of min(rows, d' + 1) unknowns; ``'auto'`` uses it when that system has at most
  :data:`NEWTON_MAX_SYSTEM` unknowns.
- ``'lbfgs'``: limited-memory BFGS over all classifiers of a group at once
  (:func:`btel.learning.primal.lbfgs`). Cheap steps, but on ill-conditioned maps (N ≈ d) it needs
  thousands of them; used by ``'auto'`` for the larger shapes.
- ``'liblinear'``: scikit-learn's ``LinearSVC`` / ``LogisticRegression(solver='liblinear')``,
  dual coordinate descent when rows < 3·d'. On maps with N ≈ d it can stop at its iteration cap
  well above the optimum, and its dual solver draws random numbers (see :class:`btel.BTELocalizer`).
  ``benchmarks/bench_fit.py`` compares the three by time and objective.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..exceptions import InvalidParameterError
from .primal import Problem, lbfgs, loss_terms, newton, newton_uses_kernel

__all__ = ["CLASSIFIERS", "SOLVERS", "LinearSolution", "choose_solver", "default_max_iter", "linear_objective",
           "solve_linear", "newton_uses_kernel"]

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


def _use_dual(n_samples: int, n_features: int) -> bool:
    """liblinear's dual solver unless there are at least 3 samples per feature.

    scikit-learn's ``dual="auto"`` switches at n_samples = n_features, but on standardised
    descriptors liblinear's primal solver is much slower than the dual between n = d and n = 3d,
    and faster only below d' ≈ n/3.
    """
    return n_samples < 3 * n_features


def _make_classifier(classifier: str, C: float, max_iter: int, random_state: int | None, dual: bool):
    from sklearn.linear_model import LogisticRegression  # fit-only: a loaded model never imports scikit-learn
    from sklearn.svm import LinearSVC

    if classifier == "svm":
        return LinearSVC(C=C, loss="squared_hinge", dual=dual, max_iter=max_iter, random_state=random_state)
    if classifier == "logistic":
        return LogisticRegression(C=C, solver="liblinear", tol=0.01, dual=dual, max_iter=max_iter,
                                  random_state=random_state)
    raise InvalidParameterError(f"classifier must be one of {CLASSIFIERS}; got {classifier!r}.")



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
    loss = loss_terms(classifier, margins, Y, sw, C)[0]
    return 0.5 * ((W * W).sum(axis=1) + b * b) + loss



def _liblinear(problem_Xs: np.ndarray, labels: np.ndarray, C: float, classifier: str,
               sample_weight: np.ndarray | None, max_iter: int, random_state: int | None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """scikit-learn's liblinear classifiers, one per label column (dual when rows < 3·d')."""
    from sklearn.exceptions import ConvergenceWarning

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
        problem = Problem(Xs if name == "lbfgs" else np.asarray(Xs, dtype=np.float64), labels, C, classifier, sw)
        solve = newton if name == "newton" else lbfgs
        V, n_iter, converged = solve(problem, (NEWTON_TOL if name == "newton" else LBFGS_TOL) if tol is None else tol,
                                     cap)
    coef, intercept = V[:-1].T.copy(), V[-1].copy()
    objective = linear_objective(Xs, labels, coef, intercept, C=C, classifier=classifier, sample_weight=sw)
    return LinearSolution(coef, intercept, n_iter, np.asarray(converged, dtype=bool), objective, name)

"""Calibrated ``auto``: every candidate scored on labelled queries, a switch only beyond noise.

``AutoLocalizer(budget=…, calibration_tolerance=t).fit(X, calibration=(Q, truth))`` fits every
candidate of :func:`calibration_candidates` that fits the budget, predicts the calibration queries
with each, and compares each candidate with the map-only pick (:mod:`btel.methods.auto.rule`)
**paired on the same queries**:

- per query, the correctness (``|pred − truth| ≤ t``, or the prediction among the query's positives
  for a :class:`~btel.datasets.GroundTruth` of positives); seeded candidates (every one but brute
  force) are fitted at :data:`SEEDS` and their per-query correctness averaged over the seeds;
- the one-sided paired test of each candidate's mean difference, adjusted for all candidates at once
  by the max-T paired sign-flip permutation (:func:`max_t_pvalues`: family-wise level :data:`ALPHA`,
  correlated candidates sharing the correction); the exact McNemar p-value of each is reported beside it;
- the switch goes to the best-scoring candidate whose adjusted p-value is below :data:`ALPHA`; with
  none, the map-only pick stays.

Each row also states the calibration queries a difference of :data:`REFERENCE_DIFFERENCE` (and the
observed one) would need at the observed discordance rate (McNemar's sample size, Connor 1987,
power 0.8, one-sided, at the Bonferroni level of the candidates: a conservative bound), and the
candidate's fit seconds and µs per calibration query on the compared map (speed beside accuracy).

Cost bound: candidates are compared on at most :func:`compared_rows` map places (:data:`MAX_ROWS`,
and :data:`MAX_VALUES` rows × d), each fitted at most ``len(SEEDS)`` times. A larger map is compared
on a subsample (up to half of it the calibration queries' true places, the rest evenly spaced, in
index order) at the same bytes per row — a candidate's fixed cost (PQ's codebooks and projection, a
whitening basis) then weighs more than on the whole map, which handicaps those candidates; the
winner is refitted on the whole map at the whole budget.
OPQ (a learned d × d rotation, O(d³) per iteration of its fit) is a candidate up to :data:`MAX_ROTATION_FEATURES`
dimensions; RaBitQ's seeded rotation is O(d log d) per row, so it is one at every width. Not candidates: the
sequence methods (``seqslam`` reads the query order) and the slow paper variants (``btel-c``, ``btel-f``,
``btel-r``, ``btel-auto``, ``ryth``: minutes of fit on a few thousand rows). Calibration queries are read, scored
and dropped: the model stores no query and no query-derived array, only the table of scalars
(``choice_['calibration']``).
"""

from __future__ import annotations

import math
import time
import warnings
from typing import Any, Callable

import numpy as np

from ...core.storage import format_bytes
from ...core.validation import check_descriptors
from ...exceptions import BTELError, BudgetTooSmallError, DimensionMismatchError, InvalidParameterError

__all__ = ["ALPHA", "MAX_ROWS", "REFERENCE_DIFFERENCE", "SEEDS", "calibration_candidates", "check_calibration",
           "choose_calibrated", "decide", "max_t_pvalues", "mcnemar_exact", "queries_needed"]

#: Family-wise error level of the switch (max-T over the candidates).
ALPHA = 0.05
#: Seeds each seeded candidate is fitted at; its per-query correctness is the mean over them.
SEEDS = (0, 1)
#: Map rows compared at most (larger maps: a subsample at the same bytes per row) ...
MAX_ROWS = 4096
#: ... and at most this many map values (rows × d, 64 MB of float32): wide descriptors on fewer rows.
MAX_VALUES = 1 << 24
#: Random sign flips of the max-T adjustment (:func:`max_t_pvalues`).
N_BOOT = 4000
#: The test, as recorded in the table.
TEST = (
    "paired per-query differences against the map-only pick; one-sided max-T paired sign-flip "
    "permutation over all candidates (Westfall–Young); exact McNemar p per candidate for reference"
)
#: Fewest calibration queries with which a switch is possible: all of them won still leaves an
#: exact (and max-T) p of 2^-n, which must fall below :data:`ALPHA`.
MIN_SWITCH_QUERIES = int(math.ceil(math.log2(1 / ALPHA)))
#: The difference in calibration recall the "queries needed" column is stated for.
REFERENCE_DIFFERENCE = 0.05

#: OPQ, whose fit learns a d × d rotation (O(d³) per iteration), is compared only on descriptors of at
#: most this many dimensions.
MAX_ROTATION_FEATURES = 1024
#: (label, method, params, seeded): the calibrated candidates (module docstring).
CANDIDATES: tuple[tuple[str, str, dict[str, Any], bool], ...] = (
    ("lsh", "lsh", {"center": False}, True),
    ("lsh centred", "lsh", {"center": True}, True),
    ("lsh shrink", "lsh", {"center": False, "whiten": "shrink"}, True),
    ("btel-codes periodic", "btel-codes", {"code": "periodic"}, True),
    ("btel-codes periodic shrink", "btel-codes", {"code": "periodic", "whiten": "shrink"}, True),
    ("btel-codes random", "btel-codes", {"code": "random"}, True),
    ("btel-codes random shrink", "btel-codes", {"code": "random", "whiten": "shrink"}, True),
    ("pq", "pq", {}, True),
    ("pq shrink", "pq", {"whiten": "shrink"}, True),
    ("opq", "opq", {}, False),
    ("rabitq", "rabitq", {}, True),
    ("itq", "itq", {}, True),
    ("bruteforce", "bruteforce", {}, False),
    ("bruteforce shrink", "bruteforce", {"whiten": "shrink"}, False),
)


def calibration_candidates(whiten: Any = None, n_features: int | None = None) -> list[dict[str, Any]]:
    """The candidates as ``{"label", "method", "params", "seeded"}``; a user's ``whiten`` pins the front end,
    and OPQ is left out above :data:`MAX_ROTATION_FEATURES` dimensions."""
    out = []
    for label, method, params, seeded in CANDIDATES:
        if whiten is not None and params.get("whiten", None) not in (None, whiten):
            continue
        if method == "opq" and n_features is not None and n_features > MAX_ROTATION_FEATURES:
            continue
        out.append(
            {
                "label": label,
                "method": method,
                "seeded": seeded,
                "params": dict(params) if whiten is None else {**params, "whiten": whiten},
            }
        )
    return out


def mcnemar_exact(wins: int, losses: int) -> float:
    """One-sided exact McNemar p-value: P(≥ ``wins`` of ``wins + losses`` discordant pairs | no
    difference)."""
    from scipy.stats import binomtest

    n = int(wins) + int(losses)
    return 1.0 if n == 0 else float(binomtest(int(wins), n, 0.5, alternative="greater").pvalue)


def queries_needed(
    discordance: float, difference: float = REFERENCE_DIFFERENCE, alpha: float = ALPHA, power: float = 0.8
) -> int | None:
    """Calibration queries McNemar's test needs to detect ``difference`` at this discordance rate
    (Connor 1987).

    n = (z_α·√ψ + z_β·√(ψ − δ²))² / δ², ψ the share of discordant queries, one-sided. None when ψ < δ:
    a difference is at most the share of queries on which the two disagree, so the observed discordance
    cannot hold such a difference (the formula's small n there would read as "few queries suffice").
    """
    from scipy.stats import norm

    psi, delta = float(discordance), float(difference)
    if delta <= 0 or psi < delta - 1e-12:
        return None
    z_a, z_b = norm.ppf(1 - alpha), norm.ppf(power)
    return int(math.ceil((z_a * math.sqrt(psi) + z_b * math.sqrt(psi - delta * delta)) ** 2 / delta**2))


def max_t_pvalues(diffs: np.ndarray, n_boot: int = N_BOOT, seed: int = 0) -> np.ndarray:
    """One-sided p-values of "candidate k beats the pick", adjusted for every candidate at once (max-T).

    Parameters
    ----------
    diffs : ndarray of shape (n_candidates, n_queries)
        Per-query correctness of each candidate minus the pick's (in [−1, 1]).
    n_boot : int
        Random sign flips.

    Returns
    -------
    ndarray of shape (n_candidates,)
        p_k = share of random sign flips of the queries (one sign per query, shared by every
        candidate: the paired permutation under "no candidate differs from the pick") in which the
        largest studentised mean difference over the candidates reaches candidate k's observed t_k
        (Westfall and Young 1993): correlated candidates share the correction instead of each
        paying a Bonferroni factor, and with few discordant queries it is as strict as McNemar's
        exact test (4 wins, 0 losses: p ≈ 1/16). 1 for a candidate that never differs from the pick.
    """
    k, n = diffs.shape
    if k == 0:
        return np.zeros(0)
    squares = (diffs**2).sum(axis=1)

    def t_of(means: np.ndarray) -> np.ndarray:
        var = np.maximum(squares / n - means**2, 0.0) * n / max(n - 1, 1)
        se = np.sqrt(var / n)
        return np.where(se > 0, means / np.where(se > 0, se, 1.0), np.where(means > 0, np.inf, -np.inf))

    t = t_of(diffs.mean(axis=1))
    rng = np.random.default_rng(seed)
    peak = np.empty(n_boot)
    for start in range(0, n_boot, 256):
        signs = rng.choice([-1.0, 1.0], size=(min(256, n_boot - start), n))
        peak[start : start + signs.shape[0]] = t_of(signs @ diffs.T / n).max(axis=1)
    live = np.abs(diffs).sum(axis=1) > 0
    return np.array(
        [float((np.count_nonzero(peak >= tk) + 1) / (n_boot + 1)) if ok else 1.0 for tk, ok in zip(t, live)]
    )


def check_calibration(
    calibration: Any, n_features: int, n_places: int, tolerance: int
) -> tuple[np.ndarray, Any]:
    """``(Q, truth)`` checked: Q (n_queries, n_features) finite numbers, truth an int array of true places
    in [0, n_places) or a :class:`~btel.datasets.GroundTruth` over n_queries queries."""
    if not isinstance(calibration, (tuple, list)) or len(calibration) != 2:
        raise InvalidParameterError(
            "calibration must be a pair (Q, truth): the calibration queries (n_queries, "
            "n_features) and each one's true place (int array) or a GroundTruth."
        )
    Q = check_descriptors(calibration[0], name="the calibration query matrix")
    if Q.shape[1] != n_features:
        raise DimensionMismatchError(
            f"calibration queries have {Q.shape[1]} features; the map has {n_features}. "
            "Describe the queries with the map's descriptor."
        )
    if Q.shape[0] < 2:
        raise InvalidParameterError(
            f"calibration needs at least 2 labelled queries; got {Q.shape[0]}. Give more (at least "
            f"{MIN_SWITCH_QUERIES} for a switch to be possible; a few hundred certify a difference of "
            "0.10–0.15), or fit without calibration."
        )
    if int(tolerance) < 0:
        raise InvalidParameterError(f"calibration_tolerance must be ≥ 0; got {tolerance}.")
    truth = _checked_truth(calibration[1], Q.shape[0], n_places)
    if Q.shape[0] < MIN_SWITCH_QUERIES:
        warnings.warn(
            f"{Q.shape[0]} calibration queries cannot show any candidate better than the map-only pick "
            f"at α = {ALPHA} (that needs at least {MIN_SWITCH_QUERIES}): the map-only pick stays; give "
            "more labelled queries.", UserWarning, stacklevel=3)
    if truth.kind == "places" and int(tolerance) >= n_places - 1:
        warnings.warn(f"calibration_tolerance={tolerance} spans the whole map of {n_places} places: every prediction "
                      "counts as correct and no candidate can differ; give a few places.", UserWarning, stacklevel=3)
    if truth.kind != "places" and int(tolerance) > 0:
        warnings.warn(
            f"calibration_tolerance={tolerance} is not used: the calibration ground truth lists each "
            "query's positives, and a prediction is correct when it is one of them.", UserWarning, stacklevel=3)
    return Q, truth


def _checked_truth(truth: Any, n_queries: int, n_places: int) -> Any:
    """The calibration truth as a :class:`~btel.datasets.GroundTruth` over ``n_queries`` queries."""
    from ...datasets.groundtruth import GroundTruth

    if isinstance(truth, GroundTruth):
        if truth.n_queries != n_queries:
            raise InvalidParameterError(
                f"the calibration ground truth covers {truth.n_queries} queries; "
                f"there are {n_queries} calibration queries."
            )
        if truth.n_map is not None and truth.n_map > n_places:
            raise InvalidParameterError(
                f"the calibration ground truth names {truth.n_map} map places; the map has " f"{n_places}."
            )
        return truth
    arr = np.asarray(truth)
    if arr.ndim != 1 or arr.shape[0] != n_queries or not np.issubdtype(arr.dtype, np.integer):
        raise InvalidParameterError(
            f"the calibration truth must be an int array of shape ({n_queries},), one true "
            f"place per query, or a GroundTruth; got {arr.dtype} of shape {arr.shape}."
        )
    bad = np.flatnonzero((arr < 0) | (arr >= n_places))
    if bad.size:
        raise InvalidParameterError(
            f"calibration true places must be map places 0 … {n_places - 1}; query {bad[0]} has "
            f"{arr[bad[0]]} ({bad.size} quer{'ies' if bad.size > 1 else 'y'} outside). Give the truth "
            "as indices into the map's rows (or its places)."
        )
    return GroundTruth.from_places(arr.astype(np.int64), n_map=n_places)


def compared_rows(n_features: int) -> int:
    """The most map rows calibration compares candidates on, for rows of ``n_features`` values."""
    return int(min(MAX_ROWS, max(256, MAX_VALUES // max(int(n_features), 1))))


def _subsample(n_places: int, truth: Any, tolerance: int, cap: int) -> np.ndarray | None:
    """Map places compared (sorted), or None for the whole map: the truths' windows, filled evenly."""
    if n_places <= cap:
        return None
    wanted = np.unique(np.concatenate([truth.positives(j, tolerance) for j in range(truth.n_queries)]))
    wanted = wanted[wanted < n_places]
    if wanted.size > cap // 2:
        wanted = wanted[np.linspace(0, wanted.size - 1, cap // 2).round().astype(np.int64)]
    fill = np.setdiff1d(np.linspace(0, n_places - 1, cap).round().astype(np.int64), wanted)
    fill = fill[np.linspace(0, fill.size - 1, min(fill.size, cap - wanted.size)).round().astype(np.int64)]
    return np.union1d(wanted, fill)


def decide(table: list[dict[str, Any]], correct: dict[str, np.ndarray], pick: str) -> str:
    """The chosen candidate's label; fills each table row's paired comparison with ``pick`` (in place).

    Parameters
    ----------
    table : list of dict
        One row per candidate (``candidate``, ``status``, ``score``).
    correct : dict
        Candidate label → per-query correctness, ndarray of shape (n_queries,), float in [0, 1].
    pick : str
        The map-only pick's label. When it has no scores (it did not fit), it stays the choice.
    """
    tested = [e for e in table if e.get("status") == "ok" and e["candidate"] != pick and pick in correct]
    n = next(iter(correct.values())).size if correct else 0
    diffs = (
        np.stack([correct[e["candidate"]] - correct[pick] for e in tested]) if tested else np.zeros((0, n))
    )
    adjusted = max_t_pvalues(diffs)
    for e, diff, p_adj in zip(tested, diffs, adjusted):
        wins, losses = int(np.count_nonzero(diff > 0)), int(np.count_nonzero(diff < 0))
        psi, alpha = (wins + losses) / diff.size, ALPHA / len(tested)
        e.update(
            {
                "difference": round(float(diff.mean()), 4),
                "wins": wins,
                "losses": losses,
                "p_mcnemar": round(mcnemar_exact(wins, losses), 4),
                "p_adjusted": round(float(p_adj), 4),
                "confidence": round(1.0 - float(p_adj), 4),
                "queries_needed": queries_needed(psi, alpha=alpha),
                # the queries that would certify this candidate's lead (none for a candidate behind)
                "queries_needed_observed": (
                    queries_needed(psi, float(diff.mean()), alpha) if diff.mean() > 0 else None
                ),
            }
        )
    better = [e for e in tested if e["p_adjusted"] < ALPHA and e["difference"] > 0]
    chosen = max(better, key=lambda e: e["score"])["candidate"] if better else pick
    for e in table:
        e["role"] = (
            "chosen" if e["candidate"] == chosen else "map-only pick" if e["candidate"] == pick else ""
        )
    return chosen


def choose_calibrated(
    X: np.ndarray,
    places: np.ndarray | None,
    budget: int | None,
    Q: np.ndarray,
    truth: Any,
    tolerance: int,
    map_only: dict[str, Any],
    make: Callable[[str, dict[str, Any], int | None], Any],
    whiten: Any = None,
    progress: bool = False,
) -> dict[str, Any]:
    """Score every candidate on the calibration queries; the table and the chosen candidate.

    Parameters
    ----------
    X, places, budget : ndarray (n_rows, n_features) float32; ndarray (n_rows,) int or None; int or None
    Q : ndarray of shape (n_queries, n_features)
    truth : GroundTruth
        Over the map's places (:func:`check_calibration`).
    tolerance : int
    map_only : dict
        The map-only rule's pick (``method``, ``params``).
    make : callable
        ``make(method, params, budget)`` → an unfitted localizer with the auto's seed and front end.
    whiten : None or the user's ``whiten``
    progress : bool
        Progress over the candidates' fits: a bar on a terminal, a line every 10 s in a log.

    Returns
    -------
    dict
        ``{"method", "params", "label", "calibration": {…table…}}``.
    """
    labels = np.arange(X.shape[0]) if places is None else places
    back = _subsample(int(labels.max()) + 1, truth, tolerance, compared_rows(X.shape[1]))  # kept places, in order
    Xc, pc, sub_budget = X, places, budget
    if back is not None:  # the subsample's place i is the whole map's place back[i]
        mask = np.isin(labels, back)
        Xc, pc = X[mask], (None if places is None else np.searchsorted(back, labels[mask]))
        sub_budget = None if budget is None else int(budget * np.count_nonzero(mask) / X.shape[0])
    candidates = calibration_candidates(whiten, X.shape[1])
    key = (map_only["method"], sorted(map_only["params"].items()))
    if not any((c["method"], sorted(c["params"].items())) == key for c in candidates):
        candidates.insert(0, {"label": "map-only pick", "method": map_only["method"], "params": dict(map_only["params"]),
                              "seeded": map_only["method"] != "bruteforce"})
    from ...core.progress import progress_bar

    table: list[dict[str, Any]] = []
    correct: dict[str, np.ndarray] = {}
    bar = progress_bar(sum(len(SEEDS) if c["seeded"] else 1 for c in candidates), "calibrating auto", "fit", progress)
    for cand in candidates:
        entry = {"candidate": cand["label"], "method": cand["method"], "params": cand["params"]}
        start, runs, query_s, seeds = time.perf_counter(), [], 0.0, SEEDS if cand["seeded"] else (None,)
        bar.set_postfix_str(cand["label"])
        try:
            for seed in seeds:
                params = cand["params"] if seed is None else {**cand["params"], "random_state": seed}
                model = make(cand["method"], params, sub_budget)
                model._warn_colliding_codes = False  # a candidate, scored: the user's model is the one chosen
                model.fit(Xc, pc)
                tick = time.perf_counter()  # its answers' time, beside its accuracy: the table shows both
                pred = model.predict(Q)
                query_s += time.perf_counter() - tick
                runs.append(truth.is_correct(pred if back is None else back[pred], tolerance))
                bar.update(1)
        except BudgetTooSmallError as exc:
            # the candidate's own bytes at this budget: a calibration-table cell, not a run's row status
            table.append({**entry, "status": "over budget", "needs": format_bytes(exc.minimum or 0)})
            continue
        except BTELError as exc:  # a candidate that cannot index this map (too few rows to train, …)
            table.append({**entry, "status": f"cannot fit: {str(exc)[:160]}"})
            continue
        finally:
            bar.update(len(seeds) - len(runs))  # a refused candidate's fits count as done
        correct[cand["label"]] = np.mean(runs, axis=0)
        table.append({**entry, "status": "ok", "score": round(float(correct[cand["label"]].mean()), 4),
                      "fit_s": round(time.perf_counter() - start, 2),
                      "query_us": round(1e6 * query_s / (len(runs) * Q.shape[0]), 1)})
    bar.close()
    _warn_if_no_better_than_chance(table, truth, back if back is not None else np.arange(int(labels.max()) + 1),
                                   tolerance)
    pick = next(c["label"] for c in candidates if (c["method"], sorted(c["params"].items())) == key)
    chosen = decide(table, correct, pick)
    spec = next(c for c in candidates if c["label"] == chosen)
    return {
        "label": chosen,
        "method": spec["method"],
        "params": dict(spec["params"]),
        "calibration": {
            "n_queries": int(Q.shape[0]),
            "tolerance": int(tolerance),
            "correct_when": (f"within {int(tolerance)} place{'s' if int(tolerance) != 1 else ''} of the true place"
                             if truth.kind == "places" else "among the query's positives"),
            "seeds": list(SEEDS),
            "alpha": ALPHA,
            "test": TEST,
            "map_only": pick,
            "chosen": chosen,
            "switched": chosen != pick,
            "rows_compared": int(Xc.shape[0]),
            "budget_compared": sub_budget,
            "reference_difference": REFERENCE_DIFFERENCE,
            "table": table,
        },
    }


def _warn_if_no_better_than_chance(table: list[dict[str, Any]], truth: Any, places: np.ndarray, tolerance: int) -> None:
    """Warn when no candidate beats what random guesses among the compared ``places`` reach by luck (the 99.9 %
    binomial quantile): the ground truth is then likely not these queries' (another split's, order, numbering)."""
    from scipy.stats import binom

    scores = [row["score"] for row in table if row["status"] == "ok"]
    guesses = places[np.random.default_rng(0).integers(0, places.size, (256, truth.n_queries))]
    chance = float(np.mean([truth.is_correct(guess, tolerance).mean() for guess in guesses]))
    luck = float(binom.ppf(0.999, truth.n_queries, chance)) / truth.n_queries
    if scores and max(scores) <= luck:
        warnings.warn(f"no calibration candidate localizes more than {max(scores):.2%} of the calibration queries, "
                      f"which random guesses reach by luck (a guess is right {chance:.2%} of the time): check that "
                      "the calibration ground truth is these queries' (their order, their numbering of places); if it "
                      "is, the budget is too small for this map or the queries too few to tell the candidates apart. "
                      "The calibration table is kept as measured.", UserWarning, stacklevel=5)

"""Results as text: the console table of a run and the one-line description of an experiment row.

One place for how results read on a terminal: :func:`format_table` (``btel evaluate``, ``btel
demo``) and :func:`describe_row` (``btel experiment``). Both read :class:`~btel.evaluation.records.EvaluationResult`.
"""

from __future__ import annotations

import csv
import io
import json
import shutil
import sys
import textwrap
from collections.abc import Sequence
from typing import Any

from .records import STATUS_DOES_NOT_FIT, EvaluationResult
from ..core.modelfile import jsonable
from ..core.storage import format_bytes

__all__ = ["format_table", "terminal_width", "format_calibration", "calibration_markdown", "describe_row", "metrics_csv_text",
           "predictions_csv_text", "rows_csv_text", "SEQUENCE_MARK", "REFERENCE_MARK", "SATURATED_MARK",
           "ONE_SCORE_MARK", "PR_TABLE_NAMES"]

SEQUENCE_MARK = "†"
REFERENCE_MARK = "*"
SATURATED_MARK = "‡"
#: Beside the precision-recall cells of a row whose scores are one value for every query.
ONE_SCORE_MARK = "°"
#: The precision–recall columns of the console table: AUC-PR by VPR-Bench and by VPR_Tutorial, R@100%P.
PR_TABLE_NAMES = ("AUC-PR:VB", "AUC-PR:VT", "R@100%P")


def format_table(results: Sequence[EvaluationResult], width: int = 0) -> str:
    """The results as a plain-text table, with the metrics the ground truth supports.

    Columns: method, status, bytes, fit seconds, batch µs per query (median throughput), single-query
    latency in µs, the thread count, recall@t for every tolerance any
    row has (frame-aligned ground truth only) and R@K for every K. Rows that did not run show
    their status and reason. ``†`` marks methods that use the query sequence (not comparable
    with single-frame methods), ``*`` the unbudgeted reference, ``‡`` a model that cannot use the rest
    of its budget, ``°`` precision-recall areas of a row whose top-1 scores are all equal; a legend line
    says so.

    ``width`` (characters, e.g. :func:`terminal_width`): a table wider than it is printed in blocks
    of columns that fit, each led by the method column, and the legend wrapped; 0: one block however
    wide (a log or a file keeps one line per row).
    """
    tolerances = sorted({t for r in results for t in r.recall})
    ks = sorted({k for r in results for k in (r.recall_at_k or {})})
    has_pr = any(r.recall_at_100_precision is not None for r in results)
    metric_names = [f"recall@{t}" for t in tolerances] + [f"R@{k}" for k in ks]
    metric_names += list(PR_TABLE_NAMES) if has_pr else []
    label_width = max([len("method")] + [len(_row_label(r)) for r in results]) + 1
    # (name, width) of every column after the method's; a row's cells follow the same order.
    columns = [("status", -12), ("bytes", 10), ("fit s", 7), ("batch µs/q", 10), ("1-query µs", 10),
               ("threads", 7)] + [(m, 9) for m in metric_names]
    saturated_rows = any(r.ok and r.budget_saturated for r in results)  # then every size keeps a mark's column
    rows: list[tuple[str, list[str] | str]] = []
    for r in results:
        label = _row_label(r)
        if not r.ok:
            # The table says what the user needs to decide; the full message is in metrics.csv/json.
            why = (f"needs ≥ {format_bytes(r.minimum_bytes)}"
                   + (f" (budget {format_bytes(r.budget)})" if r.budget is not None else "")
                   if r.status == STATUS_DOES_NOT_FIT and r.minimum_bytes is not None else (r.reason or ""))
            rows.append((label, f"{r.status:<12} {why}"))
            continue
        size = (format_bytes(r.nbytes) if r.nbytes is not None else "?") + (
            (SATURATED_MARK if r.budget_saturated else " ") if saturated_rows else "")
        fit = f"{r.fit_time_s:.1f}" if r.fit_time_s is not None else "-"
        cells = [f"{v:.3f}" if v is not None else "-"
                 for v in [r.recall.get(t) for t in tolerances] + [(r.recall_at_k or {}).get(k) for k in ks]]
        if has_pr:
            mark = ONE_SCORE_MARK if _one_score(r) else ""
            cells += [f"{v:.3f}{mark}" if v is not None else "-"
                      for v in (r.auc_pr_vpr_bench, r.auc_pr_vpr_tutorial, r.recall_at_100_precision)]
        query = f"{r.query_time_s_per_query * 1e6:.1f}" if r.query_time_s_per_query is not None else "-"
        latency = f"{r.query_latency_s * 1e6:.1f}" if r.query_latency_s is not None else "-"
        threads = str(r.n_threads) if r.n_threads is not None else "-"
        rows.append((label, [r.status, size, fit, query, latency, threads] + cells))
    lines: list[str] = []
    for block in _column_blocks(columns, label_width, width):
        header = f"{'method':<{label_width}} " + " ".join(_cell(name, w) for name, w in (columns[i] for i in block))
        lines += ([""] if lines else []) + [header.rstrip(), "-" * len(header.rstrip())]
        for label, cells in rows:
            if isinstance(cells, str):  # a row that did not run: its status and why, in the first block only
                if block[0] == 0:
                    lines.append(f"{label:<{label_width}} {cells}")
                continue
            lines.append((f"{label:<{label_width}} " + " ".join(_cell(cells[i], columns[i][1]) for i in block)).rstrip())
    notes = []
    repeats = {r.timing_repeats for r in results if r.ok and r.timing_repeats}
    if repeats:
        notes.append(f"batch µs/q: median of {'/'.join(map(str, sorted(repeats)))} timed predict calls on all queries "
                     "after a warm-up, per query; 1-query µs: median latency of one query answered alone")
    if tolerances:
        notes.append("recall@t: point prediction within t frames of the true place")
    if ks:
        k_tol = max((r.tolerance_for_k for r in results if r.ok), default=0)
        within = f" (within {k_tol} frames)" if k_tol else ""
        notes.append(f"R@K: a correct place{within} among the top K ranked candidates")
    if has_pr:
        notes.append("AUC-PR, R@100%P: precision-recall of accepting each query's top-1 match by its score")
        notes.append("AUC-PR:VB as VPR-Bench computes it (recall over correct top-1 matches only: a method right on "
                     "few queries can still score high, so read it beside R@1); AUC-PR:VT and "
                     "R@100%P as VPR_Tutorial (recall over queries with a true place)")
    if has_pr and any(r.ok and _one_score(r) for r in results):
        notes.append(f"{ONE_SCORE_MARK} every query's top-1 has the same score: the precision-recall curve is one "
                     "point, so these areas say nothing about how well the scores rank the matches")
    if any(r.reference for r in results):
        notes.append(f"{REFERENCE_MARK} reference (unbudgeted)")
    if saturated_rows:
        notes.append(f"{SATURATED_MARK} the largest model the method's parameters allow: the rest of its budget "
                     "stays unused (a larger budget gives the same model)")
    if any(r.uses_query_sequence for r in results):
        notes.append(f"{SEQUENCE_MARK} uses the query sequence: not comparable with single-frame methods")
    wrap = textwrap.TextWrapper(width, initial_indent="  ", subsequent_indent="    ", break_on_hyphens=False)
    lines += [wrap.fill(n) if width else f"  {n}" for n in notes]
    return "\n".join(lines)


def _one_score(r: EvaluationResult) -> bool:
    """The row's precision-recall curve has one point: the same score for every query's top-1 match."""
    return bool(r.pr_curve) and len(r.pr_curve.get("recall") or ()) == 1


def terminal_width() -> int:
    """The width of the terminal standard output goes to (``$COLUMNS`` first), or 0 when it goes
    elsewhere (a pipe, a file, a log: one line per row there): :func:`format_table`'s ``width``."""
    isatty = getattr(sys.stdout, "isatty", None)
    return shutil.get_terminal_size(fallback=(0, 0)).columns if isatty is not None and isatty() else 0


def _cell(text: str, width: int) -> str:
    """``text`` right-aligned in ``width`` characters (left-aligned for a negative width)."""
    return f"{text:<{-width}}" if width < 0 else f"{text:>{width}}"


def _column_blocks(columns: list[tuple[str, int]], label_width: int, width: int) -> list[list[int]]:
    """Indices of ``columns`` grouped into blocks that fit ``width`` after the method column (one block
    when ``width`` is 0 or every column fits); a block holds at least one column."""
    blocks: list[list[int]] = [[]]
    used = label_width
    for i, (_, w) in enumerate(columns):
        if width and blocks[-1] and used + 1 + abs(w) > width:
            blocks.append([])
            used = label_width
        blocks[-1].append(i)
        used += 1 + abs(w)
    return blocks


def _calibration_tables(results: Sequence[EvaluationResult]) -> list[tuple[str, str, dict[str, Any]]]:
    """(row name, its calibration table as text, the table) of every row that chose on labelled queries."""
    from ..methods.registry import calibration_table  # the text auto's summary() and `btel info` show

    found = [(r.name, (r.choice or {}).get("calibration")) for r in results]
    return [(name, calibration_table(c), c) for name, c in found if calibration_table(c)]


def format_calibration(results: Sequence[EvaluationResult]) -> str:
    """The calibration table of every row whose method chose on labelled queries (``choice["calibration"]``:
    each candidate's calibration recall, its paired difference with the map-only pick, adjusted p,
    confidence, the queries a difference needs, the switch); '' when no row did."""
    return "\n".join(f"{name} — {table}" for name, table, _ in _calibration_tables(results))


def calibration_markdown(results: Sequence[EvaluationResult], title: str | None = None) -> str:
    """A run folder's ``calibration.md``: :func:`format_calibration`'s tables, one section per row;
    '' when no row chose on labelled queries."""
    tables = _calibration_tables(results)
    if not tables:
        return ""
    lines = ["# Calibration", ""] + ([title, ""] if title else [])  # each table carries its own legend
    for name, table, c in tables:
        switched = (f"switched from the map-only pick {c.get('map_only')} to {c.get('chosen')}"
                    if c.get("switched") else f"kept the map-only pick {c.get('map_only')}")
        lines += [f"## {name}", "", f"{switched} (family-wise α = {c.get('alpha')}; {c.get('test')}).", "",
                  "```text", table, "```", ""]
    return "\n".join(lines)


def _row_label(r: EvaluationResult) -> str:
    return r.name + (REFERENCE_MARK if r.reference else "") + (SEQUENCE_MARK if r.uses_query_sequence else "")


# -- CSV ------------------------------------------------------------------------------------------
def _fmt(value: float | int | None) -> str:
    if value is None:
        return ""
    return repr(float(value)) if isinstance(value, float) else str(value)


#: What each column of a run folder's CSV files means (written into its metrics.json as ``columns``).
RUN_COLUMNS: dict[str, dict[str, str]] = {
    "metrics.csv": {
        "method": "the row's name: a method, a --model file's name, or name@budget in a budget sweep",
        "chosen_method": "what an auto row ran (empty for the other rows)",
        "status": "ok, or why the row has no figures: does not fit (the budget), failed, refused, not run",
        "reference": "1 for the unbudgeted reference row (brute force)",
        "uses_query_sequence": "1 when answers depend on the query sequence (SeqSLAM, a delta front end)",
        "budget": "bytes the method was given (empty: unbudgeted)",
        "n_map": "map places N", "n_queries": "query rows",
        "nbytes": "bytes the fitted model stores, by btel's storage rule (docs/guide/concepts.md)",
        "budget_saturated": "1 when the model is the largest its parameters allow: more budget gives the same model",
        "fit_time_s": "wall-clock seconds of fit",
        "query_time_s_per_query": "median seconds of predict on all queries at once, divided by their number",
        "query_latency_s": "median seconds of one query answered alone",
        "n_threads": "threads the numerical libraries could use while timing",
        "recall@t": "share of queries whose top-1 place is within t frames (or places) of a true place",
        "R@K": "share of queries with a true place among their top K candidates",
        "auc_pr_vpr_bench": "area under precision-recall of accepting each top-1 by its score, as VPR-Bench "
                            "computes it",
        "auc_pr_vpr_tutorial": "the same area as VPR_Tutorial computes it (docs/decisions/auc-pr.md)",
        "recall@100%precision": "share of queries accepted before the first wrong top-1, by score",
        "reason": "the message behind a status other than ok",
    },
    "predictions_<method>.csv": {
        "query": "query row, from 0", "prediction": "top-1 place (map row, from 0)",
        "true": "the query's true place (one per query)", "positive": "one of the query's positives (-1: none)",
        "correct": "1 when the top-1 is a true place", "rank_K": "the K-th ranked candidate",
        "query_name, prediction_name, true_name / positive_name": "the image names of those rows, where the inputs "
                                                                   "record them",
    },
}


def metrics_csv_text(results: Sequence[EvaluationResult]) -> str:
    """The ``metrics.csv`` of a run folder: one row per record, every recall@t and R@K any row has
    (``chosen_method``: what an ``auto`` row ran; empty for the others)."""
    tolerances = sorted({t for r in results for t in r.recall})
    ks = sorted({k for r in results for k in (r.recall_at_k or {})})
    header = ["method", "chosen_method", "status", "reference", "uses_query_sequence", "budget", "n_map", "n_queries",
              "nbytes", "budget_saturated", "fit_time_s", "query_time_s_per_query", "query_latency_s", "n_threads"]
    header += [f"recall@{t}" for t in tolerances] + [f"R@{k}" for k in ks]
    header += ["auc_pr_vpr_bench", "auc_pr_vpr_tutorial", "recall@100%precision", "reason"]
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    for r in results:
        row = [r.name, r.chosen_method or "", r.status, int(r.reference), int(r.uses_query_sequence), _fmt(r.budget), _fmt(r.n_map),
               r.n_queries, _fmt(r.nbytes), int(r.budget_saturated), _fmt(r.fit_time_s), _fmt(r.query_time_s_per_query),
               _fmt(r.query_latency_s), _fmt(r.n_threads)]
        row += [_fmt(r.recall.get(t)) for t in tolerances]
        row += [_fmt((r.recall_at_k or {}).get(k)) for k in ks]
        row += [_fmt(r.auc_pr_vpr_bench), _fmt(r.auc_pr_vpr_tutorial), _fmt(r.recall_at_100_precision)]
        row.append(r.reason or "")
        writer.writerow(row)
    return buffer.getvalue()


def predictions_csv_text(r: EvaluationResult, query_names: Sequence[str] | None = None,
                         db_names: Sequence[str] | None = None) -> str:
    """The ``predictions_<method>.csv`` of the row ``r``: :func:`btel.datasets.predictions.predictions_csv` of its predictions, its
    ground truth and its ranking (when it ranked more than one candidate)."""
    from ..datasets.predictions import predictions_csv

    ranked = r.ranked if r.ranked is not None and r.ranked.shape[1] > 1 else None
    return predictions_csv(r.predictions, ranked=ranked, ground_truth=r.ground_truth, query_names=query_names,
                           db_names=db_names)


def rows_csv_text(records: Sequence[EvaluationResult]) -> str:
    """An experiment's ``results.csv``: the flat rows (:meth:`~btel.evaluation.records.EvaluationResult.to_row`),
    one column per cell any row has, in order of first appearance."""
    # A cell holding a dict or list (a front end, options) is written as JSON, not as Python's repr.
    rows = [{k: json.dumps(jsonable(v)) if isinstance(v, (dict, list, tuple)) else v for k, v in r.to_row().items()}
            for r in records]
    columns: list[str] = []
    for row in rows:
        columns.extend(k for k in row if k not in columns)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns)
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def describe_row(record: EvaluationResult) -> str:
    """One human line for an experiment's row (``btel experiment``).

    Metric names as everywhere in btel: ``recall@t`` is the point prediction within t frames,
    ``R@K`` a correct place among the top K ranked candidates. ``†`` marks methods that use the
    query sequence; the map→query direction is named when the row has one.
    """
    row = record.to_row()
    name = record.name + (" †" if record.uses_query_sequence else "")
    if row.get("direction") and "part" not in row:
        name += f" [{row['direction']}]"
    if record.status != "ok":
        return f"{name:<30} {record.status}"
    if "decoder" in row or "part" in row:  # the "beyond" experiment: say which read-out and where
        where = row.get("direction") or f"shift {row.get('condition_shift')}"
        label = f"{name} [{row.get('decoder', 'single')}, {where}]"
        ranked = f" R@10={row['R@10']:.3f}" if row.get("R@10") is not None else ""
        return (f"{label:<52} N={row['n_places']:<5} {format_bytes(row['nbytes']):>10}  "
                f"recall@10={row['recall@10']:.3f}{ranked}")
    size = format_bytes(row["nbytes"]) if row.get("nbytes") is not None else "-"
    ranked = "".join(f" R@{k}={row[f'R@{k}']:.3f}" for k in (1, 10) if row.get(f"R@{k}") is not None)
    shown = ["recall@0", "recall@10", "recall@20"]
    key = row.get("key")  # the frontier's key recall of the map (recall@2 on a route) first when it is another
    if isinstance(key, str) and key not in shown and row.get(key) is not None:
        shown.insert(1, key)
    return f"{name:<30} N={row['n_places']:<5} {size:>10}  " + " ".join(
        f"{m}={row[m]:.3f}" for m in shown) + ranked

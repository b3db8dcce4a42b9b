"""Full training, BTE-F (the paper's training schemes): one classifier per internal tree node.

Nodes are numbered in heap order (root 0, children 2j+1 and 2j+2). Node j at level l with prefix p
covers the places whose top l bits equal p and is trained on them with label bit l+1 (0-based:
``bits[:, l]``). A node whose places all share one label stores no classifier; with every place
0..N−1 present that happens exactly when the node holds no place with bit l = 1, so the constant is
always 0 and which nodes are stored follows from N alone (no node table is stored). Inference
descends from the root, one node per level. Storage grows linearly with N (about N−1 hyperplanes):
BTE-F is the paper's foil for BTE-C.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from .encoding import encode, n_bits_for
from ...learning.hyperplanes import Hyperplanes
from ...learning.training import Task

__all__ = ["full_nodes", "full_n_classifiers", "full_tasks", "predict_full", "full_path_matrices", "full_costs"]


def full_nodes(n_places: int) -> tuple[np.ndarray, np.ndarray]:
    """Levels and prefixes of the nodes that store a classifier, in heap order.

    Returns
    -------
    levels : ndarray of shape (K,), int64
    prefixes : ndarray of shape (K,), int64
        Node (l, p) is heap node ``2**l − 1 + p`` and holds places ``[p·2^(b−l), (p+1)·2^(b−l)) ∩ [0, N)``.
    """
    b = n_bits_for(n_places)
    levels, prefixes = [], []
    for level in range(b):
        span = 1 << (b - level)
        p = np.arange(-(-n_places // span), dtype=np.int64)  # non-empty nodes at this level
        # The node needs a classifier when its upper half (bit = 1) holds at least one place.
        p = p[p * span + span // 2 <= n_places - 1]
        levels.append(np.full(p.size, level, dtype=np.int64))
        prefixes.append(p)
    return np.concatenate(levels), np.concatenate(prefixes)


def full_n_classifiers(n_places: int) -> int:
    """Number of hyperplanes BTE-F stores for N places: N − 1 (the size of :func:`full_nodes`).

    In closed form because a model file's N is checked against its arrays with it, before
    anything of size N is built.
    """
    return max(int(n_places) - 1, 0)


def full_tasks(places: np.ndarray, n_places: int, rows: np.ndarray | None = None) -> list[Task]:
    """One task per node that stores a classifier, in heap order (same arguments as
    :func:`btel.methods.btel.compressed.compressed_tasks`). Node (l, p) sees the rows whose place has top l
    bits p, labelled with bit l."""
    b = n_bits_for(n_places)
    bits = encode(places, b)
    all_rows = np.arange(places.size) if rows is None else np.asarray(rows)
    order = np.argsort(places, kind="stable")
    sorted_places = places[order]
    tasks = []
    for level, prefix in zip(*full_nodes(n_places)):
        span = 1 << (b - int(level))
        lo, hi = np.searchsorted(sorted_places, [prefix * span, (prefix + 1) * span])
        local = order[lo:hi]
        tasks.append(Task(labels=bits[local, level], rows=all_rows[local]))
    return tasks


def predict_full(
    Q: np.ndarray, hyperplanes: Hyperplanes, first_row: int, n_places: int
) -> tuple[np.ndarray, np.ndarray]:
    """Descend a BTE-F tree whose node classifiers are rows ``first_row…`` of ``hyperplanes``.

    Returns
    -------
    indices : ndarray of shape (n_queries,), int64 in [0, N)
    margins : ndarray of shape (n_queries, b), float32
        Margin of the node visited at each level; −inf where the node is constant (bit 0).
    """
    b = n_bits_for(n_places)
    levels, prefixes = full_nodes(n_places)
    heap_ids = (1 << levels) - 1 + prefixes
    row_of_heap = np.full((1 << b) - 1, -1, dtype=np.int64)
    row_of_heap[heap_ids] = first_row + np.arange(heap_ids.size)
    n = Q.shape[0]
    prefix = np.zeros(n, dtype=np.int64)
    margins = np.full((n, b), -np.inf, dtype=np.float32)
    for level in range(b):
        rows = row_of_heap[(1 << level) - 1 + prefix]
        has = rows >= 0
        bit = np.zeros(n, dtype=np.int64)
        if has.any():
            m = hyperplanes.margins_per_row(Q[has], rows[has])
            margins[has, level] = m
            bit[has] = m > 0
        prefix = (prefix << 1) | bit
    return prefix, margins


@functools.lru_cache(maxsize=32)
def full_path_matrices(n_places: int) -> tuple[Any, Any]:
    """Which stored nodes lie on each place's root-to-leaf path, and the side the path takes.

    Returns
    -------
    on_path : scipy.sparse.csr_matrix of shape (K, N), float64
        1 where node (row, heap order of :func:`full_nodes`) is on place i's path.
    signed : scipy.sparse.csr_matrix of shape (K, N), float64
        +1 / −1 where the path goes to the node's bit-1 / bit-0 child.
    """
    import scipy.sparse as sp

    b = n_bits_for(n_places)
    levels, prefixes = full_nodes(n_places)
    row_of_heap = np.full((1 << b) - 1, -1, dtype=np.int64)
    row_of_heap[(1 << levels) - 1 + prefixes] = np.arange(levels.size)
    places = np.arange(n_places, dtype=np.int64)
    bits = encode(places, b)
    rows, cols, signs = [], [], []
    for level in range(b):
        node = row_of_heap[(1 << level) - 1 + (places >> (b - level))]
        stored = node >= 0
        rows.append(node[stored])
        cols.append(places[stored])
        signs.append(2.0 * bits[stored, level] - 1.0)
    rows, cols, signs = np.concatenate(rows), np.concatenate(cols), np.concatenate(signs)
    shape = (levels.size, n_places)
    on_path = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=shape)
    signed = sp.csr_matrix((signs, (rows, cols)), shape=shape)
    return on_path, signed


def full_costs(margins: np.ndarray, n_places: int) -> np.ndarray:
    """Cost of every place of one BTE-F tree: Σ over the stored nodes on its path of ``|m| − m·side``.

    The greedy descent's leaf costs 0 (it follows every node's sign), so ranking by this cost
    starts with :func:`predict_full`'s answer (up to exact ties).

    Parameters
    ----------
    margins : ndarray of shape (n_queries, K)
        Margins of every stored node of the tree, heap order.

    Returns
    -------
    ndarray of shape (n_queries, N), float64, ≥ 0
    """
    on_path, signed = full_path_matrices(n_places)
    m = np.asarray(margins, dtype=np.float64)
    return np.asarray((on_path.T @ np.abs(m).T).T - (signed.T @ m.T).T)

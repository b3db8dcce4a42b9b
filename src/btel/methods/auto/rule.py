"""The rule of ``auto``: the method, code family and front end chosen from the map and the budget alone.

No query and no label of a query is read: the choice depends on the map descriptors, their place
labels, N, d and the byte budget. The rule was fixed on the development data (Gardens Point
NetVLAD, the same with map and query rows permuted together, Nordland HOG both directions, a
synthetic route and synthetic independent places; ``btel experiment frontier``) and is not tuned
per map:

1. **Route, ordered map or independent places** (:func:`index_order`). The *route share* is the
   share of map rows whose nearest other map row (cosine, on L2-normalised rows; up to
   :data:`STAT_ROWS` rows sampled evenly) lies within :data:`ROUTE_WINDOW` = 2 places of it.
   Consecutive frames of a route look alike (Gardens Point 0.975); a map of independent places does
   not (Gardens Point permuted 0.05, synthetic independent places 0.00). Route when the share is at
   least :data:`ROUTE_SHARE` = 0.5: two NetVLAD sets of independent places have 0.14–0.40, so 0.5
   keeps them off the route branch; Nordland HOG (every 10th frame, 0.27 / 0.31) and the synthetic
   route (0.12) fall below it too and are *ordered* maps (step 3).
   And only when the *route continuity* (:func:`route_continuity`: the mean percentile rank of a
   row's cosine to the rows 3 … 8 places away, among its cosines to the map; 0.5 when the order says
   nothing) is at least :data:`ROUTE_CONTINUITY` = 0.75, halfway to a perfectly smooth route. The
   share sees only the nearest frame: a route cut into snippets of 3 frames in random order already
   has share 0.60–0.62, and the periodic codes, which assume that the whole index order is a route,
   lost there to LSH at every budget (``python benchmarks/bench_route_snippets.py``, Gardens Point,
   recall@0 at 4 / 16 / 64 KB mapped by day: 0.059 / 0.089 / 0.140 vs LSH 0.130 / 0.140 / 0.153,
   whitened LSH 0.180 at 64 KB; snippets of 5 and 10 alike; with the codes' ridge at ρ = 0.1 the
   snippets of 3 give 0.076 / 0.094 / 0.141, and those of 10 (continuity 0.61) edge ahead from 16 KB,
   0.152 / 0.183 vs LSH 0.147 / 0.155 and whitened LSH 0.158 / 0.177). The continuity there is 0.52–0.62; along
   the routes 0.87 / 0.89 (Gardens Point at night / by day), 0.97 (the synthetic route), 0.68
   (Nordland HOG, every 10th frame); snippets of 20 and 40 frames reach 0.75–0.83, where the codes
   were level with or ahead of LSH by day. Added after the frontier of the night-mapped Gardens
   Point; it changed no development choice.
2. **Route** → ``btel-codes`` with periodic codes (route-ordered codewords; the planner fills the
   budget) at every budget: on Gardens Point mapped by day they beat every other method from 4 KB
   to 256 KB. Mapped at night they lose to LSH at every budget (weak spots, below).
3. **Ordered map, few effective bits** → the same periodic output codes when the map is *ordered* —
   its route continuity is at least :data:`ORDER_CONTINUITY` = 0.6 (rows a few places apart look more
   alike than most, though the nearest row need not be the next frame; below) — and the codes ``lsh``
   would store carry fewer than
   :data:`ORDER_BITS_FACTOR` (2) × :func:`collision_bits` = 2 × 2·log2 N *effective* bits per map row
   (:meth:`~btel.methods.baselines.lsh.LSHLocalizer.effective_bits`): its P bits, each counted whole
   when ``lsh`` centres and at :func:`~btel.methods.baselines.lsh.sign_bit_entropy` of the map's cone
   ratio when it cannot afford the mean (a hyperplane through the origin leaves most rows of a cone
   on one side: 0.68 bit per sign at cone ratio 0.75, 0.32 at 0.95). N random P-bit sign codes
   collide unless P ≳ 2·log2 N (the birthday bound), and just above it they barely separate the
   places a query must tell apart; every place has its own output codeword.

   History. The first form (after the first frontier run) was the bound itself on raw bits: the
   codes beat LSH on Nordland at 4 KB (recall@10 0.024 / 0.028 vs 0.008 / 0.005; 9 bits per place
   against 2·log2 N = 23.6) and on the synthetic route at 4 KB (R@2 0.089 vs 0.030; 16 bits against
   22), LSH won above it on the synthetic route (16 KB: 0.354 vs 0.257). The frontier then showed
   Nordland HOG at 16 KB (35 uncentred bits on a cone of ratio 0.75) with the codes ahead (0.038 /
   0.044 vs 0.015 / 0.016), and a second condition gave codes to any ordered cone (ratio ≥ 0.5) that
   could not afford LSH's mean, whatever its bits. ``python benchmarks/bench_cone_route.py`` then
   tested both on synthetic routes made into cones by a shared offset (cone ratio 0.24 … 0.95; an
   easy and a hard change of conditions; N = 2000 at d = 1024, and N = 600 and 210 — the sizes of
   the NetVLAD sets of the frontier issue — at Gardens Point's d = 500; three seeds, recall@2): the
   cone condition gave codes to the N = 210 maps at 4 KB, where LSH's 152 bits per row won (cone
   0.72 / 0.84: 0.440 / 0.392 vs 0.214 / 0.235 on the hard route), and the effective bits order the
   winner far better.
   Below 1.4 × the bound the codes won all 10 rows (cone 0.95 at 8 / 16 KB, N = 2000: 0.130 / 0.272
   vs 0.043 / 0.092; N = 600 at 4 KB: 0.300 vs 0.152), below 2 × 15 of 16 (easy route at 1.42 ×:
   LSH 0.188 vs 0.133); from 2 to 2.9 × LSH won 5 of 8, the codes the hard route's three
   (0.099 vs 0.054 at 2.85 ×); from 3.1 × on LSH won every row but the hard 1024-D route at 32 KB
   once LSH centres (5.4 ×: codes 0.098 … 0.105 vs 0.081 … 0.083). The factor 2 is the round value
   where the majority turns; the condition chose the better of the two in 37 of the 44 ordered
   rows, the two earlier conditions in 34 (36 with the codes' ridge at ρ = 0.1: on the hard N = 210
   cone of ratio 0.95 at 4 KB the codes rose from 0.240 to 0.281, past LSH's 0.249). On the
   development maps it changed no choice: Nordland 16 KB has 23.8 effective bits against 47.2,
   64 KB (centred) 126; the synthetic route 14.6 at 4 KB and 60.2 at 16 KB against 44. How hard the
   queries' change of conditions is cannot be read from the map, and the hard synthetic route in
   that band (and at 32 KB) stays a miss. Maps of independent places (continuity 0.50: Gardens
   Point permuted, synthetic independent places) keep LSH at any budget.

   Ordered by the continuity, not by the route share. The first form of this step called a map
   ordered when its route share reached 0.1 (consecutive places find each other far more often
   than the ≈ 4/N of independent places). The share reads only a row's nearest neighbour, and that
   is wrong both ways (``python benchmarks/bench_ordered_snippets.py``, two seeds):

   - a map of independent places in which pairs or triples of alike rows sit next to each other in
     the index reaches it (the frontier issue's NetVLAD sets of independent places have route shares
     of 0.14–0.40). The N = 600, d = 500 synthetic route in cones of ratio 0.84 and 0.95, cut into
     snippets of 2 and 3 in random order, has share 0.10–0.22 and continuity 0.49; at 4 KB the
     effective-bits condition gave it the codes, which lost all five such rows at recall@0 (LSH
     0.203 / 0.098 / 0.103 / 0.029 / 0.022 against 0.055 / 0.059 / 0.055 / 0.006 / 0.007);
   - a route whose frames are noisy seldom has the next frame as the nearest row: a synthetic route
     of N = 1500 at d = 48 has share 0.05–0.07 and continuity 0.94–0.95, and the codes beat LSH on
     it at 2 and 4 KB (recall@2 0.133 / 0.089 / 0.025 vs 0.064 / 0.022 / 0.004 at 2 KB).

   With the continuity the step chose the better of the two in 36 of the 40 snippet rows (31 with
   the share) and 8 of the 12 noisy-route rows (5). The misses: snippets of 10 (continuity 0.68,
   like Nordland) at 4 KB, where LSH led at recall@0 and the two split 2–2 at recall@2; the noisy
   route at 8 KB (one bound's worth of centred bits: LSH 0.608 / 0.243 against 0.249 / 0.161 on the
   mild and easy changes) and mild at 4 KB (0.204 vs 0.193). The threshold 0.6 sits between pairs
   and triples of alike rows (0.49–0.53, Gardens Point's snippets of 2 and 3 included; of 5
   0.53–0.55, of 10 0.62) and the sparsest real route of the development data (Nordland HOG, every
   10th frame: 0.68 / 0.69). Set after the snippet benchmark; no development choice changed.
4. **Otherwise (independent places, or many bits)** → if cosine brute force on shrinkage-whitened
   rows fits the budget (or there is no budget), that (exact search); else ``lsh`` (asymmetric
   scoring) with ``whiten="shrink"`` when the budget gives at least
   :data:`SHRINK_LSH_BYTES_PER_PLACE` (16) bytes per place and at least d bits per place, and
   affords a whitening of rank at least :data:`SHRINK_LSH_MIN_RANK` (8), plain ``lsh`` otherwise. Below 16 B the whitening's
   quarter of the budget costs more bits than it gives back (synthetic route at 7.8 B per place R@2
   0.354 plain vs 0.204 whitened; synthetic independent places at 16 B 0.605 vs 0.654). Below rank 8
   the transform is little more than the centring LSH already does (rank 8 is the smallest rank
   that gave brute force the whitening's gain when :mod:`btel.core.shrink`'s rule was set): on Nordland
   HOG at 64 KB (rank 2) whitened LSH scored 0.064 / 0.055 against plain 0.082 / 0.081; Gardens
   Point permuted at 4 KB (rank 0) went the other way, 0.135 against 0.105 (6 of 200 queries).
   The rank condition was added after the first frontier run, with the birthday bound of step 3.
   And only when the budget gives at least :data:`SHRINK_LSH_BITS_PER_DIMENSION` × d bits per map
   row (P ≥ d). Whitening flattens the spectrum: the rows' variance spreads over many more
   directions, while a P-bit sign sketch estimates angles with an error of about 1/√P whatever d,
   so with few bits against d the flattening costs LSH more than it gives (brute force, which has
   no sketch error, gains from it at every rank). ``python benchmarks/bench_lsh_whitening.py``
   measured it (three seeds) on a high-dimensional synthetic map made for the test (d = 2048, as a
   route and permuted): whitened − plain −0.00 … −0.01 / −0.07 … −0.08 / −0.18 … −0.20 /
   −0.03 … −0.04 at P/d = 0.06 / 0.12 / 0.25 / 0.5, +0.005 at P/d = 1. On the development maps the
   sign changes in the same place: −0.057 on Gardens Point at P/d = 0.32, +0.012 … +0.067 from
   P/d = 1.28 on; Nordland −0.004 … −0.074 at P/d = 0.04 … 0.15 and −0.001 / +0.029 at 0.59; the
   256-D synthetic maps −0.097 at 0.24, +0.002 at 0.5, +0.023 at 0.98. The crossover lies between
   P/d = 0.5 and 1; the rule takes the round, safe side (whitening passed over below d cost at most
   0.029 here; whitening below d/2 lost up to 0.20).
   Added when the 4-bit
   whitening basis doubled the rank a budget affords and whitened LSH on Nordland at 256 KB fell
   from 0.197 to 0.173 (plain 0.260); the high-dimensional synthetic map was made to test the
   mechanism, not fitted to a cell.

Known weak spots on the development data (``btel experiment frontier``, means of three seeds): on
Gardens Point mapped at night (the query traverse as the map, day queries; added to the frontier
after the rule was set) LSH beats the route's output codes at every budget (recall@2 0.530 / 0.622 /
0.655 vs 0.418 / 0.532 / 0.588 at 4 / 16 / 64 KB; 0.390 / 0.495 / 0.508 with the codes' earlier ridge
ρ = 0.03), while mapped by day the codes win by 0.04–0.16.
No statistic of the map tells the two apart for certain (route share 0.92 vs 0.975, cone ratio
0.37 vs 0.17: one pair is no rule); whitening turns the same way (brute force +0.09 by day, −0.135
at night), so the codes' learned projection, like the whitening, carries over from the richer
condition to the poorer one and not back. Tried for it and dropped (32 KB, three seeds): fusing
the codes' and LSH's z-scored place scores on a split budget lands between the parents (day
0.570 / 0.595 with ½ / ¾ of it to the codes, against the codes' 0.628 at ρ = 0.03; night 0.620 / 0.605
against LSH's 0.625), a hedge that misses the day target of 0.60; a larger ridge α for the codes trades
one direction for the other (ρ = 0.03 / 0.1 / 0.3 / 1: day 0.628 / 0.617 / 0.597 / 0.548, night
0.520 / 0.573 / 0.610 / 0.655; the codes now take ρ = 0.1, the largest that costs no development
cell more than 0.02, :mod:`btel.methods.codes.solvers`); training rows augmented with their route
neighbours moved either by at most 0.022. The synthetic routes argue the same way where the
route branch reaches them: the easy N = 210 route of ``benchmarks/bench_cone_route.py`` (route share
0.60) gave LSH 0.967 against the codes' 0.635 at 4 KB (152 bits per place) — a linear-Gaussian
model on which cosine is near-perfect, weaker evidence than a real route, but a second reason to try
``lsh`` beside auto on a route when the budget gives many bits per place. PQ at 1 MB beats LSH on Nordland HOG, and on Gardens Point the
periodic codes on whitened rows beat the plain ones at 4, 16 and 256 KB (0.598 vs 0.578 at 16 KB)
but not at 64 KB nor on the synthetic route. The rule was not changed to fit those rows. A holdout
on the map itself (even rows as the map, odd rows as queries, the candidate with the best holdout recall) was tried as a chooser instead and dropped: it
picked a candidate within 0.95 of the best of three (periodic codes, LSH, whitened LSH) in 10–11 of
22 development cells, this rule in 18; the holdout has no change of conditions between map and
queries, so it never picked the output codes on Gardens Point, where they win.

The figures above were measured when ``lsh`` drew i.i.d. Gaussian hyperplanes; it then drew
orthonormal blocks and now sign-flip + Walsh–Hadamard blocks (:mod:`btel.methods.baselines.lsh`,
docs/decisions/lsh-projection.md), and ``btel experiment frontier`` has the current figures.

A choice that does not fit the budget falls back to the next candidate (``lsh``, then
``btel-codes``); what was chosen, why, and the statistics are recorded in the model file
(``choice_``), in :meth:`AutoLocalizer.summary` and in ``btel train``'s output.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...core.storage import format_bytes
from .statistics import ORDER_CONTINUITY, collision_bits, index_order, map_cone_ratio

__all__ = ["ORDER_BITS_FACTOR", "SHRINK_LSH_BITS_PER_DIMENSION", "SHRINK_LSH_BYTES_PER_PLACE", "SHRINK_LSH_MIN_RANK",
           "choose_method"]

#: Independent places: from this many bytes per place on, LSH runs on shrinkage-whitened rows.
SHRINK_LSH_BYTES_PER_PLACE = 16
#: LSH runs on shrinkage-whitened rows only when the budget affords at least this rank (fewer
#: directions is little more than the centring LSH does anyway, for 2d bytes of mean).
SHRINK_LSH_MIN_RANK = 8
#: LSH runs on shrinkage-whitened rows only when the budget gives at least this many bits per map row
#: per dimension (P ≥ d): below, the whitening's flatter spectrum costs the sign sketch more than it gives.
SHRINK_LSH_BITS_PER_DIMENSION = 1.0
#: An ordered map gets output codes while LSH's effective bits per map row
#: (:meth:`~btel.methods.baselines.lsh.LSHLocalizer.effective_bits`) are below this × :func:`collision_bits`.
ORDER_BITS_FACTOR = 2.0


def choose_method(X: np.ndarray, places: np.ndarray | None, n_places: int, budget: int | None,
                  whiten: Any = None) -> list[dict[str, Any]]:
    """The candidates, best first, that the rule gives for this map and budget (module docstring).

    Each is ``{"method", "params", "reason", "route_share", "bytes_per_place"}``; :class:`AutoLocalizer`
    fits the first that fits the budget.
    """
    from ...core.frontend import FrontEnd
    from ...core.shrink import shrink_rank
    from ..baselines import BruteForceNN
    from ..baselines.lsh import LSHLocalizer

    order = index_order(X, places)
    share, continuity, where = order.share, order.continuity, order.why
    n_rows, d = X.shape
    per_place = None if budget is None else budget / n_rows
    stats = {"route_share": round(share, 4), "bytes_per_place": None if per_place is None else round(per_place, 2),
             "n_places": int(n_places), "n_rows": int(n_rows), "n_features": int(d)}
    stats["route_continuity"] = round(continuity, 4)
    white = (lambda default: default) if whiten is None else (lambda default: whiten)
    bpp = "no budget" if per_place is None else f"{per_place:.1f} B per map row"
    lsh = {"method": "lsh", "params": {"whiten": white(None)}, "reason": f"fallback: plain LSH ({bpp})"}
    codes = {"method": "btel-codes", "params": {"code": "periodic", "whiten": white(None)},
             "reason": f"fallback: periodic output codes ({bpp})"}
    out: list[dict[str, Any]] = []
    few = collision_bits(n_rows)
    filling = "periodic output codes filling the budget"
    why = None
    if order.kind == "route":
        why = f"route ({where}), {bpp}: {filling}"
    elif order.kind == "ordered" and budget is not None:
        cone = map_cone_ratio(X)
        effective = LSHLocalizer().effective_bits(n_rows, d, budget, cone)
        stats.update({"cone_ratio": round(cone, 4), "lsh_effective_bits": round(effective, 1)})
        if effective < ORDER_BITS_FACTOR * few:
            why = (f"ordered map ({where}) where LSH's codes would carry ≈ {effective:.1f} effective bits per map row "
                   f"({8 * per_place:.0f} bits of budget, cone ratio {cone:.2f}) < {ORDER_BITS_FACTOR:g} × "
                   f"2·log2 N = {ORDER_BITS_FACTOR * few:.1f}: sign codes that weak collide or barely separate "
                   f"places, so {filling}")
    if why is not None:  # output codes, plain LSH as the fallback
        return [{**c, **stats} for c in ({**codes, "reason": why}, lsh)]
    kind = "independent places" if order.kind == "independent" else "ordered map with bits to spare for LSH"
    front = FrontEnd(normalize="l2", whiten=white("shrink"), budget=budget)
    exact = BruteForceNN.planned_bytes(n_rows, front.n_features_out(d)) + front.planned_bytes(n_rows, d)
    if budget is None or exact <= budget:
        out.append({"method": "bruteforce", "params": {"whiten": white("shrink")},
                    "reason": f"{kind} ({where}); brute force on shrinkage-whitened rows fits "
                              f"({format_bytes(exact)})"})
    rank = shrink_rank(d, n_rows, budget)
    bits = None if per_place is None else 8 * per_place
    if (bits is None or (per_place >= SHRINK_LSH_BYTES_PER_PLACE and bits >= SHRINK_LSH_BITS_PER_DIMENSION * d)) \
            and rank >= SHRINK_LSH_MIN_RANK:
        out.append({"method": "lsh", "params": {"whiten": white("shrink")},
                    "reason": f"{kind} ({where}), {bpp} ≥ {SHRINK_LSH_BYTES_PER_PLACE} and "
                              f"{'no budget' if bits is None else f'{bits:.0f} bits per row ≥ d = {d}'}: asymmetric "
                              f"LSH on shrinkage-whitened rows (rank {rank})"})
    out.append({**lsh, "reason": f"{kind} ({where}), {bpp}: asymmetric LSH"})
    out.append(codes)
    return [{**c, **stats} for c in out]

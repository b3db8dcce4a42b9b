"""The registered methods that play a fixed role: the default, the unbudgeted reference, the demo set.

Plain names and no imports, so that the command line shows them in its help (``[default: …]``)
without loading the methods and scikit-learn. :mod:`btel.methods.registry` re-exports them; the
tests check that each is a registered method.
"""

from __future__ import annotations

__all__ = ["DEFAULT_METHOD", "REFERENCE_METHOD", "WHITENED_REFERENCE", "DEMO_METHODS"]

#: The method fitted when none is named (``btel train``, ``btel evaluate``): it chooses from the map and budget.
DEFAULT_METHOD = "auto"

#: The unbudgeted reference of a comparison: exact nearest neighbour over every map descriptor.
REFERENCE_METHOD = "bruteforce"

#: The second reference row: the same exact search on shrinkage-whitened rows (label, parameters). It is
#: the stronger unbudgeted row on most maps (``btel experiment frontier``: Gardens Point day → night
#: recall@2 0.565 vs cosine 0.480, Nordland HOG summer → winter recall@10 0.465 vs 0.381) but not on
#: all (Gardens Point night → day 0.530 vs 0.665), so both references are shown.
WHITENED_REFERENCE: tuple[str, dict[str, str]] = ("bruteforce shrink", {"whiten": "shrink"})

#: The methods ``btel demo`` compares when none are named (the default, the paper's, output codes, PQ, the reference).
DEMO_METHODS: tuple[str, ...] = ("auto", "btel-c", "btel-r", "btel-codes", "pq", "bruteforce")

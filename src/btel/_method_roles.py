"""The registered methods that play a fixed role: the default, the unbudgeted reference, the demo set.

Plain names and no imports, so that the command line shows them in its help (``[default: …]``)
without loading the methods and scikit-learn. :mod:`btel.methods.registry` re-exports them; the
tests check that each is a registered method.
"""

from __future__ import annotations

__all__ = ["DEFAULT_METHOD", "REFERENCE_METHOD", "DEMO_METHODS"]

#: The method fitted when none is named (``btel train``, ``btel evaluate``): it chooses from the map and budget.
DEFAULT_METHOD = "auto"

#: The unbudgeted reference of a comparison: exact nearest neighbour over every map descriptor.
REFERENCE_METHOD = "bruteforce"

#: The methods ``btel demo`` compares when none are named (the paper's, output codes, PQ, the reference).
DEMO_METHODS: tuple[str, ...] = ("btel-c", "btel-r", "btel-codes", "pq", "bruteforce")

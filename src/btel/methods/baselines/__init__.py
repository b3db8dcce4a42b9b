"""The baselines BTEL is compared with, each a :class:`btel.methods.base.PlaceLocalizer`.

Every baseline takes ``budget`` (bytes or ``"500KB"``), counts its storage by the one storage rule
(docs/guide/concepts.md) and ranks candidate places (``rank(Q, k)``). RYTH lives in :mod:`btel.methods.ryth`.

========== ============================ ==========================================================
name       class                        storage
========== ============================ ==========================================================
bruteforce :class:`BruteForceNN`        N×d float32; exact cosine (L2 with normalize='none')
pq         :class:`PQLocalizer`         codes + codebooks (+ d×p PCA); most code bits that fit
opq        :class:`OPQLocalizer`        codes + codebooks + d×p rotation
itq        :class:`ITQLocalizer`        binary codes + d×b projection + mean; Hamming distance
lsh        :class:`LSHLocalizer`        N×P sign bits (+ d float16 mean); projection from its seed, 0 B
rabitq     :class:`RaBitQLocalizer`     N×(D·B bits + factors) + D centroid; rotation from its seed, 0 B
seqslam    :class:`SeqSLAM`             N×d uint8; sequences of ds = 10 frames
========== ============================ ==========================================================
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

from ..._lazy import lazy_names

if TYPE_CHECKING:  # pragma: no cover - imported on first use (btel._lazy)
    from ..base import PlaceLocalizer
    from ._common import quiet_faiss
    from .bruteforce import BruteForceNN
    from .itq import ITQLocalizer
    from .lsh import LSHLocalizer
    from .opq import OPQLocalizer
    from .pq import PQConfig, PQLocalizer
    from .rabitq import RaBitQLocalizer
    from .seqslam import SeqSLAM, enhance_contrast, seqslam_match, sequence_costs

__all__ = [
    "BASELINES",
    "BruteForceNN",
    "PQLocalizer",
    "PQConfig",
    "OPQLocalizer",
    "ITQLocalizer",
    "LSHLocalizer",
    "RaBitQLocalizer",
    "SeqSLAM",
    "seqslam_match",
    "enhance_contrast",
    "sequence_costs",
    "quiet_faiss",
]

#: Baseline name → the class and its module; ``BASELINES`` (name → class, merged into
#: :data:`btel.methods.METHODS`) imports them all on first access.
_BASELINE_CLASSES = {"bruteforce": ("BruteForceNN", ".bruteforce"), "pq": ("PQLocalizer", ".pq"),
                     "opq": ("OPQLocalizer", ".opq"), "itq": ("ITQLocalizer", ".itq"),
                     "lsh": ("LSHLocalizer", ".lsh"), "seqslam": ("SeqSLAM", ".seqslam")}


def _baselines() -> dict[str, type[PlaceLocalizer]]:
    return {name: getattr(sys.modules[__name__], cls) for name, (cls, _) in _BASELINE_CLASSES.items()}


__getattr__, __dir__ = lazy_names(__name__, {
    **{cls: module for cls, module in _BASELINE_CLASSES.values()}, "quiet_faiss": "._common",
    "PQConfig": ".pq", "RaBitQLocalizer": ".rabitq",
    **dict.fromkeys(("enhance_contrast", "seqslam_match", "sequence_costs"), ".seqslam")},
    computed={"BASELINES": _baselines})

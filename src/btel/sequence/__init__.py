"""Places over time: the paper's sequence filter, HMM decoding over any method's scores, one query at a time
(:class:`~btel.sequence.querystream.QueryStream`) and line streams (``btel localize --stream``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_names

__all__ = ["SequenceFilter", "filter_sequence"]

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from .filter import SequenceFilter, filter_sequence

__getattr__, __dir__ = lazy_names(__name__, {"SequenceFilter": ".filter", "filter_sequence": ".filter"})

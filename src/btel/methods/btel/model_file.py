"""BTEL's model file: the arrays a fitted model stores, its header state, and their checks on load.

Stored: every tree classifier (weights, biases, column indices unless d' = d), and with r ≥ 2
regions the region classifier and the region starts (in blocks). The header state holds d', r
and the count of unconverged classifiers; everything else (the number of blocks, bits, tree
sizes and offsets) is derived from N, the parameters and the region starts, and checked against
the arrays' shapes before any array is used (:class:`~btel.exceptions.ModelFileError` otherwise).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...core.validation import read_state_int
from ..base import ArraySpec
from ...exceptions import InvalidParameterError, ModelFileError
from ...learning.hyperplanes import Hyperplanes
from .planning import array_specs, starts_dtype

__all__ = ["TreeModelFile", "MAX_REGIONS_IN_FILE"]

#: Most regions a model file may declare (its region list is built before the arrays are checked).
MAX_REGIONS_IN_FILE = 1 << 16


class TreeModelFile:
    """Saving and loading a BTEL model (mixed into :class:`~btel.methods.btel.localizer.BTELocalizer`).

    The base class (:class:`btel.methods.base.PlaceLocalizer`) writes and reads the file; these are the
    method's parts of it. ``_restore`` rebuilds the structure through the estimator's
    ``_set_structure``, as ``fit`` does.
    """

    def _stored_arrays(self) -> dict[str, np.ndarray]:
        arrays = self.hyperplanes_.arrays("")
        if self.region_hyperplanes_ is not None:
            arrays.update(self.region_hyperplanes_.arrays("region_"))
            arrays["region_starts"] = self.region_starts_.astype(starts_dtype(self.n_blocks_))
        return arrays

    #: The state key holding what the fit chose for a parameter of another name (``chosen_at_fit``).
    _STATE_OF_PARAM = {"n_features": "n_selected"}

    def _fitted_state(self) -> dict[str, Any]:
        return {"n_selected": self.n_selected_, "n_regions": self.n_regions_, "n_unconverged": self.n_unconverged_}

    def _array_specs(self, state: dict[str, Any]) -> dict[str, ArraySpec]:
        n_places = int(state["n_places"])
        d = self.front_end_.n_features_out(int(state["n_features_in"]))
        n_blocks = -(-n_places // int(self.block_size))
        if n_blocks < 2:
            raise ModelFileError(f"the model file's N = {n_places} and block_size = {self.block_size} leave "
                                 f"{n_blocks} block; an index needs at least 2.")
        n_selected = read_state_int(state, "n_selected", 1, d)
        r = read_state_int(state, "n_regions", 1, min(n_blocks, MAX_REGIONS_IN_FILE))
        self._check_combinations_from_file()
        # The region sizes are read from region_starts; the specs need only their count and total,
        # except for the number of tree classifiers, checked in _restore once the starts are known.
        specs = array_specs([n_blocks] if r == 1 else [1] * (r - 1) + [n_blocks - r + 1], n_selected, d,
                            scheme=self.scheme, dtype=np.dtype(self.dtype).name, code_copies=int(self.code_copies))
        for name in ("weights", "bias", "columns"):
            if name in specs:
                specs[name].shape = (None,) + specs[name].shape[1:]
        return specs

    def _check_combinations_from_file(self) -> None:
        try:
            self._check_combinations()
        except InvalidParameterError as exc:
            raise ModelFileError(f"the model file's parameters contradict each other: {exc}") from exc

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        n_places = int(state["n_places"])
        d = self.front_end_.n_features_out(int(state["n_features_in"]))
        n_selected = int(state["n_selected"])
        n_blocks = -(-n_places // int(self.block_size))
        starts = arrays.get("region_starts", np.zeros(1, dtype=np.int64)).astype(np.int64)
        if starts[0] != 0 or np.any(np.diff(starts) < 1) or starts[-1] >= n_blocks:
            raise ModelFileError("the model file's region starts are not increasing within the route's codes.")
        self._set_structure(n_places, n_selected, starts)
        if arrays["weights"].shape[0] != self.tree_offsets_[-1]:
            raise ModelFileError(
                f"model file holds {arrays['weights'].shape[0]} classifiers; its regions imply {self.tree_offsets_[-1]}."
            )
        k = int(self.tree_offsets_[-1])
        if arrays["bias"].shape[0] != k or ("columns" in arrays and arrays["columns"].shape[0] != k):
            raise ModelFileError(f"the model file's bias or columns do not hold one row per classifier ({k}).")
        self.hyperplanes_ = Hyperplanes.from_arrays(arrays, "", d)
        self.region_hyperplanes_ = Hyperplanes.from_arrays(arrays, "region_", d) if self.n_regions_ >= 2 else None
        self.n_unconverged_ = read_state_int(state, "n_unconverged", 0, int(self.tree_offsets_[-1]) + self.n_regions_)

"""The output codes' model file: the arrays a fitted model stores, its header state, and their checks on load.

Stored: the K × d' quantised weights with their per-column scales (:mod:`btel.methods.codes.quantise`),
the K biases and the d' kept columns (none when every column is kept). The codewords are not
stored: the header state records the family, K, the seed and the generation rule (``code_rule``;
files without one get the per-bit rule they were written with), and the codebook is regenerated
from them on load (:class:`~btel.methods.codes.codebook.Codebook`). Every state value and array is
checked before use (:class:`~btel.exceptions.ModelFileError` otherwise).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...core.validation import read_state_int
from ..base import ArraySpec
from ...exceptions import InvalidParameterError, ModelFileError
from ...learning.hyperplanes import MAX_WEIGHT_NORM, weights_out_of_range
from .codebook import FAMILIES, MAX_COLUMNS, ROUTE_FAMILIES, Codebook
from .hashing import LEGACY_RULE, RULES
from .planning import CodePlan, code_array_specs
from .quantise import WEIGHT_BITS, QuantisedWeights

__all__ = ["CodeModelFile"]


def _code_rule(state: dict[str, Any]) -> int:
    """The codebook's generation rule recorded in the header state (:mod:`~btel.methods.codes.hashing`).

    A file without one was written before rules were recorded: its random codewords come from the
    per-bit rule (:data:`~btel.methods.codes.hashing.LEGACY_RULE`), so it predicts as it did.
    """
    if "code_rule" not in state:
        return LEGACY_RULE
    rule = state["code_rule"]
    if isinstance(rule, bool) or not isinstance(rule, int) or rule not in RULES:
        raise ModelFileError(f"the model file's code_rule = {repr(rule)[:40]} is not one of {RULES}; the file is "
                             "damaged or from a newer btel. Upgrade btel, or refit and save it again.")
    return rule


class CodeModelFile:
    """Saving and loading a :class:`~btel.methods.codes.estimator.CodeLocalizer` (mixed into it).

    The base class (:class:`btel.methods.base.PlaceLocalizer`) writes and reads the file; these are the
    method's parts of it. ``_restore`` ends in the estimator's ``_set_structure``, as ``fit`` does.
    """

    def _stored_arrays(self) -> dict[str, np.ndarray]:
        arrays = {**self.weights_.arrays(), "bias": self.bias_}
        if self.columns_ is not None:
            arrays["columns"] = self.columns_
        return arrays

    #: The state key holding what the fit chose for a parameter of another name (``chosen_at_fit``).
    _STATE_OF_PARAM = {"n_features": "n_selected"}

    def _fitted_state(self) -> dict[str, Any]:
        return {"n_codes": self.n_codes_, "n_selected": self.n_selected_, "weight_bits": self.weight_bits_,
                "code": self.code_, "code_reason": self.code_reason_, "code_seed": self.code_seed_,
                "code_rule": int(self.codebook_.rule), "alpha": self.alpha_, "n_unconverged": self.n_unconverged_,
                "plan_rule": self.plan_.rule, "plan_budget": self.plan_.budget}

    def _array_specs(self, state: dict[str, Any]) -> dict[str, ArraySpec]:
        d = self.front_end_.n_features_out(int(state["n_features_in"]))
        K = read_state_int(state, "n_codes", 1, MAX_COLUMNS)
        d_sel = read_state_int(state, "n_selected", 1, d)
        bits = read_state_int(state, "weight_bits", 4, 32)
        if bits not in WEIGHT_BITS:
            raise ModelFileError(f"the model file's weight width {bits} is not one of {WEIGHT_BITS}.")
        return code_array_specs(K, d_sel, d, bits)

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        try:
            self._check_combinations()
        except InvalidParameterError as exc:
            raise ModelFileError(f"the model file's parameters contradict each other: {exc}") from exc
        d = self.front_end_.n_features_out(int(state["n_features_in"]))
        K, d_sel = int(state["n_codes"]), int(state["n_selected"])
        seed = read_state_int(state, "code_seed", 0, 2**32 - 1)
        family = state.get("code", self.code)  # files written before code='auto' record only the parameter
        if family not in FAMILIES or (self.code != "auto" and family != self.code):
            raise ModelFileError(f"the model file's code family {family!r} is not one of {FAMILIES}"
                                 + ("" if self.code == "auto" else f" or contradicts its parameter code={self.code!r}")
                                 + "; the file is damaged or from another version. Refit and save it again.")
        if self.decode == "coarse" and family not in ROUTE_FAMILIES:
            raise ModelFileError(f"the model file asks for decode='coarse' with {family} codes, which have no "
                                 "route order; the file is damaged. Refit and save it again.")
        reason = state.get("code_reason")
        self.code_, self.code_reason_ = family, reason if isinstance(reason, str) else "given"
        codebook = Codebook(family, int(state["n_places"]), K, seed, _code_rule(state))  # bad values → ModelFileError
        columns = arrays.get("columns")
        if columns is not None and (int(columns.max()) >= d or np.any(np.diff(columns.astype(np.int64)) <= 0)):
            raise ModelFileError("the model file's kept columns are not increasing indices below d.")
        bias = arrays["bias"]
        if not np.isfinite(bias).all():
            raise ModelFileError("the model file's biases contain NaN or infinite values.")
        self.weights_ = QuantisedWeights.from_arrays(arrays, int(state["weight_bits"]), d_sel)
        problem = weights_out_of_range(self.weights_.dequantise(), bias)
        if problem is not None:
            raise ModelFileError(f"the model file's weights or biases hold {problem}; no fit stores "
                                 f"weights beyond {MAX_WEIGHT_NORM:.0e}: the file is damaged or was edited. "
                                 "Refit and save it again.")
        self.bias_ = bias
        self.columns_ = columns
        alpha = state.get("alpha")
        self.alpha_ = float(alpha) if isinstance(alpha, (int, float)) and not isinstance(alpha, bool) else None
        self.n_unconverged_ = read_state_int(state, "n_unconverged", 0, K)
        rule, room = state.get("plan_rule"), state.get("plan_budget")
        self.plan_ = CodePlan(K, d_sel, int(state["weight_bits"]),
                              int(sum(spec.nbytes for spec in self._array_specs(state).values())),
                              room if isinstance(room, int) and not isinstance(room, bool) else None,
                              rule if isinstance(rule, str) else "recorded without a rule")
        self._set_structure(codebook)

"""Packages whose public names are imported on first use (PEP 562 module ``__getattr__``).

A package's ``__init__`` maps each public name to the submodule that defines it and takes its
``__getattr__`` and ``__dir__`` from :func:`lazy_names`; the same imports stand under
``if TYPE_CHECKING:`` for type checkers, IDEs and the import-graph test. Importing a package then
costs nothing, and loading a model and answering queries imports only the modules its method
reads: nothing that fitting alone needs (scikit-learn, ruptures, joblib).
"""

from __future__ import annotations

import importlib
import sys
from typing import Any, Callable, Mapping

__all__ = ["lazy_names"]


def lazy_names(package: str, names: Mapping[str, str],
               computed: Mapping[str, Callable[[], Any]] | None = None) -> tuple[Callable[[str], Any],
                                                                                Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for ``package`` whose public names load on first access.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    names : mapping of str to str
        Public name → the submodule that defines it, relative to the package (``".localizer"``).
    computed : mapping of str to callable, optional
        Public name → a function building its value (a table of several submodules' classes).

    Returns
    -------
    __getattr__, __dir__
        To assign in the package. A value is cached in the package once built; an unknown name
        raises ``AttributeError``.
    """
    computed = dict(computed or {})

    def __getattr__(name: str) -> Any:
        if name in names:
            value = getattr(importlib.import_module(names[name], package), name)
        elif name in computed:
            value = computed[name]()
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(names) | set(computed))

    return __getattr__, __dir__

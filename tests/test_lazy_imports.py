"""Start-up: ``import btel`` and ``btel --help`` import no scikit-learn, and loading a model and answering
(``btel.load`` + ``predict``, ``btel localize``) imports nothing that only fitting needs.

Timings: ``benchmarks/bench_import.py`` and ``benchmarks/bench_first_answer.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import btel

SRC = str(Path(btel.__file__).resolve().parents[1])


def modules_after(code: str) -> set[str]:
    env = {**os.environ, "PYTHONPATH": SRC}
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys; print('\\n'.join(sys.modules))"], env=env,
                         check=True, capture_output=True, text=True).stdout
    return set(out.split())


def test_import_btel_does_not_import_sklearn() -> None:
    loaded = modules_after("import btel")
    assert "btel" in loaded
    assert not {m for m in loaded if m.split(".")[0] in ("sklearn", "scipy")}


def test_btel_help_does_not_import_sklearn() -> None:
    code = ("import sys; sys.argv = ['btel', '--help']\nfrom btel.cli import main\n"
            "try:\n    main()\nexcept SystemExit:\n    pass")
    loaded = modules_after(code)
    assert "btel.cli" in loaded and "click" in loaded
    assert not {m for m in loaded if m.split(".")[0] in ("sklearn", "scipy")}


def test_public_names_are_unchanged_and_listed() -> None:
    names = {"BTELocalizer", "CodeLocalizer", "PlaceLocalizer", "SequenceFilter", "filter_sequence", "load",
             "make_method", "parse_budget", "__version__"}
    assert set(btel.__all__) == names
    assert names <= set(dir(btel))
    from btel.methods.btel.localizer import BTELocalizer

    assert btel.BTELocalizer is BTELocalizer
    from btel import load, make_method  # noqa: F401  (from-imports resolve through __getattr__)


def test_subpackages_are_attributes_after_import_btel_and_cost_nothing_before() -> None:
    """``import btel; btel.datasets.synthetic_route(...)`` works, as a newcomer writes it; importing btel
    alone still imports no subpackage."""
    loaded = modules_after("import btel")
    assert not {m for m in loaded if m.split(".")[:2] == ["btel", "datasets"]}
    loaded = modules_after("import btel\nprint(btel.datasets.synthetic_route(20, 4, seed=0).map.shape)")
    assert "btel.datasets" in loaded and not {m for m in loaded if m.split(".")[0] in ("sklearn", "scipy")}
    assert {"datasets", "descriptors", "evaluation", "experiments", "methods", "sequence"} <= set(dir(btel))


def test_an_unknown_name_is_an_attribute_error() -> None:
    try:
        btel.NoSuchThing  # noqa: B018
    except AttributeError as exc:
        assert "NoSuchThing" in str(exc)
    else:  # pragma: no cover
        raise AssertionError("btel.NoSuchThing did not raise AttributeError")


def test_python_m_btel_cli_runs() -> None:
    env = {**os.environ, "PYTHONPATH": SRC}
    out = subprocess.run([sys.executable, "-m", "btel.cli", "--version"], env=env, capture_output=True, text=True)
    assert out.returncode == 0 and "btel" in out.stdout


def test_btel_help_does_not_import_numpy() -> None:
    code = ("import sys; sys.argv = ['btel', '--help']\nfrom btel.cli import main\n"
            "try:\n    main()\nexcept SystemExit:\n    pass")
    assert "numpy" not in modules_after(code)


# -- loading a model and answering imports nothing that only fitting needs ------------------------------

#: Packages only fitting needs (classifiers, PCA, KTS, parallel fits, progress bars, plots, images).
FIT_ONLY = ("sklearn", "ruptures", "scipy", "joblib", "dask", "distributed", "tqdm", "matplotlib", "cv2",
            "skimage", "h5py")
#: What a method's inference itself reads, by method: BTE-F ranks candidates with sparse path matrices.
INFERENCE_NEEDS = {"btel-f": {"scipy"}}

#: One interpreter loads and answers with every model in turn and reports, per model, the packages it added.
_LOAD_AND_ANSWER = """
import json, sys
import numpy as np
import btel
Q = np.load(sys.argv[1])
report = {}
for path in sys.argv[2:]:
    before = {m.split(".")[0] for m in sys.modules}
    model = btel.load(path)
    model.predict(Q)
    model.predict(Q[:1])
    model.search(Q, 3)
    report[path] = sorted({m.split(".")[0] for m in sys.modules} - before)
print(json.dumps(report))
"""


def _fit_only_imports(models: dict[str, Path], Q: np.ndarray, tmp_path: Path) -> dict[str, list[str]]:
    """Method name → the fit-only packages its model's loading and answering imported (a new interpreter)."""
    np.save(tmp_path / "q.npy", Q)
    env = {**os.environ, "PYTHONPATH": SRC}
    argv = [sys.executable, "-c", _LOAD_AND_ANSWER, str(tmp_path / "q.npy"), *map(str, models.values())]
    out = subprocess.run(argv, env=env, check=True, capture_output=True, text=True).stdout
    added = json.loads(out.splitlines()[-1])
    return {name: sorted(set(added[str(path)]) & (set(FIT_ONLY) - INFERENCE_NEEDS.get(name, set())))
            for name, path in models.items()}


def test_load_and_answer_imports_nothing_fit_only(tmp_path: Path) -> None:
    from btel.datasets import synthetic_route
    from btel.methods import make_method, method_names

    route = synthetic_route(120, 32, seed=0)
    models = {}
    for name in method_names():
        model = make_method(name)
        quiet = {k: v for k, v in {"progress": False, "n_jobs": 1}.items() if k in model.get_params()}
        models[name] = model.set_params(**quiet).fit(route.map).save(tmp_path / f"{name}.npz")
    found = _fit_only_imports(models, route.queries[:5], tmp_path)
    assert found == {name: [] for name in models}, {n: f for n, f in found.items() if f}


@pytest.mark.realdata
def test_load_and_answer_on_real_descriptors(gardenspoint_netvlad, tmp_path: Path) -> None:
    from btel.methods import make_method

    X_map, X_query = gardenspoint_netvlad
    models = {name: make_method(name, budget="8KB").fit(X_map).save(tmp_path / f"{name}.npz")
              for name in ("lsh", "btel-codes", "pq")}
    assert _fit_only_imports(models, X_query[:20], tmp_path) == {name: [] for name in models}


def test_the_check_sees_a_fit_only_import(tmp_path: Path) -> None:
    """The subprocess report catches a load that imports a fit-only package (joblib, imported on purpose)."""
    env = {**os.environ, "PYTHONPATH": SRC}
    code = _LOAD_AND_ANSWER.replace("model = btel.load(path)", "import joblib; model = btel.load(path)")
    from btel.datasets import synthetic_route
    from btel.methods import make_method

    route = synthetic_route(50, 8, seed=0)
    path = make_method("bruteforce").fit(route.map).save(tmp_path / "m.npz")
    np.save(tmp_path / "q.npy", route.queries[:2])
    argv = [sys.executable, "-c", code, str(tmp_path / "q.npy"), str(path)]
    out = subprocess.run(argv, env=env, check=True, capture_output=True, text=True).stdout
    assert "joblib" in json.loads(out.splitlines()[-1])[str(path)]


def test_btel_localize_imports_nothing_fit_only(tmp_path: Path) -> None:
    """The command a robot runs: ``btel localize MODEL q.npy -o out.csv`` (batch) in a fresh interpreter."""
    from btel.datasets import synthetic_route
    from btel.methods import make_method

    route = synthetic_route(200, 16, seed=0)
    path = make_method("btel-codes", budget="2KB").fit(route.map).save(tmp_path / "m.npz")
    np.save(tmp_path / "q.npy", route.queries[:10])
    argv = ["btel", "localize", str(path), str(tmp_path / "q.npy"), "-o", str(tmp_path / "out.csv")]
    code = (f"import sys; sys.argv = {argv!r}\nfrom btel.cli import main\n"
            "try:\n    main()\nexcept SystemExit:\n    pass")
    loaded = {m.split(".")[0] for m in modules_after(code)}
    assert (tmp_path / "out.csv").read_text().count("\n") == 11
    assert not loaded & set(FIT_ONLY), sorted(loaded & set(FIT_ONLY))


def test_the_registry_imports_a_method_only_when_asked_for() -> None:
    loaded = modules_after("from btel.methods import make_method, method_names\nmake_method('lsh')\n"
                           "assert 'btel-codes' in method_names()")
    assert "btel.methods.baselines.lsh" in loaded
    assert not {"btel.methods.btel.localizer", "btel.methods.codes.estimator", "btel.methods.ryth",
                "btel.methods.baselines.pq"} & loaded
    from btel.methods import MODEL_CLASSES, REGISTRY, registry

    for name, (factory, _) in REGISTRY.items():  # the table's module and class are the class's own
        entry = registry._ENTRIES[name]
        cls = getattr(factory, "func", factory)
        assert (cls.__module__, cls.__name__) == ("btel.methods" + entry.module, entry.cls)
        assert MODEL_CLASSES[entry.cls] is cls

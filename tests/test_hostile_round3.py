"""Hostile inputs, round 3: regexes that backtracked quadratically, the ``PATH.json`` record beside a
descriptor ``.npy`` read without a type or size check, and a progressive JPEG scan bomb.

Each case ends with one error naming the file (or line) and the fix, in bounded time: the slow cases
run in a subprocess with a generous ``timeout`` (CI machines are slow), asserting the outcome rather
than a duration. The rewritten regexes are compared with the old ones on every short string.
"""

from __future__ import annotations

import importlib.util
import itertools
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from btel.cli import main
from btel.descriptors import npy_header
from btel.descriptors.extract import extract_cached, extraction_difference, is_extraction_of
from btel.descriptors.hog import HOGDescriptor
from btel.descriptors.images import MAX_JPEG_SCANS, read_image
from btel.datasets.row_names import row_images, row_names
from btel.exceptions import DataNotFoundError, InvalidDescriptorsError
from btel.experiments import report
from btel.methods import make_method
from btel.sequence import lineparse

FAMILIES_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "fuzz_families.py"

#: The regexes as they were before round 3 (quadratic on a long run of digits, or of unclosed markers).
OLD_DECIMAL = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z", re.ASCII)
OLD_NUMBER = re.compile(r"\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*|\s*[-+]?(nan|inf)\s*", re.IGNORECASE)
OLD_MARKER = re.compile(r"<!-- (?P<name>[\w-]+):start -->.*?<!-- (?P=name):end -->", re.S)

#: Generous bound for a run that takes well under a second once linear (minutes when quadratic).
TIMEOUT = 60


def _strings(alphabet: str, longest: int):
    for n in range(longest + 1):
        for chars in itertools.product(alphabet, repeat=n):
            yield "".join(chars)


SRC = str(Path(__file__).resolve().parents[1] / "src")


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "btel.cli", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=TIMEOUT, env=_env())


# --- 1. the strict line parser -------------------------------------------------------------------

def test_decimal_regex_accepts_the_same_strings_as_before() -> None:
    """Every string of up to 6 characters over the characters a number is made of (and one that is not)."""
    for text in _strings("01.eE+-x", 6):
        assert bool(lineparse._DECIMAL.match(text)) == bool(OLD_DECIMAL.match(text)), text


def test_a_1mib_run_of_digits_is_one_not_a_number_error(tmp_path: Path) -> None:
    """'1' * 1 MiB + 'x' hung the stream for hours (quadratic backtracking in _DECIMAL)."""
    make_method("lsh", budget="2KB").fit(np.random.default_rng(0).standard_normal((50, 16))).save(tmp_path / "m.btel.npz")
    line = "1" * ((1 << 20) - 1) + "x"
    # Line 1: the count is wrong (the hint names the bad token); line 2: 16 tokens, each checked by parse_strict.
    (tmp_path / "in.txt").write_text(line + "\n" + " ".join(["1" * 60_000 + "x"] * 16) + "\n")
    done = _run(["localize", "m.btel.npz", "--stream", "--input", "in.txt"], tmp_path)
    assert done.stdout == ""
    assert done.stderr.count("is not a number") == 2, done.stderr[:500]
    assert "line 1:" in done.stderr and "line 2:" in done.stderr and "Traceback" not in done.stderr
    with pytest.raises(InvalidDescriptorsError, match="is not a number"):  # parse_strict's own check
        lineparse.parse_strict(" ".join(["1" * 100_000 + "x"] * 16), 16)


# --- 2. the text-matrix check of a descriptor file -----------------------------------------------

def test_text_matrix_number_regex_accepts_the_same_strings_as_before() -> None:
    for text in _strings("1.eE+- x", 6):
        assert bool(npy_header._NUMBER.fullmatch(text)) == bool(OLD_NUMBER.fullmatch(text)), text
    for text in ("nan", " -inf ", "INF", "\u0661.5", "1e5 ", "١٢"):  # the second alternative, other scripts' digits
        assert bool(npy_header._NUMBER.fullmatch(text)) == bool(OLD_NUMBER.fullmatch(text)), text


def test_a_text_file_of_one_long_digit_run_is_refused_at_once(tmp_path: Path) -> None:
    (tmp_path / "t.npy").write_text("1" * 65000 + "x\n")
    done = _run(["train", "t.npy", "-o", "x.npz", "--method", "btel-c", "--budget", "5KB"], tmp_path)
    assert done.returncode == 2, done.stderr
    assert "is a text matrix" in done.stderr and "Convert it once" in done.stderr and "skiprows=1" in done.stderr


# --- 3. btel report's kept sections --------------------------------------------------------------

def test_kept_sections_are_what_the_old_regex_found() -> None:
    """Every sequence of up to 6 marker pieces: the same blocks, names in the same order."""
    pieces = ["<!-- a:start -->", "<!-- a:end -->", "<!-- b:start -->", "<!-- b:end -->", "x\n",
              "<!-- a-b:start -->", "<!-- a-b:end -->"]
    for n in range(7):
        for parts in itertools.product(pieces, repeat=n):
            text = "".join(parts)
            old = {m.group("name"): m.group(0) for m in OLD_MARKER.finditer(text)}
            assert list(report._kept_sections(text).items()) == list(old.items()), text
    odd = "<!-- <!-- a:start --> <!--a:end --> <!-- a:end--> <!-- é:start -->é<!-- é:end --><!-- a:end -->"
    assert report._kept_sections(odd) == {m.group("name"): m.group(0) for m in OLD_MARKER.finditer(odd)}


def test_report_reads_60000_unclosed_markers_at_once(tmp_path: Path) -> None:
    """'<!-- a:start -->' * 60000 (960 KB) in docs/results.md hung btel report for hours, with and without
    --overwrite (the check that the report wrote the file, and the sections it keeps)."""
    (tmp_path / "runs" / "accuracy").mkdir(parents=True)
    (tmp_path / "runs" / "accuracy" / "results.json").write_text('{"rows": [], "run": {}}')
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "results.md").write_text("<!-- a:start -->" * 60000)
    done = _run(["report", "--runs", "runs", "--docs", "docs"], tmp_path)
    assert done.returncode == 2 and "was not written by btel report" in done.stderr, done.stderr
    (tmp_path / "docs" / "results.md").write_text("<!-- a:start -->" * 60000 + "<!-- b:start -->B<!-- b:end -->")
    done = _run(["report", "--runs", "runs", "--docs", "docs"], tmp_path)  # a kept block: the report's file
    assert done.returncode == 0, done.stderr
    text = (tmp_path / "docs" / "results.md").read_text()
    assert "<!-- b:start -->B<!-- b:end -->" in text and "<!-- a:start -->" not in text


# --- 4. the record beside a descriptor .npy ------------------------------------------------------

def _break(sidecar: Path, kind: str) -> None:
    sidecar.unlink()
    if kind == "deep":
        sidecar.write_text("[" * 100_000 + "]" * 100_000)
    elif kind == "not json":
        sidecar.write_bytes(b'{"images": [["a.png", 1, 1]')
    elif kind == "too large":
        with open(sidecar, "wb") as fh:
            fh.truncate(npy_header.MAX_SIDECAR_BYTES + 1)  # sparse: no disk used
    elif kind == "folder":
        sidecar.mkdir()


@pytest.mark.parametrize("kind", ["deep", "not json", "too large", "folder"])
def test_a_broken_record_is_an_error_for_every_reader(extracted, kind: str) -> None:
    images, out = extracted
    sidecar = Path(str(out) + ".json")
    assert row_names(out) == ["00.png", "01.png", "02.png", "03.png"]
    _break(sidecar, kind)
    model = HOGDescriptor()
    for read in (lambda: row_names(out), lambda: row_images(out), lambda: is_extraction_of(out, images, model),
                 lambda: extraction_difference(out, images, model),
                 lambda: extract_cached(images, out, model, progress=False)):
        with pytest.raises(InvalidDescriptorsError, match=r"db\.npy\.json'.*Delete it"):
            read()
    if kind != "folder":  # --force writes the record anew (a folder in its place is the user's to remove)
        assert extract_cached(images, out, model, progress=False, force=True)[1] is False
        assert row_names(out) == ["00.png", "01.png", "02.png", "03.png"]


def test_no_record_still_means_no_names(extracted) -> None:
    images, out = extracted
    Path(str(out) + ".json").unlink()
    assert row_names(out) is None and row_images(out) is None
    assert is_extraction_of(out, images, HOGDescriptor()) is False
    assert extraction_difference(out, images, HOGDescriptor()) is None


@pytest.mark.parametrize("kind", ["fifo", "dev-zero"])
def test_a_record_that_is_no_regular_file_is_refused_without_reading(extracted, kind: str) -> None:
    """A FIFO blocked forever; a symlink to /dev/zero grew memory until it ran out."""
    if not hasattr(os, "mkfifo") or not os.path.exists("/dev/zero"):
        pytest.skip("needs FIFOs and /dev/zero")
    _, out = extracted
    sidecar = Path(str(out) + ".json")
    sidecar.unlink()
    os.mkfifo(sidecar) if kind == "fifo" else sidecar.symlink_to("/dev/zero")

    def cap_memory() -> None:  # the old reader of /dev/zero would fill the machine before the timeout
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))

    code = f"from btel.datasets.row_names import row_names; row_names({str(out)!r})"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=TIMEOUT,
                          preexec_fn=cap_memory, env={**_env(), "OPENBLAS_NUM_THREADS": "1"})
    assert "InvalidDescriptorsError" in done.stderr and "is not a regular file" in done.stderr, done.stderr[-600:]
    assert "db.npy.json" in done.stderr and "Delete it" in done.stderr


def test_localize_names_the_broken_record_and_the_fix(tmp_path: Path) -> None:
    """'[' * 100000 … gave "Error: RecursionError: …", naming neither the file nor the fix."""
    rng = np.random.default_rng(1)
    np.save(tmp_path / "db.npy", rng.standard_normal((12, 32)).astype("f4"))
    np.save(tmp_path / "q.npy", rng.standard_normal((5, 32)).astype("f4"))
    make_method("lsh", budget="2KB").fit(np.load(tmp_path / "db.npy")).save(tmp_path / "m.btel.npz")
    (tmp_path / "db.npy.json").write_text("[" * 100_000 + "]" * 100_000)
    result = CliRunner().invoke(main, ["localize", str(tmp_path / "m.btel.npz"), str(tmp_path / "q.npy"),
                                       "--db", str(tmp_path / "db.npy"), "-o", str(tmp_path / "p.csv")])
    assert result.exit_code == 2, result.output
    assert "db.npy.json" in result.output and "nests too deeply" in result.output and "Delete it" in result.output
    assert "RecursionError" not in result.output and "Traceback" not in result.output


# --- 5. progressive JPEG scan bomb ---------------------------------------------------------------

def _jpeg_with_scans(scans: int, size: int = 256) -> bytes:
    """The benchmarks' crafter (``benchmarks/fuzz_families.py``), loaded as the fuzz tests load their harness."""
    spec = importlib.util.spec_from_file_location("fuzz_families", FAMILIES_PATH)
    families = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(families)
    return families.jpeg_of_empty_scans(scans, size)


def test_a_jpeg_of_too_many_scans_is_refused_before_decoding(tmp_path: Path) -> None:
    path = tmp_path / "a.jpg"
    path.write_bytes(_jpeg_with_scans(MAX_JPEG_SCANS + 1))
    with pytest.raises(DataNotFoundError, match=rf"a\.jpg' is a JPEG of {MAX_JPEG_SCANS + 1} scans.*Re-save it"):
        read_image(path)
    (tmp_path / "imgs").mkdir()
    (tmp_path / "imgs" / "a.jpg").write_bytes(_jpeg_with_scans(20_000, size=2000))  # minutes to decode before
    result = CliRunner().invoke(main, ["extract", str(tmp_path / "imgs"), "-o", str(tmp_path / "o.npy")])
    assert result.exit_code == 2 and "20000 scans" in result.output, result.output


@pytest.mark.parametrize("mode", ["L", "RGB"])
def test_ordinary_progressive_and_baseline_jpegs_are_read(tmp_path: Path, mode: str) -> None:
    image = Image.fromarray(np.random.default_rng(2).integers(0, 255, (48, 64, 3), dtype=np.uint8)).convert(mode)
    for progressive in (True, False):
        path = tmp_path / f"{mode}{progressive}.jpg"
        image.save(path, "JPEG", progressive=progressive, optimize=True)
        assert read_image(path, grey=True).shape == (48, 64)

"""Streaming localization: one descriptor per line in, one prediction per line out."""

from __future__ import annotations

import io
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel import BTELocalizer, filter_sequence, load
from btel.cli import main
from btel.datasets import synthetic_route
from btel.methods.btel.encoding import decode_constrained, n_bits_for
from btel.exceptions import InvalidDescriptorsError, InvalidParameterError
from btel.streaming import localize_stream, parse_descriptor_line, read_lines


@pytest.fixture(scope="module")
def route():
    return synthetic_route(300, 32, n_regions=3, seed=4)


@pytest.fixture(scope="module")
def model_path(route, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("stream") / "m.npz"
    BTELocalizer(n_regions=3, feature_ratio=0.5, random_state=0, progress=False).fit(route.map).save(path)
    return path


def as_lines(Q: np.ndarray, sep: str = ",") -> list[str]:
    # repr of a float32 value read back as float64 and cast to float32 is the same value.
    return [sep.join(repr(v) for v in row.tolist()) + "\n" for row in Q]


# ----------------------------------------------------------------------------- parsing
@pytest.mark.parametrize("line", ["1,2,3", "1 2 3", "1, 2,\t3\n", "  1.0e0 ,2 3  "])
def test_parse_accepts_commas_and_whitespace(line: str) -> None:
    np.testing.assert_array_equal(parse_descriptor_line(line, 3), [[1, 2, 3]])
    assert parse_descriptor_line(line).dtype == np.float32


@pytest.mark.parametrize(
    "line, message",
    [
        ("1,2", "expected 3 values, got 2"),
        ("1,2,3,4", "expected 3 values, got 4"),
        ("1,abc,3", "'abc' is not a number"),
        ("1,nan,3", "value 2 is 'nan'"),
        ("1,2,-inf", "value 3 is '-inf'"),
        ("   ", "empty line"),
    ],
)
def test_parse_rejects_malformed_lines(line: str, message: str) -> None:
    with pytest.raises(InvalidDescriptorsError, match=message):
        parse_descriptor_line(line, 3)


def test_read_lines_follows_a_growing_file_and_waits_for_whole_lines(tmp_path: Path) -> None:
    path = tmp_path / "grow.txt"
    path.write_text("1,2\n3,")

    def append() -> None:
        time.sleep(0.3)
        with open(path, "a") as fh:
            fh.write("4\n")  # completes the half-written line
            fh.flush()
            time.sleep(0.2)
            fh.write("5,6\n")

    writer = threading.Thread(target=append)
    writer.start()
    with open(path) as fh:
        lines = list(read_lines(fh, follow=True, poll_interval=0.02, idle_timeout=1.0))
    writer.join()
    assert lines == ["1,2\n", "3,4\n", "5,6\n"]


# ----------------------------------------------------------------------------- the Python API
def test_stream_equals_batch_predict_plus_filter(route, model_path: Path) -> None:
    model = load(model_path)
    Q = route.queries[:120]
    errors: list[tuple[int, str]] = []
    text = io.StringIO("".join(as_lines(Q)))
    out = list(localize_stream(model, text, window=5, on_error=lambda n, m: errors.append((n, m))))
    expected = filter_sequence(model.predict(Q), 5, n_places=model.n_places_)
    assert errors == []
    assert [n for n, _ in out] == list(range(1, 121))
    np.testing.assert_array_equal([p for _, p in out], expected)


def test_stream_hmm_equals_batch_hmm(route, model_path: Path) -> None:
    # Online forward filtering, one line at a time, is the batch decode of the same traverse.
    model = load(model_path)
    Q = route.queries[:80]
    lines = as_lines(Q)
    lines.insert(10, "not, numbers\n")
    errors: list[tuple[int, str]] = []
    out = list(localize_stream(model, io.StringIO("".join(lines)), hmm=True,
                               on_error=lambda n, m: errors.append((n, m))))
    assert [n for n, _ in errors] == [11] and len(out) == 80
    np.testing.assert_array_equal([p for _, p in out], model.predict_sequence(Q, "hmm"))
    with pytest.raises(InvalidParameterError, match="not both"):
        list(localize_stream(model, io.StringIO(lines[0]), hmm=True, window=5))


def test_one_query_at_a_time_equals_batch(route, model_path: Path) -> None:
    # The single-query fast paths (decode on Python ints, per-region weight blocks) agree with batch.
    model = load(model_path)
    Q = route.queries
    batch = model.predict(Q)
    assert batch.min() >= 0 and np.unique(model.predict_region(Q)).size == 3
    np.testing.assert_array_equal([model.predict(Q[i : i + 1])[0] for i in range(len(Q))], batch)


@pytest.mark.parametrize("n_places", [2, 3, 5, 8, 9, 300, 1000, 1025])
def test_single_row_decode_equals_vectorised(n_places: int) -> None:
    rng = np.random.default_rng(n_places)
    margins = rng.standard_normal((500, n_bits_for(n_places)))
    margins[rng.random(margins.shape) < 0.1] = 0.0  # exact zeros read as bit 0 on both paths
    batch = decode_constrained(margins, n_places)
    assert batch.max() < n_places
    np.testing.assert_array_equal([decode_constrained(m[None], n_places)[0] for m in margins], batch)


# ----------------------------------------------------------------------------- the command line
def test_cli_stream_skips_malformed_lines_and_goes_on(route, model_path: Path) -> None:
    model = load(model_path)
    Q = route.queries[:40]
    lines = as_lines(Q, sep=" ")
    bad = {3: "1,2,3\n", 8: "not,numbers\n", 15: ",".join(["nan"] * 32) + "\n"}
    feed: list[str] = []
    good_rows = []
    for i, line in enumerate(lines):
        if len(feed) + 1 in bad:
            feed.append(bad[len(feed) + 1])
        feed.append(line)
        good_rows.append(i)
    feed.append("\n")  # blank lines are ignored
    result = CliRunner().invoke(main, ["localize", str(model_path), "--stream", "--sequence-filter", "4"],
                                input="".join(feed), catch_exceptions=False)
    assert result.exit_code == 0, result.stderr
    got = [int(v) for v in result.stdout.split()]
    np.testing.assert_array_equal(got, filter_sequence(model.predict(Q), 4, n_places=model.n_places_))
    errors = result.stderr.strip().splitlines()
    assert errors[0].startswith("error: line 3: expected 32 values, got 3")
    assert errors[1].startswith("error: line 8: expected 32 values, got 2")
    assert errors[2].startswith("error: line 15: value 1 is 'nan'")
    assert errors[3] == "40 predictions; 3 malformed line(s) skipped"


@pytest.mark.parametrize(
    "args, message",
    [
        (["QUERIES", "--stream"], "drop QUERIES"),
        (["--stream", "--follow"], "--follow needs --input"),
        (["QUERIES", "-o", "p.csv", "--follow"], "only apply with --stream"),
        ([], "give QUERIES"),
        (["--stream", "--hmm", "--sequence-filter", "5"], "not both"),
        (["--stream", "--top-k", "3"], "batch"),
    ],
)
def test_cli_stream_usage_errors(model_path: Path, args: list[str], message: str) -> None:
    result = CliRunner().invoke(main, ["localize", str(model_path), *args])
    assert result.exit_code == 2 and message in result.stderr


def _btel(*args: str, **kwargs) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([sys.executable, "-m", "btel.cli", *args], text=True, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kwargs)


def test_subprocess_answers_each_line_before_the_next_arrives(route, model_path: Path) -> None:
    # What a robot does: write one descriptor, read its place, write the next. This deadlocks
    # unless every prediction is flushed as soon as its line is read.
    model = load(model_path)
    Q = route.queries[:12]
    proc = _btel("localize", str(model_path), "--stream", stdin=subprocess.PIPE)
    try:
        answers = []
        for i, line in enumerate(as_lines(Q)):
            if i == 5:
                proc.stdin.write("oops\n")
            proc.stdin.write(line)
            proc.stdin.flush()
            answers.append(int(proc.stdout.readline()))
        proc.stdin.close()
        stderr = proc.stderr.read()
        assert proc.wait(timeout=30) == 0
    finally:
        proc.kill()
    np.testing.assert_array_equal(answers, model.predict(Q))
    assert "line 6:" in stderr


def test_subprocess_follows_a_file_being_appended_to(route, model_path: Path, tmp_path: Path) -> None:
    model = load(model_path)
    Q = route.queries[:20]
    lines = as_lines(Q)
    feed = tmp_path / "frames.txt"
    feed.write_text("".join(lines[:10]))
    proc = _btel("localize", str(model_path), "--stream", "--input", str(feed), "--follow",
                 "--idle-timeout", "1.5", "--sequence-filter", "3")
    try:
        time.sleep(0.5)
        with open(feed, "a") as fh:
            for line in lines[10:]:
                fh.write(line)
                fh.flush()
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    np.testing.assert_array_equal([int(v) for v in out.split()],
                                  filter_sequence(model.predict(Q), 3, n_places=model.n_places_))


# ----------------------------------------------------------------------------- real data
@pytest.mark.realdata
def test_nordland_patchnorm_stream_equals_batch(nordland_pixels, tmp_path: Path) -> None:
    from btel.descriptors import patch_normalise

    summer, winter = nordland_pixels
    describe = lambda frames: np.stack([patch_normalise(f.reshape(32, 64)).ravel() for f in frames])  # noqa: E731
    X = describe(summer[::4])  # 894 places, 2048-D
    Q = describe(winter[::4][300:360])  # 60 consecutive winter frames
    model_file = tmp_path / "nordland.npz"
    BTELocalizer(feature_ratio=0.05, random_state=0, progress=False).fit(X).save(model_file)
    model = load(model_file)
    result = CliRunner().invoke(main, ["localize", str(model_file), "--stream", "--sequence-filter", "5"],
                                input="".join(as_lines(Q)), catch_exceptions=False)
    assert result.exit_code == 0, result.stderr
    expected = filter_sequence(model.predict(Q), 5, n_places=X.shape[0])
    np.testing.assert_array_equal([int(v) for v in result.stdout.split()], expected)


# ----------------------------------------------------------------------------- hostile lines (issue #20, point 8)
@pytest.mark.parametrize(
    "line, message",
    [
        ("1_0,2,3", "'1_0' is not a number"),
        ("\u0661,2,3", "is not a number"),  # an Arabic-Indic digit: float() would accept it
        ("0x10,2,3", "'0x10' is not a number"),
        ("3.5e38,1,1", "value 1 is outside float32's range"),
        ("1e400,1,1", "value 1 is outside float32's range"),
        ("3e38,3e38,1", "squared norm"),
        ("1,NaN,2", "value 2 is 'NaN'"),
        ("1,2,Infinity", "value 3 is 'Infinity'"),
        ("true,1,2", "'true' is not a number"),
        ('"1",2,3', "is not a number"),
    ],
)
def test_parse_rejects_values_that_are_not_finite_float32_decimals(line: str, message: str) -> None:
    for form in (line, line.encode("utf-8")):
        with pytest.raises(InvalidDescriptorsError, match=message):
            parse_descriptor_line(form, 3)


@pytest.mark.parametrize("line", ["+1,.5,5.", "1,,2,3", "1e2, -2E-1 ,3", b"1,2,3\r\n", "01 2 3"])
def test_fast_and_strict_parsers_agree_on_good_lines(line) -> None:
    values = parse_descriptor_line(line)
    text = line.decode() if isinstance(line, bytes) else line
    expected = [float(t) for t in text.replace(",", " ").split()]
    np.testing.assert_array_equal(values[0], np.float32(expected))


def test_a_line_past_the_limit_is_dropped_unread_and_reported(monkeypatch) -> None:
    from btel.streaming import LineTooLong, max_line_bytes

    good = b"1,2,3\n"
    data = good + b"4," * 5000 + b"5\n" + good + b"7," * 40  # the last line is long and unterminated
    got = list(read_lines(io.BytesIO(data), max_line=64))
    assert got[0] == good and isinstance(got[1], LineTooLong) and got[2] == good and isinstance(got[3], LineTooLong)
    assert len(got) == 4
    # A line of exactly the limit passes.
    assert list(read_lines(io.BytesIO(b"1" * 64 + b"\n"), max_line=64)) == [b"1" * 64 + b"\n"]
    monkeypatch.setenv("BTEL_MAX_LINE_BYTES", "100")
    assert max_line_bytes() == 100
    monkeypatch.setenv("BTEL_MAX_LINE_BYTES", "-3")
    with pytest.raises(InvalidParameterError, match="BTEL_MAX_LINE_BYTES must be a positive number"):
        max_line_bytes()


def test_cli_stream_reports_an_overlong_line_and_goes_on(route, model_path: Path) -> None:
    model = load(model_path)
    lines = as_lines(route.queries[:3])
    feed = lines[0] + "1," * 3000 + "1\n" + lines[1] + lines[2]
    result = CliRunner().invoke(main, ["localize", str(model_path), "--stream"], input=feed,
                                env={"BTEL_MAX_LINE_BYTES": "4096"}, catch_exceptions=False)
    assert result.exit_code == 0, result.stderr
    np.testing.assert_array_equal([int(v) for v in result.stdout.split()], model.predict(route.queries[:3]))
    assert "error: line 2: line longer than 4096 bytes" in result.stderr
    assert "BTEL_MAX_LINE_BYTES" in result.stderr


def test_a_whole_file_is_predicted_in_blocks_with_the_same_answers_and_errors(route, model_path: Path,
                                                                               tmp_path: Path) -> None:
    import btel.streaming as streaming

    model = load(model_path)
    lines = as_lines(route.queries[:300])
    lines[10] = "1,2\n"
    lines[200] = "reset\n"
    path = tmp_path / "frames.txt"
    path.write_text("".join(lines))
    errors_file: list[tuple[int, str]] = []
    errors_pipe: list[tuple[int, str]] = []
    with open(path, "rb") as source:
        assert streaming._is_regular_file(source)
        from_file = list(localize_stream(model, source, window=4, on_error=lambda n, m: errors_file.append((n, m))))
    piped = io.BytesIO(path.read_bytes())  # not a regular file: line by line
    assert not streaming._is_regular_file(piped)
    one_by_one = list(localize_stream(model, piped, window=4, on_error=lambda n, m: errors_pipe.append((n, m))))
    assert from_file == one_by_one and len(from_file) == 298
    assert errors_file == errors_pipe == [(11, "expected 32 values, got 2.")]

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
from btel.sequence.streaming import localize_stream, parse_descriptor_line, read_lines


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
    assert result.exit_code == 1, result.stderr  # a line skipped: exit 1 (not every input answered)
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
        (["QUERIES", "--stream"], "are for batch localization"),
        (["--stream", "--follow"], "--follow needs --input"),
        (["QUERIES", "-o", "p.csv", "--follow"], "need --stream"),
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
        assert proc.wait(timeout=30) == 1  # "oops" was skipped: not every line answered
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


@pytest.mark.parametrize("line", ["+1,.5,5.", "1  2,3", "1e2, -2E-1 ,3", b"1,2,3\r\n", "01 2 3"])
def test_fast_and_strict_parsers_agree_on_good_lines(line) -> None:
    values = parse_descriptor_line(line)
    text = line.decode() if isinstance(line, bytes) else line
    expected = [float(t) for t in text.replace(",", " ").split()]
    np.testing.assert_array_equal(values[0], np.float32(expected))


def test_a_line_past_the_limit_is_dropped_unread_and_reported(monkeypatch) -> None:
    from btel.sequence.streaming import LineTooLong, max_line_bytes

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
    with pytest.raises(InvalidParameterError, match="BTEL_MAX_LINE_BYTES must be a number of bytes from 1 to"):
        max_line_bytes()


def test_cli_stream_reports_an_overlong_line_and_goes_on(route, model_path: Path) -> None:
    model = load(model_path)
    lines = as_lines(route.queries[:3])
    feed = lines[0] + "1," * 3000 + "1\n" + lines[1] + lines[2]
    result = CliRunner().invoke(main, ["localize", str(model_path), "--stream"], input=feed,
                                env={"BTEL_MAX_LINE_BYTES": "4096"}, catch_exceptions=False)
    assert result.exit_code == 1, result.stderr  # a line skipped: exit 1 (not every input answered)
    np.testing.assert_array_equal([int(v) for v in result.stdout.split()], model.predict(route.queries[:3]))
    assert "error: line 2: line longer than 4096 bytes" in result.stderr
    assert "BTEL_MAX_LINE_BYTES" in result.stderr


def test_a_whole_file_is_predicted_in_blocks_with_the_same_answers_and_errors(route, model_path: Path,
                                                                               tmp_path: Path) -> None:
    import btel.sequence.streaming as streaming

    model = load(model_path)
    lines = as_lines(route.queries[:300])
    lines[10] = lines[289] = "1,2\n"
    lines[200] = "reset\n"
    path = tmp_path / "frames.txt"
    path.write_text("".join(lines) + "0.5,0.5")  # the producer stopped inside line 301
    errors_file: list[tuple[int, str]] = []
    errors_pipe: list[tuple[int, str]] = []
    with open(path, "rb") as source:
        assert streaming._is_regular_file(source)
        from_file = list(localize_stream(model, source, window=4, on_error=lambda n, m: errors_file.append((n, m))))
    piped = io.BytesIO(path.read_bytes())  # not a regular file: line by line
    assert not streaming._is_regular_file(piped)
    one_by_one = list(localize_stream(model, piped, window=4, on_error=lambda n, m: errors_pipe.append((n, m))))
    assert from_file == one_by_one and len(from_file) == 297
    # In line order, though line 301 is refused while reading and line 290 only when its block is parsed.
    assert [n for n, _ in errors_file] == [n for n, _ in errors_pipe] == [11, 290, 301]
    assert errors_file == errors_pipe and errors_file[0] == (11, "expected 32 values, got 2.")


# ----------------------------------------------------------------------------- what numpy.savetxt writes
@pytest.mark.parametrize("delimiter", [" ", ",", "\t"])
def test_savetxt_lines_take_the_fast_path_and_equal_the_strict_parser(route, tmp_path: Path,
                                                                      delimiter: str) -> None:
    from btel.sequence.lineparse import parse_lines, parse_strict

    Q = route.queries[:40]
    np.savetxt(tmp_path / "q.txt", Q, delimiter=delimiter)  # numpy's default format '%.18e'
    raw = (tmp_path / "q.txt").read_bytes().splitlines(keepends=True)
    rows, fast = parse_lines(raw, Q.shape[1])
    assert all(fast) and rows.dtype == np.float32 and rows.shape == Q.shape
    np.testing.assert_array_equal(rows, Q)  # float32 → '%.18e' → float32 is exact
    np.testing.assert_array_equal(rows, np.concatenate([parse_strict(line, Q.shape[1]) for line in raw]))


@pytest.mark.parametrize("line", [b"1,true,2", b"1 false 2", b"1,null,2", b'1,"2",3', b"1,[2],3", b"1,{},3",
                                  b"[1,2,3]", b"1],[2", b"1  2 3", b"1,,2,3", b" 1 2 3", b"+1,2,3",
                                  b"1,2,3,"])
def test_a_line_that_is_not_plain_numbers_leaves_the_fast_path(line: bytes) -> None:
    from btel.sequence.lineparse import parse_lines

    rows, fast = parse_lines([line], 3)
    assert fast == [False] and rows.shape == (0, 3)


def test_a_block_mixes_fast_strict_and_bad_lines_in_order(route) -> None:
    from btel.sequence.lineparse import parse_lines

    good = [line.encode() for line in as_lines(route.queries[:3], sep=" ")]
    block = [good[0], b"1,2\n", good[1], b"3e38," * 31 + b"3e38\n", good[2]]
    rows, fast = parse_lines(block, 32)
    assert fast == [True, False, True, False, True]  # the overflowing norm goes to the strict parser
    np.testing.assert_array_equal(rows, route.queries[:3])


def test_cli_stream_of_savetxt_files_equals_batch(route, model_path: Path, tmp_path: Path) -> None:
    model = load(model_path)
    Q = route.queries[:300]
    for delimiter in (" ", ","):
        np.savetxt(tmp_path / "q.txt", Q, delimiter=delimiter)
        args = ["localize", str(model_path), "--stream", "--input", str(tmp_path / "q.txt")]
        result = CliRunner().invoke(main, args, catch_exceptions=False)
        assert result.exit_code == 0, result.stderr
        np.testing.assert_array_equal([int(v) for v in result.stdout.split()], model.predict(Q))


def test_a_pipe_backlog_is_answered_in_blocks_with_the_same_answers(route, model_path: Path) -> None:
    """A producer faster than btel: its lines wait in the pipe and go through in blocks, errors in place."""
    model = load(model_path)
    Q = route.queries[np.arange(600) % 300]
    lines = as_lines(Q, sep=" ")
    lines[7] = "1 2\n"
    lines[400] = "reset\n"
    proc = _btel("localize", str(model_path), "--stream", "--sequence-filter", "3", stdin=subprocess.PIPE)
    out, err = proc.communicate("".join(lines), timeout=120)
    assert proc.returncode == 1, err  # a line skipped: exit 1 (not every input answered)
    keep = [i for i in range(600) if i not in (7, 400)]
    expected = np.concatenate([filter_sequence(model.predict(Q[[i for i in keep if i < 400]]), 3,
                                               n_places=model.n_places_),
                               filter_sequence(model.predict(Q[[i for i in keep if i > 400]]), 3,
                                               n_places=model.n_places_)])
    np.testing.assert_array_equal([int(v) for v in out.split()], expected)
    assert "error: line 8: expected 32 values, got 2" in err


def test_the_chunk_reader_says_when_a_pipe_is_idle() -> None:
    from btel.sequence.streamread import IDLE, chunk_lines

    read_end, write_end = os.pipe()
    with os.fdopen(read_end, "rb") as source, os.fdopen(write_end, "wb") as sink:
        sink.write(b"1,2\n3,4\n5,")
        sink.flush()
        lines = chunk_lines(source)
        assert [next(lines), next(lines)] == [b"1,2\n", b"3,4\n"]
        assert next(lines) is IDLE  # half a line held, nothing more waiting: the caller answers now
        sink.write(b"6\n")
        sink.close()
        assert list(lines) == [b"5,6\n"]  # at the end the pipe reads as ready (EOF): no wait, no IDLE


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="F_SETPIPE_SZ is Linux's")
def test_the_chunk_reader_widens_a_pipe_so_a_backlog_comes_in_large_reads() -> None:
    """A fast producer may run up to 1 MiB ahead (80 savetxt lines at d = 500), not the default 64 KiB."""
    import fcntl

    from btel.sequence.streamread import chunk_lines

    get_size = getattr(fcntl, "F_GETPIPE_SZ", 1032)
    read_end, write_end = os.pipe()
    with os.fdopen(read_end, "rb") as source, os.fdopen(write_end, "wb") as sink:
        before = fcntl.fcntl(read_end, get_size)
        sink.write(b"1,2\n")
        sink.close()
        assert list(chunk_lines(source)) == [b"1,2\n"]
        with open("/proc/sys/fs/pipe-max-size") as fh:
            allowed = int(fh.read())
        assert fcntl.fcntl(read_end, get_size) >= max(before, min(1 << 20, allowed))


# ----------------------------------------------------------------------------- binary float32 frames
def frames(Q: np.ndarray) -> bytes:
    return b"".join(np.uint32(row.size).tobytes() + row.astype("<f4").tobytes() for row in Q)


def test_binary_frames_equal_text_lines_and_report_wrong_frames(route, model_path: Path) -> None:
    model = load(model_path)
    Q = route.queries[:50]
    bad = np.full((1, 32), np.nan, dtype=np.float32)
    data = (frames(Q[:10]) + frames(Q[:1, :5]) + frames(bad) + frames(Q[10:30]) + np.uint32(0).tobytes()
            + frames(Q[30:]))
    args = ["localize", str(model_path), "--stream", "--binary", "--sequence-filter", "3"]
    result = CliRunner().invoke(main, args, input=data, catch_exceptions=False)
    assert result.exit_code == 1, result.stderr  # a line skipped: exit 1 (not every input answered)
    expected = np.concatenate([filter_sequence(model.predict(Q[:30]), 3, n_places=model.n_places_),
                               filter_sequence(model.predict(Q[30:]), 3, n_places=model.n_places_)])
    np.testing.assert_array_equal([int(v) for v in result.stdout.split()], expected)
    errors = result.stderr.strip().splitlines()
    assert errors[0] == "error: frame 11: a frame of 5 values; the model takes 32. (skipped)"
    assert errors[1] == "error: frame 12: value 1 is not finite. (skipped)"
    assert errors[2] == "50 predictions; 2 malformed frame(s) skipped"


@pytest.mark.parametrize("tail, message", [
    (np.uint32(32).tobytes() + b"\0" * 20, "frame 3: the input ends after 20 of its 128 bytes"),
    (b"\x01\x00", "frame 3: the input ends inside its 4-byte count"),
    (np.uint32(1 << 30).tobytes(), "frame 3: its count 1073741824 values"),
])
def test_a_cut_or_unframed_binary_input_stops_with_a_named_error(route, model_path: Path, tail: bytes,
                                                                  message: str) -> None:
    result = CliRunner().invoke(main, ["localize", str(model_path), "--stream", "--binary"],
                                input=frames(route.queries[:2]) + tail)
    assert result.exit_code == 2 and message in result.stderr
    assert len(result.stdout.split()) == 2  # the frames before it were answered


def test_binary_only_with_stream(model_path: Path) -> None:
    result = CliRunner().invoke(main, ["localize", str(model_path), "q.npy", "-o", "p.csv", "--binary"])
    assert result.exit_code == 2 and "need --stream" in result.stderr


@pytest.mark.realdata
def test_gardens_point_savetxt_and_frames_stream_like_batch(gardenspoint_netvlad, tmp_path: Path) -> None:
    X_map, X_query = gardenspoint_netvlad
    path = BTELocalizer(random_state=0, progress=False).fit(X_map).save(tmp_path / "gp.npz")
    model = load(path)
    np.savetxt(tmp_path / "q.txt", X_query)
    (tmp_path / "q.bin").write_bytes(frames(X_query))
    for flags in (["--input", str(tmp_path / "q.txt")], ["--binary", "--input", str(tmp_path / "q.bin")]):
        result = CliRunner().invoke(main, ["localize", str(path), "--stream", *flags], catch_exceptions=False)
        assert result.exit_code == 0, result.stderr
        np.testing.assert_array_equal([int(v) for v in result.stdout.split()], model.predict(X_query))


def test_a_followed_file_that_is_truncated_is_read_again_from_its_start(tmp_path) -> None:
    """As `tail -f`: a followed file emptied and rewritten by its producer was read on from the old offset,
    so the new lines were never answered, without a word."""
    import threading
    import time
    import warnings as _warnings

    from btel.sequence.streamread import read_lines

    path = tmp_path / "frames.txt"
    path.write_bytes(b"1,2\n3,4\n5,6\n")

    def rewrite() -> None:
        time.sleep(0.6)
        with open(path, "r+b") as fh:  # new content over the old, then cut: never shorter than 4 bytes
            fh.write(b"7,8\n")
            fh.truncate(4)

    writer = threading.Thread(target=rewrite)
    with open(path, "rb") as fh, _warnings.catch_warnings(record=True) as caught:
        _warnings.simplefilter("always")
        writer.start()
        lines = list(read_lines(fh, follow=True, poll_interval=0.05, idle_timeout=1.5))
    writer.join()
    assert lines == [b"1,2\n", b"3,4\n", b"5,6\n", b"7,8\n"]
    assert [str(w.message) for w in caught] == [
        f"{path} was truncated (it holds 4 bytes; 12 were read): reading it again from its start"]


@pytest.mark.parametrize(("line", "column"), [("1,,2,3", 2), (",1,2,3", 1), ("1,2,3,", 4), ("1, ,2,3", 2),
                                              ("1 2,,3", 3)])
def test_an_empty_value_between_commas_is_a_malformed_line_not_a_skipped_separator(line: str, column: int) -> None:
    """`1,,2,3` read as three values: a line missing one value and holding one extra passed for a whole row."""
    with pytest.raises(InvalidDescriptorsError, match=f"value {column} is empty"):
        parse_descriptor_line(line, None)
    np.testing.assert_array_equal(parse_descriptor_line("1, 2,3", 3), [[1, 2, 3]])  # spaces after commas: fine
    errors: list[tuple[int, str]] = []
    model = BTELocalizer(progress=False).fit(synthetic_route(40, 4, seed=0).map)
    out = list(localize_stream(model, io.BytesIO(f"1,2,3,4\n{line},4\n1,2,3,4\n".encode()),
                               on_error=lambda n, m: errors.append((n, m))))
    assert [n for n, _ in out] == [1, 3] and [n for n, _ in errors] == [2]

"""VPR-Bench object arrays parsed from pickle opcodes: legitimate files read, hostile ones refused
without running, importing or allocating what they ask for (issue 20, findings 1 and 3)."""

from __future__ import annotations

import pickle
import struct
from pathlib import Path

import numpy as np
import pytest

from btel.datasets import GroundTruth
from btel.datasets.groundtruth import read_object_npy
from btel.datasets.pickleparse import parse_object_array
from btel.exceptions import DataNotFoundError, ResourceLimitError


def _npy(path: Path, payload: bytes, shape: tuple[int, ...]) -> Path:
    with open(path, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": "|O", "fortran_order": False, "shape": shape})
        fh.write(payload)
    return path


def _u(text: str) -> bytes:  # BINUNICODE
    raw = text.encode()
    return b"X" + struct.pack("<I", len(raw)) + raw


def _vpr(positives: list[list[int]], dtype: str = "int64") -> np.ndarray:
    array = np.empty((len(positives), 2), dtype=object)
    for q, places in enumerate(positives):
        array[q, 0] = np.int64(q)
        array[q, 1] = np.asarray(places, dtype=dtype)
    return array


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
def test_every_protocol_with_an_empty_positives_array(tmp_path: Path, protocol: int) -> None:
    positives = [[0, 1], [], [2, 3, 4]]
    array = _vpr(positives)
    path = _npy(tmp_path / "gt.npy", pickle.dumps(array, protocol=protocol), array.shape)
    gt = GroundTruth.from_file(path)
    assert [gt.positives(j).tolist() for j in range(3)] == positives


def test_other_integer_dtypes_big_endian_and_fortran_order(tmp_path: Path) -> None:
    array = _vpr([[5], [1, 2]], dtype=">u2")
    path = _npy(tmp_path / "be.npy", pickle.dumps(array, protocol=2), array.shape)
    assert [GroundTruth.from_file(path).positives(j).tolist() for j in range(2)] == [[5], [1, 2]]
    fortran = np.asfortranarray(_vpr([[3], [0, 4], [1]]))
    np.save(tmp_path / "f.npy", fortran, allow_pickle=True)
    assert [GroundTruth.from_file(tmp_path / "f.npy").positives(j).tolist() for j in range(3)] == [[3], [0, 4], [1]]


def test_ndarray_over_file_bytes_is_refused_not_a_pointer(tmp_path: Path) -> None:
    """ndarray((1,), 'O', buffer) turned 8 file bytes into an object pointer (a segfault before)."""
    payload = (b"\x80\x02cnumpy\nndarray\nK\x01\x85" + _u("O") + b"C\x08" + struct.pack("<Q", 0x4141414141)
               + b"\x87R.")
    path = _npy(tmp_path / "ptr.npy", payload, (1,))
    with pytest.raises(DataNotFoundError, match="unexpected call of numpy.ndarray"):
        read_object_npy(path)


def test_allocation_bomb_is_refused_before_allocating(tmp_path: Path) -> None:
    """A 258-byte pickle asking for ndarray((10**8,), 'i8') (2.5 GB before)."""
    payload = (b"\x80\x02cnumpy\nndarray\nJ" + struct.pack("<i", 10**8) + b"\x85" + _u("i8") + b"\x86R.")
    with pytest.raises(DataNotFoundError, match="numpy.ndarray"):
        parse_object_array(payload)
    # The same size declared in a legitimate array state: over the budget before any allocation, and
    # under it, the shape must still match the bytes present.
    good = pickle.dumps(_vpr([[1, 2]]), protocol=2)
    assert b"K\x02\x85" in good
    with pytest.raises(ResourceLimitError, match="BTEL_MEMORY_LIMIT"):
        parse_object_array(good.replace(b"K\x02\x85", b"J" + struct.pack("<i", 10**8) + b"\x85", 1))
    with pytest.raises(DataNotFoundError, match="bytes"):
        parse_object_array(good.replace(b"K\x02\x85", b"J" + struct.pack("<i", 10**6) + b"\x85", 1))


def _with_item(item_ops: bytes, n_items: int = 1) -> bytes:
    """A protocol-2 1-D object array whose items are the value ``item_ops`` leaves on the stack."""
    one = np.empty(n_items, dtype=object)
    for i in range(n_items):
        one[i] = [7777777]
    template = pickle.dumps(one, protocol=2)
    sentinel = b"J" + struct.pack("<i", 7777777) + b"a"
    start = template.index(sentinel) - 3  # EMPTY_LIST, BINPUT k
    assert template[start:start + 2] == b"]q"
    if n_items == 1:
        return template[:start] + item_ops + template[start + 3 + len(sentinel):]
    end = template.rindex(sentinel) + len(sentinel)
    return template[:start] + item_ops + template[end:]


def test_nested_list_bomb_ends_fast() -> None:
    """2**22 leaves from a few hundred bytes of lists sharing memo entries (60 s before)."""
    body = b"]r" + struct.pack("<I", 1000) + b"K\x01a"
    for level in range(1, 23):
        prev = struct.pack("<I", 999 + level)
        body += b"0(j" + prev + b"j" + prev + b"lr" + struct.pack("<I", 1000 + level)  # POP, [prev, prev]
    payload = _with_item(body)
    assert len(payload) < 700
    with pytest.raises(DataNotFoundError, match="list holding something other than integers"):
        parse_object_array(payload)


def test_a_shared_list_referenced_many_times_is_counted_before_building(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "1M")
    ints = b"".join(b"M" + struct.pack("<H", i) for i in range(1000))
    body = b"]r" + struct.pack("<I", 1000) + b"(" + ints + b"e" + (b"j" + struct.pack("<I", 1000)) * 299
    payload = _with_item(body, n_items=300)
    assert len(payload) < 6000
    with pytest.raises(ResourceLimitError, match="BTEL_MEMORY_LIMIT"):
        parse_object_array(payload)
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "4M")
    shape, items = parse_object_array(payload)
    assert shape == (300,) and len(items) == 300 and items[299].tolist() == list(range(1000))


@pytest.mark.parametrize("global_name", [b"os\nsystem", b"builtins\neval", b"numpy\nload", b"numpy.core.multiarray\n_reconstruct_x"])
def test_any_other_global_is_refused_by_name(global_name: bytes) -> None:
    payload = b"\x80\x02c" + global_name + b"\n" + _u("true") + b"\x85R."
    with pytest.raises(DataNotFoundError, match="refused global"):
        parse_object_array(payload)


@pytest.mark.parametrize("payload", [
    b"", b"\x80\x01N.", b"\x80\x06N.", b"\x80\x02N", b"\x80\x02N.", b"\x80\x02(.", b"\x80\x02h\x05.",
    b"\x80\x02\x8a\x09" + b"\xff" * 9 + b".", b"\x80\x02\x8b\x00\x00\x00\x00.", b"\x80\x02P.", b"\x80\x02\x82\x01.",
    b"\x80\x05\x97.", b"\x80\x02]K\x01a\x88b.", b"\x80\x02X\xff\xff\xff\xff",
])
def test_malformed_payloads_are_data_errors(payload: bytes) -> None:
    with pytest.raises(DataNotFoundError):
        parse_object_array(payload)


def test_strings_floats_and_booleans_are_not_place_indices() -> None:
    for item, message in ((["a"], "list holding"), ("a", "found a str"), (True, "boolean"),
                          (np.array([0.5]), "float64")):
        one = np.empty(1, dtype=object)
        one[0] = item
        with pytest.raises(DataNotFoundError, match=message):
            parse_object_array(pickle.dumps(one, protocol=3))
    one = np.empty(1, dtype=object)
    one[0] = np.array([2.0, 3.0])  # whole floats are read as indices
    assert parse_object_array(pickle.dumps(one, protocol=4))[1][0].tolist() == [2, 3]


@pytest.mark.parametrize("body", [b"N" + b"\x94" * 3_000_000, b"]" * 3_000_000],
                         ids=["memo entries", "empty lists"])
def test_one_byte_opcodes_that_each_add_an_object_are_counted(body: bytes, monkeypatch: pytest.MonkeyPatch,
                                                              tmp_path: Path) -> None:
    """Each MEMOIZE or EMPTY_LIST byte adds a Python object of ~100 B: a 60 MB file held 5.4 GB for 61 s
    before its unbalanced stack was reported. Every object is now charged against the memory limit."""
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "64M")
    with pytest.raises(ResourceLimitError, match="the objects its pickle builds"):
        parse_object_array(b"\x80\x04" + body + b".")
    header = np.lib.format.header_data_from_array_1_0(np.empty(2, dtype=object))
    path = tmp_path / "gt.npy"
    with open(path, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, header)
        fh.write(b"\x80\x04" + body + b".")
    with pytest.raises(ResourceLimitError, match=f"{path.name}.*the objects its pickle builds"):
        read_object_npy(path)
    # a genuine ground truth of 20,000 queries stays far inside the default limit
    monkeypatch.delenv("BTEL_MEMORY_LIMIT")
    truth = np.empty(20_000, dtype=object)
    for i in range(truth.size):
        truth[i] = np.arange(i % 7 + 1, dtype=np.int64)
    shape, items = parse_object_array(pickle.dumps(truth, protocol=4))
    assert shape == (20_000,) and len(items) == 20_000

"""VPR-Bench's pickled object arrays, parsed and never unpickled.

VPR-Bench stores ground truth as ``ground_truth_new.npy``: an object array (per query, the indices
of its correct map images) whose payload is a pickle. :func:`parse_object_array` reads that payload
by walking its opcodes with :func:`pickletools.genops` against the exact shapes numpy writes for an
object array of integer arrays (pickle protocols 2 to 5, numpy 1.x and 2.x names), and builds the
integer arrays itself with :func:`numpy.frombuffer`.

Nothing in the file is ever called or imported: a ``GLOBAL``/``STACK_GLOBAL`` opcode only yields a
*name*, and ``REDUCE``/``BUILD`` are interpreted only for the few names numpy's array pickles use
(``_reconstruct``, ``ndarray``, ``dtype``, ``scalar``, ``_frombuffer``, ``_codecs.encode``,
``bytes``), with their argument shapes checked. Any other name or opcode is refused. Element
counts are bounded by :mod:`btel.core.limits` before anything is allocated.
"""

from __future__ import annotations

import math
import pickletools
import re
from typing import Any

import numpy as np

from ..exceptions import DataNotFoundError, ResourceLimitError
from ..core.limits import check_count

__all__ = ["parse_object_array"]

_RECONSTRUCT = {("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct")}
_SCALAR = {("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar")}
_FROMBUFFER = {("numpy.core.numeric", "_frombuffer"), ("numpy._core.numeric", "_frombuffer")}
_NDARRAY = {("numpy", "ndarray")}
_DTYPE = {("numpy", "dtype")}
_ENCODE = {("_codecs", "encode")}
_BYTES = {("__builtin__", "bytes"), ("builtins", "bytes")}
_KNOWN = _RECONSTRUCT | _SCALAR | _FROMBUFFER | _NDARRAY | _DTYPE | _ENCODE | _BYTES

#: dtypes an integer-array item may have (plus whole-valued floats); "O" only for the outer array.
_DTYPE_SPEC = re.compile(r"[iu][1248]|f[48]|O[48]")
_MAX_DEPTH = 64  # nesting of tuples/lists on the stack (numpy's pickles need 4)
#: Bytes charged per Python object the walk holds (a stack entry, a memo entry, a list item): 1-byte opcodes
#: such as MEMOIZE or EMPTY_LIST each add an object of ~60–100 B, so a 60 MB file once held 5.4 GB.
_BYTES_PER_OBJECT = 100


class _Refused(Exception):
    """Internal: the payload is not an object array of integer arrays."""


class _Name:
    __slots__ = ("key",)

    def __init__(self, module: str, name: str) -> None:
        if (module, name) not in _KNOWN:
            raise _Refused(f"refused global {module}.{name}: only numpy arrays of integers are read")
        self.key = (module, name)


class _DType:
    """``numpy.dtype(spec, False, True)``; BUILD sets the byte order."""

    __slots__ = ("spec", "order")

    def __init__(self, spec: Any) -> None:
        if isinstance(spec, bytes):
            spec = spec.decode("latin1")
        if not isinstance(spec, str) or not _DTYPE_SPEC.fullmatch(spec):
            raise _Refused(f"dtype {spec!r} is not an integer, float or object dtype")
        self.spec, self.order = spec, "|"

    def build(self, state: Any) -> None:
        if not (isinstance(state, tuple) and len(state) >= 2 and state[1] in ("<", ">", "|", "=")):
            raise _Refused("unexpected dtype state")
        self.order = state[1]

    def resolve(self) -> np.dtype:
        order = self.order if self.order in "<>" else "="
        return np.dtype(order + self.spec) if self.spec[0] != "O" else np.dtype(object)


class _Array:
    """``_reconstruct(ndarray, (0,), b'b')``; BUILD fills shape, dtype and data."""

    __slots__ = ("value",)

    def __init__(self) -> None:
        self.value: Any = None

    def build(self, state: Any, budget: list[int]) -> None:
        if self.value is not None or not (isinstance(state, tuple) and len(state) == 5):
            raise _Refused("unexpected array state")
        _, shape, dtype, fortran, data = state
        if not isinstance(dtype, _DType) or not isinstance(fortran, bool):
            raise _Refused("unexpected array state")
        self.value = _make_array(shape, dtype.resolve(), fortran, data, budget)


def _shape(shape: Any) -> tuple[int, ...]:
    if not (isinstance(shape, tuple) and len(shape) <= 2
            and all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s for s in shape)):
        raise _Refused(f"array shape {shape!r} is not one or two non-negative sizes")
    return shape


def _make_array(shape: Any, dtype: np.dtype, fortran: bool, data: Any, budget: list[int]) -> Any:
    shape = _shape(shape)
    size = math.prod(shape)
    _spend(budget, size)
    if dtype == object:
        if not isinstance(data, list) or len(data) != size:
            raise _Refused(f"object array of shape {shape} holds {type(data).__name__} data of another size")
        return ("object", shape, fortran, data)
    if len(shape) != 1:
        raise _Refused(f"an integer array of shape {shape}; place indices are 1-D")
    if isinstance(data, str):
        data = data.encode("latin1")
    if not isinstance(data, (bytes, bytearray)) or len(data) != size * dtype.itemsize:
        raise _Refused(f"array data of {len(data) if isinstance(data, (bytes, bytearray)) else '?'} bytes "
                       f"for {size} items of {dtype}")
    return _integers(np.frombuffer(bytes(data), dtype=dtype))


def _integers(values: np.ndarray) -> np.ndarray:
    if values.dtype.kind == "f":
        if not (np.all(np.isfinite(values)) and np.all(values == np.round(values))
                and np.all(np.abs(values) < 2.0**62)):
            raise _Refused(f"found an array of dtype {values.dtype} with values that are not place indices")
    elif values.dtype.kind == "u" and values.size and values.max() > np.iinfo(np.int64).max:
        raise _Refused("found an unsigned value beyond int64")
    return values.astype(np.int64)


def _spend(budget: list[int], count: int) -> None:
    budget[0] += count
    check_count(budget[0], 8, "VPR-Bench ground truth")


def _reduce(func: Any, args: Any, budget: list[int]) -> Any:
    if not isinstance(func, _Name) or not isinstance(args, tuple):
        raise _Refused("REDUCE of something other than numpy's array reconstruction")
    key = func.key
    if key in _RECONSTRUCT:
        if len(args) == 3 and isinstance(args[0], _Name) and args[0].key in _NDARRAY and args[1] == (0,):
            return _Array()
    elif key in _DTYPE:
        if len(args) == 3 and args[1:] in ((False, True), (0, 1)):
            return _DType(args[0])
    elif key in _SCALAR:
        if len(args) == 2 and isinstance(args[0], _DType):
            dtype = args[0].resolve()
            data = args[1].encode("latin1") if isinstance(args[1], str) else args[1]
            if dtype != object and isinstance(data, bytes) and len(data) == dtype.itemsize:
                return int(_integers(np.frombuffer(data, dtype=dtype))[0])
    elif key in _FROMBUFFER:
        if len(args) == 4 and isinstance(args[1], _DType) and args[3] in ("C", "F"):
            dtype = args[1].resolve()
            if dtype != object:
                return _make_array(args[2], dtype, args[3] == "F", args[0], budget)
    elif key in _ENCODE:
        if len(args) == 2 and isinstance(args[0], str) and args[1] == "latin1":
            return args[0].encode("latin1")
    elif key in _BYTES:
        if args == ():
            return b""
    raise _Refused(f"unexpected call of {'.'.join(key)} with {len(args)} arguments")


_PUSH_NONE = {"NONE"}
_INTS = {"BININT", "BININT1", "BININT2", "LONG1", "INT"}
_STRS = {"SHORT_BINUNICODE", "BINUNICODE", "BINUNICODE8", "SHORT_BINSTRING", "BINSTRING", "UNICODE", "STRING"}
_BYTES_OPS = {"SHORT_BINBYTES", "BINBYTES", "BINBYTES8", "BYTEARRAY8"}


def parse_object_array(payload: bytes) -> tuple[tuple[int, ...], list[np.ndarray]]:
    """Parse the pickle of an object array whose items are integers or 1-D integer arrays.

    Parameters
    ----------
    payload : bytes
        The pickle after an ``.npy`` header (``np.save(..., allow_pickle=True)`` of an object array).

    Returns
    -------
    shape : tuple of int
        The object array's shape (C order).
    items : list of ndarray, dtype int64
        Each item as a 1-D integer array (an integer item becomes a length-1 array), in C order.

    Raises
    ------
    DataNotFoundError
        Anything but the opcodes and names numpy writes for such an array, or items that are not
        integers.
    ResourceLimitError
        More elements than :mod:`btel.core.limits` allows.
    """
    try:
        return _parse(payload)
    except _Refused as exc:
        raise DataNotFoundError(
            f"{exc}; btel reads only object arrays of integer arrays (VPR-Bench's ground truth) from "
            "pickles and never runs code from a file.") from None
    except ResourceLimitError:
        raise
    except (ValueError, TypeError, OverflowError, UnicodeError, RecursionError, MemoryError) as exc:
        raise DataNotFoundError(f"not a valid pickled object array ({type(exc).__name__}: {exc}).") from None


def _parse(payload: bytes) -> tuple[tuple[int, ...], list[np.ndarray]]:
    stack: list[Any] = []
    marks: list[int] = []
    memo: dict[int, Any] = {}
    budget = [0]
    protocol = None
    result: Any = None
    held, checked = 0, 0  # objects created (never decreased: a bound on what the walk can hold)
    for op, arg, pos in pickletools.genops(payload):
        name = op.name
        held += 1
        if held - checked >= 4096:  # every object, counted in strides: the check is a function call
            check_count(held, _BYTES_PER_OBJECT, "VPR-Bench ground truth (the objects its pickle builds)")
            checked = held
        if protocol is None:
            if name != "PROTO" or not 2 <= arg <= 5:
                raise _Refused("not a pickle of protocol 2 to 5")
            protocol = arg
            continue
        if name == "FRAME":
            continue
        if name == "STOP":
            if len(stack) != 1 or marks:
                raise _Refused("pickle ends with an unbalanced stack")
            result = stack.pop()
            break
        if name == "MARK":
            if len(marks) >= _MAX_DEPTH:
                raise _Refused("nested too deeply")
            marks.append(len(stack))
        elif name in _PUSH_NONE:
            stack.append(None)
        elif name in ("NEWTRUE", "NEWFALSE"):
            stack.append(name == "NEWTRUE")
        elif name in _INTS:
            if isinstance(arg, bool) or not isinstance(arg, int) or abs(arg) >= 2**63:
                raise _Refused("an integer outside int64")
            stack.append(arg)
        elif name == "LONG4":
            raise _Refused("an integer outside int64")
        elif name in _STRS:
            stack.append(arg)
        elif name in _BYTES_OPS:
            stack.append(bytes(arg))
        elif name == "EMPTY_TUPLE":
            stack.append(())
        elif name in ("TUPLE1", "TUPLE2", "TUPLE3"):
            n = int(name[-1])
            if len(stack) - (marks[-1] if marks else 0) < n:
                raise _Refused("stack underflow")
            items = tuple(stack[-n:])
            del stack[-n:]
            stack.append(items)
        elif name in ("TUPLE", "LIST", "APPENDS"):
            if not marks:
                raise _Refused("missing MARK")
            start = marks.pop()
            items = stack[start:]
            del stack[start:]
            if name == "TUPLE":
                stack.append(tuple(items))
            elif name == "LIST":
                stack.append(items)
            else:
                if not stack or not isinstance(stack[-1], list):
                    raise _Refused("APPENDS to something other than a list")
                stack[-1].extend(items)
        elif name == "EMPTY_LIST":
            stack.append([])
        elif name == "APPEND":
            if len(stack) < 2 or not isinstance(stack[-2], list):
                raise _Refused("APPEND to something other than a list")
            stack[-2].append(stack.pop())
        elif name in ("GLOBAL", "STACK_GLOBAL"):
            if name == "GLOBAL":
                module, _, attr = arg.partition(" ")
            else:
                if len(stack) < 2 or not all(isinstance(s, str) for s in stack[-2:]):
                    raise _Refused("STACK_GLOBAL without a module and a name")
                module, attr = stack[-2], stack[-1]
                del stack[-2:]
            stack.append(_Name(module, attr))
        elif name == "REDUCE":
            if len(stack) < 2:
                raise _Refused("stack underflow")
            args = stack.pop()
            stack.append(_reduce(stack.pop(), args, budget))
        elif name == "BUILD":
            if len(stack) < 2:
                raise _Refused("stack underflow")
            state = stack.pop()
            target = stack[-1]
            if isinstance(target, _DType):
                target.build(state)
            elif isinstance(target, _Array):
                target.build(state, budget)
            else:
                raise _Refused(f"BUILD of a {type(target).__name__}")
        elif name in ("PUT", "BINPUT", "LONG_BINPUT", "MEMOIZE"):
            if not stack:
                raise _Refused("stack underflow")
            memo[len(memo) if name == "MEMOIZE" else int(arg)] = stack[-1]
        elif name in ("GET", "BINGET", "LONG_BINGET"):
            if int(arg) not in memo:
                raise _Refused(f"memo key {arg} used before it was set")
            stack.append(memo[int(arg)])
        elif name == "POP":
            if not stack:
                raise _Refused("stack underflow")
            stack.pop()
        else:
            raise _Refused(f"refused pickle opcode {name}")
        if marks and marks[-1] > len(stack):
            raise _Refused("MARK below the stack")
    else:
        raise _Refused("pickle has no STOP")
    return _object_items(result, budget)


def _object_items(result: Any, budget: list[int]) -> tuple[tuple[int, ...], list[np.ndarray]]:
    value = result.value if isinstance(result, _Array) else None
    if not (isinstance(value, tuple) and value[0] == "object"):
        raise _Refused("the pickle does not hold an object array")
    _, shape, _fortran, data = value  # numpy lists object items in C order even for Fortran arrays
    # Count first: one list in the memo referenced a million times is a million lists' worth.
    _spend(budget, sum(_length(x) for x in data))
    items = [_item(x) for x in data]
    return shape, items


def _length(x: Any) -> int:
    if isinstance(x, _Array) and isinstance(x.value, np.ndarray):
        return len(x.value)
    return len(x) if isinstance(x, list) else 1


def _item(x: Any) -> np.ndarray:
    if isinstance(x, _Array):
        x = x.value
    if isinstance(x, bool):
        raise _Refused("found a boolean where place indices were expected")
    if isinstance(x, int):
        return np.array([x], dtype=np.int64)
    if isinstance(x, np.ndarray):
        return x
    if isinstance(x, list):
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in x):
            raise _Refused("found a list holding something other than integers")
        return np.array(x, dtype=np.int64)
    kind = "an object array" if isinstance(x, tuple) and x and x[0] == "object" else f"a {type(x).__name__}"
    raise _Refused(f"found {kind} where place indices were expected")

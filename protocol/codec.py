"""The wire codec: msgpack with numpy arrays carried as raw bytes, bounded when decoding.

Why msgpack and not pickle: a server must be able to read a payload from anyone without
running their code, and a client in another language must be able to write one. Why arrays
as an extension type and not lists of floats: observations and renders are large and must
round-trip bit for bit (dtype, shape and every byte), which a float list cannot promise.

Extension types (the data of each is itself a msgpack array ``[dtype, shape, data]``):

* ``EXT_NDARRAY`` (1): a ``numpy.ndarray``. ``dtype`` is numpy's type string with its byte
  order (``"<f4"``, ``"|u1"``, ``"|b1"``); ``shape`` a list of non-negative ints (``[]`` for
  0-d); ``data`` the C-order bytes, exactly ``prod(shape) * itemsize`` long.
* ``EXT_SCALAR`` (2): a numpy scalar (``np.float32(1.5)``), same layout with ``shape`` ``[]``;
  decodes to the numpy scalar, so types survive the trip as well as values.

Only boolean, integer, unsigned, float and complex dtypes are accepted; object, string,
structured and datetime arrays are refused both ways.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import msgpack
import numpy as np

from neuronsmae.protocol.errors import MalformedMessageError, MessageTooLargeError

EXT_NDARRAY = 1
EXT_SCALAR = 2
ALLOWED_KINDS = frozenset("biufc")
"""numpy dtype kinds that may cross the wire: bool, int, uint, float, complex."""
MAX_NDIM = 32
MAX_DTYPE_LEN = 16
PACK_BUFFER = 16 << 10
"""Bytes a packer starts with (it grows as needed). msgpack's default, 256 KiB, costs more
to allocate than a step's whole message takes to pack."""


_DTYPES: dict[str, np.dtype] = {}
"""Wire dtype strings already vetted (a few at most: a payload's arrays repeat them)."""


def _dtype_of(text: Any) -> np.dtype:
    """Parse and vet a wire dtype string; refuse anything that is not plain numbers."""
    known = _DTYPES.get(text) if type(text) is str else None
    if known is not None:
        return known
    if not isinstance(text, str) or not 0 < len(text) <= MAX_DTYPE_LEN:
        raise MalformedMessageError(f"array dtype must be a short string, got {text!r}")
    try:
        dtype = np.dtype(text)
    except (TypeError, ValueError) as exc:
        raise MalformedMessageError(f"unknown array dtype {text!r}") from exc
    if dtype.kind not in ALLOWED_KINDS or dtype.fields is not None or dtype.subdtype:
        raise MalformedMessageError(f"array dtype {text!r} is not a plain numeric type")
    if len(_DTYPES) < 64:  # numpy spells a dtype in finitely many ways; stay small anyway
        _DTYPES[text] = dtype
    return dtype


_PREFIXES: dict[tuple[str, tuple[int, ...]], bytes] = {}
"""Packed ``[dtype, shape, <bin header>`` of the layouts already encoded: a step's arrays
repeat a few layouts, so their payload is one lookup and one concatenation."""
_HEADERS: dict[bytes, tuple[np.dtype, tuple[int, ...], int]] = {}
"""The same prefixes, decoding side: prefix bytes -> (dtype, shape, data bytes), all vetted."""
_PREFIX_LENGTHS: list[int] = []
"""Distinct lengths of the prefixes in ``_HEADERS`` (a handful)."""
MAX_LAYOUTS = 64
"""Most layouts each cache holds; a full cache is emptied (the layouts in use refill it)."""


def _prefix(dtype_text: str, shape: tuple[int, ...], nbytes: int) -> bytes:
    """The msgpack bytes of ``[dtype_text, shape, data]`` up to the data itself."""
    packed = msgpack.packb([dtype_text, list(shape), b""], use_bin_type=True)
    if nbytes < 1 << 8:
        bin_header = b"\xc4" + nbytes.to_bytes(1, "big")
    elif nbytes < 1 << 16:
        bin_header = b"\xc5" + nbytes.to_bytes(2, "big")
    else:
        bin_header = b"\xc6" + nbytes.to_bytes(4, "big")
    return packed[:-2] + bin_header  # the empty bin's header (c4 00) is replaced


def _array_payload(array: np.ndarray) -> bytes:
    dtype = array.dtype
    key = (dtype.str, array.shape)
    prefix = _PREFIXES.get(key)
    if prefix is None:
        if dtype.kind not in ALLOWED_KINDS or dtype.fields is not None:
            raise MalformedMessageError(f"cannot encode an array of dtype {dtype}")
        prefix = _prefix(dtype.str, array.shape, array.nbytes)
        if len(_PREFIXES) >= MAX_LAYOUTS:
            _PREFIXES.clear()  # the layouts in use come back at once
        _PREFIXES[key] = prefix
    return prefix + array.tobytes()


def _default(obj: Any) -> Any:
    """msgpack's hook for everything it does not pack natively (strict_types is on)."""
    if isinstance(obj, np.ndarray):
        return msgpack.ExtType(EXT_NDARRAY, _array_payload(obj))
    if isinstance(obj, np.generic):
        return msgpack.ExtType(EXT_SCALAR, _array_payload(np.asarray(obj)))
    if isinstance(obj, tuple):
        return list(obj)
    if isinstance(obj, Mapping):
        return dict(obj)
    for base in (bool, int, float, str, bytes):  # subclasses such as IntEnum
        if isinstance(obj, base):
            return base(obj)
    raise MalformedMessageError(f"cannot encode a {type(obj).__name__}")


def encode(obj: Any) -> bytes:
    """Pack ``obj`` (None, bool, int, float, str, bytes, lists, tuples, dicts, numpy arrays
    and scalars) into msgpack bytes; raise ``MalformedMessageError`` for anything else."""
    try:
        packer = msgpack.Packer(
            default=_default, use_bin_type=True, strict_types=True, buf_size=PACK_BUFFER
        )
        return packer.pack(obj)
    except MalformedMessageError:
        raise
    except (TypeError, ValueError, OverflowError) as exc:
        raise MalformedMessageError(f"cannot encode message: {exc}") from exc


def _unpack_array(data: bytes) -> np.ndarray:
    """Decode one array extension, checking every field before trusting the length.

    A payload that starts with the prefix of a layout already vetted (and is exactly as
    long as that layout needs) is read at once; any other is parsed field by field."""
    size = len(data)
    for length in _PREFIX_LENGTHS:
        known = _HEADERS.get(data[:length])
        if known is not None:
            dtype, shape, nbytes = known
            if size - length == nbytes:
                return np.frombuffer(data, dtype=dtype, offset=length).reshape(shape).copy()
    array = _parse_array(data)
    prefix = _prefix(array.dtype.str, array.shape, array.nbytes)
    if data.startswith(prefix):  # spelled as this codec spells it (the parse saw the rest)
        if len(_HEADERS) >= MAX_LAYOUTS:
            _HEADERS.clear()
            _PREFIX_LENGTHS.clear()
        _HEADERS[prefix] = (array.dtype, array.shape, array.nbytes)
        if len(prefix) not in _PREFIX_LENGTHS:
            _PREFIX_LENGTHS.append(len(prefix))
    return array


def _parse_array(data: bytes) -> np.ndarray:
    """Decode one array extension field by field."""
    try:
        fields = msgpack.unpackb(data, raw=False, use_list=True, max_array_len=MAX_NDIM + 3)
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        raise MalformedMessageError(f"bad array header: {exc}") from exc
    if not isinstance(fields, list) or len(fields) != 3:
        raise MalformedMessageError("array extension must be [dtype, shape, data]")
    dtype_text, shape, raw = fields
    dtype = _dtype_of(dtype_text)
    if not isinstance(shape, list) or len(shape) > MAX_NDIM:
        raise MalformedMessageError(f"array shape must be a list of at most {MAX_NDIM} ints")
    count = 1
    for n in shape:
        if type(n) is not int or n < 0:
            raise MalformedMessageError(f"array shape must hold non-negative ints, got {shape!r}")
        count *= n
    if type(raw) is not bytes or count * dtype.itemsize != len(raw):
        raise MalformedMessageError(
            f"array data must be {count} × {dtype.itemsize} bytes for shape {shape}"
        )
    # A copy, so callers get a writable array that does not pin the message buffer.
    return np.frombuffer(raw, dtype=dtype).reshape(shape).copy()


def _ext_hook(code: int, data: bytes) -> Any:
    if code == EXT_NDARRAY:
        return _unpack_array(data)
    if code == EXT_SCALAR:
        array = _unpack_array(data)
        if array.ndim != 0:
            raise MalformedMessageError("a scalar extension must have shape []")
        return array[()]
    raise MalformedMessageError(f"unknown msgpack extension type {code}")


def decode(data: bytes | bytearray | memoryview, *, max_bytes: int) -> Any:
    """Unpack one msgpack object of at most ``max_bytes`` bytes.

    Every length msgpack could allocate for (buffer, str, bin, array, map, ext) is capped by
    ``max_bytes``, so a hostile length prefix cannot make the decoder reserve memory the
    payload does not contain. Raises ``MessageTooLargeError`` or ``MalformedMessageError``.
    """
    size = len(data)
    if size > max_bytes:
        raise MessageTooLargeError(f"message of {size} bytes exceeds the limit of {max_bytes}")
    if size == 0:
        raise MalformedMessageError("empty message")
    unpacker = msgpack.Unpacker(
        raw=False,
        use_list=True,
        strict_map_key=False,
        ext_hook=_ext_hook,
        max_buffer_size=max_bytes,
        max_str_len=max_bytes,
        max_bin_len=max_bytes,
        max_array_len=max_bytes,
        max_map_len=max_bytes // 2,
        max_ext_len=max_bytes,
    )
    try:
        unpacker.feed(data)
        obj = unpacker.unpack()
        extra = unpacker.tell() != size
    except MalformedMessageError:
        raise
    except msgpack.OutOfData as exc:
        raise MalformedMessageError("truncated message") from exc
    except (ValueError, TypeError, msgpack.UnpackException, RecursionError) as exc:
        raise MalformedMessageError(f"undecodable message: {type(exc).__name__}: {exc}") from exc
    if extra:
        raise MalformedMessageError("trailing bytes after the message")
    return obj

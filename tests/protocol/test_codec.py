"""The codec and the messages: exact round trips, bounded decoding, typed refusals."""

from __future__ import annotations

import contextlib

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from neuronsmae.protocol import codec
from neuronsmae.protocol.codec import EXT_NDARRAY, EXT_SCALAR, PACK_BUFFER, decode, encode
from neuronsmae.protocol.errors import (
    ERRORS,
    InvalidActionError,
    MalformedMessageError,
    MessageTooLargeError,
    NeuronsMAEError,
    VersionMismatchError,
)
from neuronsmae.protocol.messages import (
    MAX_REQUEST_BYTES,
    MESSAGES,
    PROTOCOL_VERSION,
    Close,
    Configure,
    Contexts,
    ErrorReply,
    Get,
    OkReply,
    Ping,
    Render,
    Reset,
    Step,
    VGet,
    VReset,
    VStep,
    decode_reply,
    decode_request,
    encode_reply,
    encode_request,
    reply_in_version,
)

LIMIT = 1 << 16


def same(a: object, b: object) -> bool:
    """Equal in type, dtype, shape and every byte (so -0.0 ≠ 0.0 and NaN == NaN)."""
    if isinstance(a, (np.ndarray, np.generic)):
        return (
            type(a) is type(b)
            and a.dtype == b.dtype  # type: ignore[union-attr]
            and a.shape == b.shape  # type: ignore[union-attr]
            and a.tobytes() == b.tobytes()  # type: ignore[union-attr]
        )
    if isinstance(a, (list, tuple)):
        return isinstance(b, list) and len(a) == len(b) and all(map(same, a, b))
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, float):
        return type(b) is float and np.float64(a).tobytes() == np.float64(b).tobytes()
    return type(a) is type(b) and a == b


# ---- arrays ----------------------------------------------------------------------------

DTYPES = ["<f4", "<f8", ">f8", "<i8", "<i4", "|i1", "|u1", "<u2", "|b1", "<c8", "<f2"]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", [(), (0,), (3,), (2, 3), (0, 4), (2, 1, 3), (1,) * 5])
def test_array_round_trip(dtype: str, shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(0)
    array = np.asarray(rng.standard_normal(shape) * 100).astype(dtype)
    back = decode(encode(array), max_bytes=LIMIT)
    assert same(array, back)
    assert back.flags.writeable


def test_arrays_larger_than_the_first_pack_buffer() -> None:
    big = np.arange(3 * PACK_BUFFER, dtype=np.float64).reshape(3, -1)
    value = {"a": big, "b": [big[0], b"x" * PACK_BUFFER]}
    assert same(value, decode(encode(value), max_bytes=64 * PACK_BUFFER))


def test_dtype_spellings_are_remembered_only_when_valid_and_few() -> None:
    sizes = {"i": (1, 2, 4, 8), "u": (1, 2, 4, 8), "f": (2, 4, 8)}
    spellings = [f"{o}{k}{n}" for o in "<>=|" for k, ns in sizes.items() for n in ns]
    for text in spellings:
        dtype = np.dtype(text)
        payload = _ext(EXT_NDARRAY, [text, [1], b"\0" * dtype.itemsize])
        assert decode(payload, max_bytes=LIMIT).dtype == dtype
    assert len(codec._DTYPES) <= 64
    for bad in ("|O", "<U4", "nonsense"):
        with pytest.raises(MalformedMessageError):
            decode(_ext(EXT_NDARRAY, [bad, [1], b"\0" * 4]), max_bytes=LIMIT)
        assert bad not in codec._DTYPES


def test_array_layouts_are_remembered_without_changing_the_wire() -> None:
    """Arrays of a layout seen before are packed and read through a remembered prefix: the
    bytes are exactly the field-by-field ``[dtype, shape, data]`` extension, a payload that
    only starts like a known layout is still checked field by field, and the caches stay
    small whatever shapes arrive."""
    array = np.arange(12, dtype=np.float32).reshape(3, 4)
    for _ in range(2):  # the first time fills the caches, the second uses them
        payload = encode(array)
        assert payload == _ext(EXT_NDARRAY, ["<f4", [3, 4], array.tobytes()])
        assert same(array, decode(payload, max_bytes=LIMIT))
    assert ("<f4", (3, 4)) in codec._PREFIXES
    data = array.tobytes()
    for body in (data + b"\0", data[:-1], data):  # a known prefix, the wrong amount of data
        ext = msgpack.packb(["<f4", [3, 4], body], use_bin_type=True)
        with pytest.raises(MalformedMessageError):
            decode(msgpack.packb(msgpack.ExtType(EXT_NDARRAY, ext + b"\0")), max_bytes=LIMIT)
        if body is not data:
            with pytest.raises(MalformedMessageError):
                decode(msgpack.packb(msgpack.ExtType(EXT_NDARRAY, ext)), max_bytes=LIMIT)
    for n in range(2 * codec.MAX_LAYOUTS):
        assert same(np.zeros(n, np.uint8), decode(encode(np.zeros(n, np.uint8)), max_bytes=LIMIT))
    assert len(codec._PREFIXES) <= codec.MAX_LAYOUTS
    assert len(codec._HEADERS) <= codec.MAX_LAYOUTS


def test_non_contiguous_and_special_values() -> None:
    base = np.arange(24, dtype=np.float32).reshape(4, 6)
    for array in (base.T, base[::2, 1::3], np.array([np.nan, -0.0, np.inf, -np.inf])):
        assert same(np.ascontiguousarray(array), decode(encode(array), max_bytes=LIMIT))


@pytest.mark.parametrize(
    "scalar", [np.float32(1.5), np.float64(-0.0), np.int64(-7), np.uint8(255), np.bool_(True)]
)
def test_numpy_scalars_keep_their_type(scalar: np.generic) -> None:
    assert same(scalar, decode(encode(scalar), max_bytes=LIMIT))


def test_nested_structures_and_tuples() -> None:
    value = {"obs": [np.zeros(3, np.float32)], "info": {"t": 3, "winner": None, "x": (1, 2.5)}}
    back = decode(encode(value), max_bytes=LIMIT)
    assert same({**value, "info": {**value["info"], "x": [1, 2.5]}}, back)


@pytest.mark.parametrize("bad", [np.array([object()]), np.array(["a"]), {1, 2}, object()])
def test_unencodable_values_are_refused(bad: object) -> None:
    with pytest.raises(MalformedMessageError):
        encode(bad)


def _ext(code: int, fields: list[object]) -> bytes:
    return msgpack.packb(msgpack.ExtType(code, msgpack.packb(fields, use_bin_type=True)))


@pytest.mark.parametrize(
    "payload",
    [
        _ext(EXT_NDARRAY, ["|O", [1], b"\0" * 8]),  # object dtype
        _ext(EXT_NDARRAY, ["<U4", [1], b"\0" * 16]),  # strings
        _ext(EXT_NDARRAY, ["f4,i4", [1], b"\0" * 8]),  # structured
        _ext(EXT_NDARRAY, ["nonsense", [1], b"\0"]),
        _ext(EXT_NDARRAY, [3, [1], b"\0"]),
        _ext(EXT_NDARRAY, ["<f4", [3], b"\0" * 8]),  # wrong byte count
        _ext(EXT_NDARRAY, ["<f4", [-1], b""]),
        _ext(EXT_NDARRAY, ["<f4", [True], b"\0" * 4]),
        _ext(EXT_NDARRAY, ["<f4", [1] * 40, b"\0" * 4]),
        _ext(EXT_NDARRAY, ["<f4", 4, b"\0" * 16]),
        _ext(EXT_NDARRAY, ["<f4", [1]]),
        _ext(EXT_SCALAR, ["<f4", [2], b"\0" * 8]),
        _ext(99, ["<f4", [1], b"\0" * 4]),
        msgpack.packb(msgpack.ExtType(EXT_NDARRAY, b"\xc1")),
    ],
)
def test_bad_arrays_are_refused(payload: bytes) -> None:
    with pytest.raises(MalformedMessageError):
        decode(payload, max_bytes=LIMIT)


# ---- bounded decoding ------------------------------------------------------------------


def test_size_limit() -> None:
    data = encode(b"x" * 2000)
    assert decode(data, max_bytes=len(data)) == b"x" * 2000
    with pytest.raises(MessageTooLargeError):
        decode(data, max_bytes=len(data) - 1)


@pytest.mark.parametrize(
    "payload",
    [
        b"\xdd\xff\xff\xff\xff",  # array32 claiming 4 billion items
        b"\xdf\xff\xff\xff\xff",  # map32 claiming 4 billion pairs
        b"\xdb\xff\xff\xff\xff",  # str32 claiming 4 GiB
        b"\xc6\xff\xff\xff\xff",  # bin32 claiming 4 GiB
        b"\xc9\xff\xff\xff\xff\x01",  # ext32 claiming 4 GiB
        b"\x91" * 5000 + b"\x00",  # nesting deeper than the decoder's stack
        b"",
        b"\xc1",  # never-used byte
        b"\x92\x01",  # truncated
        b"\x01\x02",  # trailing bytes
        b"\xa2\xff\xfe",  # invalid UTF-8
        msgpack.packb({(1, 2): 3}),  # unhashable key
    ],
)
def test_hostile_lengths_and_garbage_are_refused(payload: bytes) -> None:
    with pytest.raises(MalformedMessageError):
        decode(payload, max_bytes=10_000)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=512))
def test_random_bytes_decode_or_fail_typed(data: bytes) -> None:
    with contextlib.suppress(MalformedMessageError, MessageTooLargeError):
        decode(data, max_bytes=256)


scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**64 - 1),
    st.floats(allow_nan=False),
    st.text(max_size=20),
    st.binary(max_size=20),
)
arrays = hnp.arrays(
    dtype=st.sampled_from(DTYPES),
    shape=hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=4),
)
values = st.recursive(
    st.one_of(scalars, arrays),
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=20,
)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(values)
def test_random_structures_round_trip(value: object) -> None:
    assert same(value, decode(encode(value), max_bytes=1 << 20))


# ---- messages --------------------------------------------------------------------------

REQUESTS = [
    Configure(),
    Configure(seed=7, options={"action_space": "continuous", "n_blue": 3, "lidar": True}),
    Reset(),
    Reset(contexts={"Friction_coeff": 0.3, "level": "hard"}, seed=12),
    Step(actions=[1, 2]),
    Step(actions=[[0.5, -0.5, 0.1, 3.0], [0.0, 0.0, 0.0, 2.0]]),
    Step(actions=np.array([3, 4], dtype=np.int64)),
    *(Get(what=w) for w in ("obs", "state", "avail_actions", "env_info")),
    Contexts(),
    Render(),
    Ping(),
    Close(),
    Configure(seed=3, options={}, arenas=8),
    VReset(),
    VReset(contexts={"level": "hard"}, seeds=[1, None, 3]),
    VReset(contexts=[{"coef": 0.5}, None], seeds=None),
    VStep(actions=np.zeros((4, 2), np.int64)),
    VStep(actions=[[1, 2], [3, 4]], seeds=[None, 9], contexts=[None, {"VK1": 0.1}]),
    VStep(actions=[[1, 2], [3, 4]], active=[True, False]),
    *(VGet(what=w) for w in ("obs", "state", "avail_actions", "env_info")),
]


def test_every_message_type_is_covered() -> None:
    assert {type(r) for r in REQUESTS} == set(MESSAGES.values())


@pytest.mark.parametrize("body", REQUESTS, ids=lambda r: type(r).__name__)
def test_request_round_trip(body: object) -> None:
    request = decode_request(encode_request(body, session="abc"))  # type: ignore[arg-type]
    assert request.session == "abc"
    assert type(request.body) is type(body)
    for name, value in vars(body).items():
        assert same(value, getattr(request.body, name))


@pytest.mark.parametrize(
    "reply",
    [
        OkReply(None),
        OkReply([[np.ones(3, np.float32)], [0.5, -0.0], True, {"winner": "blue"}]),
        OkReply(np.zeros((4, 5, 3), np.uint8)),
        OkReply([np.ones(2)], {"state": np.ones(4), "avail_actions": [np.ones(3, np.int8)]}),
        *(ErrorReply(code, f"message for {code}") for code in ERRORS),
    ],
)
def test_reply_round_trip(reply: object) -> None:
    back = decode_reply(encode_reply(reply))  # type: ignore[arg-type]
    assert type(back) is type(reply) and same(vars(reply), vars(back))


def _raw(**fields: object) -> bytes:
    return msgpack.packb({"v": PROTOCOL_VERSION, "session": "s", **fields}, use_bin_type=True)


@pytest.mark.parametrize(
    "payload",
    [
        msgpack.packb([1, 2, 3]),
        msgpack.packb("step"),
        msgpack.packb({"type": "ping"}),  # no version
        _raw(type="teleport"),
        _raw(type=None),
        _raw(type="step"),  # missing actions
        _raw(type="step", actions="up"),
        _raw(type="step", actions={"a": 1}),
        _raw(type="step", actions=[1], extra=1),
        _raw(type="get", what="secrets"),
        _raw(type="reset", seed="7"),
        _raw(type="reset", seed=-1),
        _raw(type="reset", seed=True),
        _raw(type="reset", contexts=[1, 2]),
        _raw(type="configure", options={1: 2}),
        _raw(type="ping", session=5),
        msgpack.packb({"v": 1, "type": "ping", "session": "x" * 200}),
        msgpack.packb({"v": 2, "type": "ping"}),  # the envelope's session is required
        msgpack.packb({"v": 2, "type": "configure"}),
        _raw(type="configure", session=""),  # ownership is by session id: not anonymous
        _raw(type="configure", arenas=0),
        _raw(type="configure", arenas=65),
        _raw(type="configure", arenas=2.0),
        _raw(type="vreset", seeds=5),
        _raw(type="vreset", seeds=[1, -1]),
        _raw(type="vreset", contexts=[{"coef": 1}, 3]),
        _raw(type="vreset", contexts="hard"),
        _raw(type="vstep"),
        _raw(type="vstep", actions=[[0, 0]], active=[1]),
        _raw(type="vstep", actions=[[0, 0]], contexts={"level": 1}),
        _raw(type="vstep", actions=[[0, 0]], seeds=[True]),
        _raw(type="vget", what="render"),
    ],
)
def test_malformed_requests(payload: bytes) -> None:
    with pytest.raises(MalformedMessageError):
        decode_request(payload)


@pytest.mark.parametrize("version", [0, 3, 99, "1", 1.0, True, None])
def test_version_mismatch_names_both_versions(version: object) -> None:
    with pytest.raises(VersionMismatchError, match=rf"{version!r}.*{PROTOCOL_VERSION}"):
        decode_request(msgpack.packb({"v": version, "type": "ping", "session": "s"}))


@pytest.mark.parametrize(
    "fields",
    [{"type": "vstep", "actions": [[0, 0]]}, {"type": "vget", "what": "obs"}, {"type": "vreset"}],
)
def test_vector_messages_need_version_2(fields: dict[str, object]) -> None:
    with pytest.raises(VersionMismatchError, match="version 2"):
        decode_request(msgpack.packb({"v": 1, "session": "s", **fields}))


def test_version_1_requests_are_still_answered() -> None:
    wire = {"v": 1, "type": "step", "session": "s", "actions": [1]}
    request = decode_request(msgpack.packb(wire))
    assert isinstance(request.body, Step) and request.body.actions == [1]
    assert request.version == 1
    assert decode_request(encode_request(Ping())).version == PROTOCOL_VERSION


def test_a_reply_speaks_its_requests_version() -> None:
    """protocol/README.md: version-1 ``configure`` and ``ping`` replies carry ``version: 1``
    and none of version 2's fields; other replies are the same in both versions."""
    ping = {"version": 2, "server": "s", "owned": False, "time_scale": 0.0, "arenas": 1, "pid": 7}
    assert reply_in_version(Ping, ping, 1) == {
        "version": 1,
        "server": "s",
        "owned": False,
        "time_scale": 0.0,
    }
    configured = {"version": 2, "server": "s", "rebuilt": True, "arenas": 1}
    assert reply_in_version(Configure, configured, 1) == {
        "version": 1,
        "server": "s",
        "rebuilt": True,
    }
    assert reply_in_version(Ping, ping, 2) is ping
    assert reply_in_version(Get, {"version": 9}, 1) == {"version": 9}  # an env_info map: as is


def test_oversized_request() -> None:
    with pytest.raises(MessageTooLargeError):
        decode_request(encode_request(Step(actions=[b"x" * MAX_REQUEST_BYTES])))


@pytest.mark.parametrize("payload", [b"", msgpack.packb([]), msgpack.packb({"ok": "yes"})])
def test_malformed_replies(payload: bytes) -> None:
    with pytest.raises(MalformedMessageError):
        decode_reply(payload)


plain_values = st.recursive(
    scalars,
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(), inner, max_size=3),
)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.dictionaries(
        st.sampled_from(
            ["v", "type", "session", "seed", "options", "contexts", "actions", "what", "junk"]
        ),
        st.one_of(plain_values, st.sampled_from([*MESSAGES, PROTOCOL_VERSION])),
        max_size=6,
    )
)
def test_random_request_maps_decode_or_fail_typed(wire: dict[str, object]) -> None:
    try:
        decode_request(encode(wire))
    except NeuronsMAEError as exc:
        assert type(exc) in (MalformedMessageError, VersionMismatchError, MessageTooLargeError)


def test_errors_keep_their_type_across_the_wire() -> None:
    from neuronsmae.protocol.errors import error_from_code

    reply = decode_reply(encode_reply(ErrorReply.from_exception(InvalidActionError("bad"))))
    assert isinstance(reply, ErrorReply)
    exc = error_from_code(reply.code, reply.message)
    assert type(exc) is InvalidActionError and isinstance(exc, ValueError)

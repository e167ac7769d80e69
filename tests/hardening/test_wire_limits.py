"""The wire decoder is bounded, and nothing on the wire is ever unpickled.

In-process (no server): the decoder is the same code the server runs on every payload, so a
payload it refuses here never reaches an arena there.
"""

from __future__ import annotations

import ast
import pickle
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import pytest

from neuronsmae.protocol.codec import decode
from neuronsmae.protocol.errors import MalformedMessageError, MessageTooLargeError
from neuronsmae.protocol.messages import (
    MAX_REQUEST_BYTES,
    PROTOCOL_VERSION,
    ErrorReply,
    decode_reply,
    decode_request,
)
from neuronsmae.server.serving.service import ArenaService

REPO = Path(__file__).resolve().parents[2]
WIRE_PACKAGES = ("protocol", "server", "client")
"""Every package whose code reads bytes from the network."""
QUICK_S = 0.05
"""A refused hostile payload costs the server at most this much CPU (seconds).

Bounds here are on the decoding thread's CPU time (``time.thread_time``), not wall time: the
machines are shared, and a wall-clock bound fails whenever another job takes the core, which
says nothing about the decoder. CPU time is what an attacker's payload costs the server."""


def _step(actions: Any) -> bytes:
    wire = {"v": PROTOCOL_VERSION, "type": "step", "session": "s", "actions": actions}
    return msgpack.packb(wire, use_bin_type=True)


def _ext(dtype: str, shape: list[Any], data: bytes) -> msgpack.ExtType:
    return msgpack.ExtType(1, msgpack.packb([dtype, shape, data], use_bin_type=True))


class _Boom:
    def __reduce__(self) -> tuple[Callable[..., Any], tuple[str]]:
        return (print, ("unpickled!",))


HOSTILE: dict[str, tuple[bytes, type[Exception]]] = {
    "deep-arrays": (b"\x91" * (MAX_REQUEST_BYTES - 1) + b"\xc0", MalformedMessageError),
    "deep-maps": (b"\x81\xa1a" * 300_000 + b"\xc0", MalformedMessageError),
    "array32-lies": (b"\xdd\xff\xff\xff\xff" + b"\xc0" * 8, MalformedMessageError),
    "map32-lies": (b"\xdf\xff\xff\xff\xff" + b"\xc0" * 8, MalformedMessageError),
    "bin32-lies": (b"\xc6\xff\xff\xff\xff" + b"\x00" * 8, MalformedMessageError),
    "str32-lies": (b"\xdb\xff\xff\xff\xff" + b"a" * 8, MalformedMessageError),
    "ext32-lies": (b"\xc9\xff\xff\xff\xff\x01" + b"a" * 8, MalformedMessageError),
    "over-1MiB": (b"\x00" * (MAX_REQUEST_BYTES + 1), MessageTooLargeError),
    "over-1MiB-valid": (_step([1000] * (MAX_REQUEST_BYTES // 2)), MessageTooLargeError),
    "ext-shape-2^80": (_step(_ext("<f8", [2**40, 2**40], b"")), MalformedMessageError),
    "ext-40-dims": (_step(_ext("|u1", [1] * 40, b"\x00")), MalformedMessageError),
    "ext-object-dtype": (_step(_ext("|O", [1], b"\x00" * 8)), MalformedMessageError),
    "ext-in-ext": (_step(msgpack.ExtType(1, msgpack.packb(_ext("|u1", [1], b"\x00")))),
                   MalformedMessageError),
    "pickle-dict": (pickle.dumps({"v": 1, "type": "ping", "session": "s"}),
                    MalformedMessageError),
    "pickle-reduce": (pickle.dumps(_Boom()), MalformedMessageError),
    "pickle-reduce-v0": (pickle.dumps(_Boom(), protocol=0), MalformedMessageError),
    "invalid-utf8-str": (b"\x83\xa1v\x01\xa4type\xa4ping\xa7session\xa2\xff\xfe",
                         MalformedMessageError),
}  # fmt: skip


@pytest.mark.parametrize("case", HOSTILE, ids=list(HOSTILE))
def test_hostile_payload_is_refused_quickly(case: str, capsys: pytest.CaptureFixture) -> None:
    payload, error = HOSTILE[case]

    def refuse() -> None:
        with pytest.raises(error):
            decode_request(payload)

    assert _cpu(refuse) < QUICK_S  # the best of a few tries: a loaded machine adds noise
    assert "unpickled" not in capsys.readouterr().out


BULKY = {
    "1M-nils": _step([None] * (MAX_REQUEST_BYTES - 100)),
    "80k-tiny-arrays": _step([_ext("|u1", [1], b"\x00")] * (MAX_REQUEST_BYTES // 13 - 10)),
    "650k-nested-lists": _step([[[[[[]]]]]] * (MAX_REQUEST_BYTES // 8)),
}


def _cpu(work: Callable[[], Any], repeats: int = 3) -> float:
    """The least thread CPU time ``work`` took over ``repeats`` runs."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.thread_time()
        work()
        best = min(best, time.thread_time() - t0)
    return best


@pytest.mark.slow  # seconds by design: each payload is decoded 6 times at the size limit
@pytest.mark.parametrize("case", BULKY, ids=list(BULKY))
def test_worst_case_payloads_under_the_limit_cost_what_msgpack_itself_costs(case: str) -> None:
    """The most objects 1 MiB can describe decode at a small multiple of what msgpack alone
    takes for the same bytes (these are then refused by the arena's own checks, as wrong
    actions): the bounds and checks add no work that grows faster than the payload. Measured
    as a ratio in one thread, back to back, so a slow or loaded machine slows both sides."""
    payload = BULKY[case]
    assert len(payload) <= MAX_REQUEST_BYTES
    ours = _cpu(lambda: decode_request(payload))
    plain = _cpu(lambda: msgpack.unpackb(payload, strict_map_key=False))
    assert ours <= 10.0 * plain + 0.01, (ours, plain)


@pytest.mark.parametrize(
    ("prefix", "refusal"),
    [(b"\xdd", "exceeds max_array_len"), (b"\xdf", "exceeds max_map_len"),
     (b"\xc6", "truncated"), (b"\xdb", "truncated"), (b"\xc9", "exceeds max_ext_len")],
)  # fmt: skip
def test_every_length_the_decoder_may_allocate_is_capped(prefix: bytes, refusal: str) -> None:
    """A declared length of 4 Gi (array, map, bin, str, ext) in a 13-byte message is never
    believed: arrays, maps and extensions are refused by the cap on their length, bin and
    str because the bytes never come; nothing near the declared size is allocated."""
    tracemalloc.start()
    try:
        with pytest.raises(MalformedMessageError, match=refusal):
            decode(prefix + (2**32 - 1).to_bytes(4, "big") + b"\x00" * 8, max_bytes=32)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20


def test_pickle_payload_gets_a_typed_refusal_from_the_service() -> None:
    class NoArena:  # the service must refuse before ever needing an arena
        def __init__(self, **kwargs: Any) -> None:
            raise AssertionError("the arena was built for a pickle payload")

    service = ArenaService(NoArena)  # type: ignore[arg-type]
    for payload in (pickle.dumps(_Boom()), pickle.dumps({"v": 1, "type": "ping"})):
        reply = decode_reply(service.handle(payload))
        assert isinstance(reply, ErrorReply) and reply.code == "malformed_message"


# ---- no pickle on the wire ---------------------------------------------------------------

UNSAFE_MODULES = {"pickle", "cPickle", "_pickle", "dill", "cloudpickle", "marshal", "shelve",
                  "jsonpickle", "joblib"}  # fmt: skip
UNSAFE_CALLS = {"load", "loads"}
"""On a module in UNSAFE_MODULES or on ``torch``/``numpy`` (``np.load(allow_pickle=True)``)."""


def _unsafe_uses(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name.split(".")[0] for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            names = [(node.module or "").split(".")[0]]
        else:
            names = []
        found += [f"{path.name}:{node.lineno} imports {n}" for n in names if n in UNSAFE_MODULES]
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "torch":
            found += [f"{path.name}:{node.lineno} imports torch's {a.name}"
                      for a in node.names if a.name in UNSAFE_CALLS]  # fmt: skip
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            owner = ast.unparse(node.func.value)  # torch, torch.serialization, pickle, ...
            if node.func.attr in UNSAFE_CALLS and owner.split(".")[0] in {*UNSAFE_MODULES, "torch"}:
                found.append(f"{path.name}:{node.lineno} calls {owner}.{node.func.attr}")
            for kw in node.keywords:
                if kw.arg == "allow_pickle" and not (
                    isinstance(kw.value, ast.Constant) and kw.value.value is False
                ):
                    found.append(f"{path.name}:{node.lineno} passes allow_pickle")
    return found


def test_no_pickle_anywhere_on_the_wire() -> None:
    files = [f for pkg in WIRE_PACKAGES for f in sorted((REPO / pkg).rglob("*.py"))]
    assert len(files) > 20, "the wire packages were not found"
    offenders = [use for f in files for use in _unsafe_uses(f)]
    assert offenders == []


def test_the_scanner_would_notice_pickle(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text(
        "import pickle\nfrom dill import loads\nimport numpy as np\nimport torch\n"
        "pickle.loads(b'')\nnp.load('x', allow_pickle=True)\ntorch.load('x')\n"
        "from torch import load\ntorch.serialization.load('x')\n"
    )
    assert len(_unsafe_uses(bad)) == 7

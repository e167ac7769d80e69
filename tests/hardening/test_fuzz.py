"""A short run of bench/fuzz.py's generator against a live server (the long run is the
bench: ``python -m bench.fuzz`` sends 20,000 + 5,000 payloads)."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from bench.fuzz import Raw, broken, fire, fresh_episode_matches, owner_phase, payloads
from neuronsmae.protocol.messages import Close, encode_request

from .conftest import Server

TIMEOUT = 5.0


@pytest.fixture(scope="module", params=[1, 3], ids=["one-arena", "vector"])
def raw(
    start_server: Callable[..., Server], request: pytest.FixtureRequest
) -> Iterator[tuple[Server, Raw, int]]:
    server = start_server("--arenas", str(request.param))
    client = Raw(server.port)
    yield server, client, request.param
    client.close()


def test_the_generator_is_deterministic_and_mixed() -> None:
    first, again = list(payloads(3, 300)), list(payloads(3, 300))
    assert first == again and len(set(first)) > 250
    assert any(p.startswith(b"\x80") for p in first)  # pickles are among them


def test_every_fuzzed_payload_gets_a_typed_reply(raw: tuple[Server, Raw, int]) -> None:
    server, client, arenas = raw
    result = fire(client, payloads(seed=7, count=1500, arenas=arenas), TIMEOUT)
    assert result["sent"] == 1500
    assert broken(result["codes"]) == 0, result["codes"]
    assert result["max_latency_s"] < TIMEOUT
    assert server.proc.poll() is None


def test_fuzzing_beside_an_owner_leaves_its_episodes_alone(raw: tuple[Server, Raw, int]) -> None:
    server, client, arenas = raw
    client.send(encode_request(Close(), "fuzz"), 1.0)  # in case the fuzz claimed the server
    result = owner_phase(server.port, client, seed=8, count=400, timeout=TIMEOUT, arenas=arenas)
    assert result["owner_intact"], result
    assert broken(result["codes"]) == 0, result["codes"]


def test_after_fuzzing_new_episodes_equal_fresh_arenas(raw: tuple[Server, Raw, int]) -> None:
    server, client, arenas = raw
    client.send(encode_request(Close(), "fuzz"), 1.0)
    assert fresh_episode_matches(server.port, decisions=20, arenas=arenas)

"""Episode recordings: the file format, its reader and writer, and the per-decision hash.

A recording holds everything needed to play an episode again exactly, and a fingerprint
of every decision to prove that it was: ``neuronsmae-replay`` re-simulates it in an
in-process arena and names the first decision whose hash differs. It lives in the protocol
package because both sides use it: the client's ``Recorder`` writes recordings of any
arena (local or remote), the server's replay tool reads them.

Format (version 1): gzip-compressed JSON lines, one object per line, UTF-8, strict JSON
(no NaN). JSON rather than msgpack so that ``zcat FILE | head`` shows what happened; never
pickle, because a recording must be safe to open whoever wrote it.

* Line 1, the header::

    {"format": "neuronsmae-episode", "version": 1,
     "arena_seed": 7, "options": {...}, "seed": 1000000003, "contexts": {...} | null,
     "meta": {...}, "hash": "<hash after reset>"}

  ``Arena(seed=arena_seed, **options).reset(contexts, seed=seed)`` starts the episode again.
  ``meta`` is free-form (who played: bot levels, checkpoint, ...).
* Lines 2…, one per decision ``k = 1, 2, ...``::

    {"k": 1, "actions": [...], "rewards": [...], "done": false, "hash": "..."}

  the last one also has ``"winner"``. A file whose last decision is not ``done`` is an
  episode cut short (the program stopped); it still replays as far as it goes.

The hash of a decision (:func:`decision_hash`) is SHA-256 over the global state after it
(``get_state()`` as little-endian float64), its rewards (float64) and ``done``. The state
is the same whichever side of the wire it is read on, so a recording made through ``RM``
replays in process.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import re
import zlib
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from neuronsmae.protocol.errors import InvalidOptionError, RecordingFormatError

FORMAT = "neuronsmae-episode"
VERSION = 1
SUFFIX = ".jsonl.gz"
"""File name ending of recordings."""
_HASH_TAG = b"neuronsmae-decision-v1\0"
"""Prefix of every hashed message, so the hash can change meaning only with the format."""


def decision_hash(state: Any, rewards: Sequence[float] = (), done: bool = False) -> str:
    """Hex SHA-256 of one decision's outcome: global state, rewards and ``done``.

    Values are widened to float64 before hashing (exact for the float32 state), so the hash
    does not depend on the dtype a transport chose; lengths are hashed too, so a state and
    rewards cannot trade values and collide.
    """
    s = np.ascontiguousarray(np.asarray(state, dtype="<f8").reshape(-1))
    r = np.ascontiguousarray(np.asarray(list(rewards), dtype="<f8").reshape(-1))
    h = hashlib.sha256(_HASH_TAG)
    h.update(np.array([s.size, r.size], dtype="<u8").tobytes())
    h.update(s.tobytes())
    h.update(r.tobytes())
    h.update(b"\1" if done else b"\0")
    return h.hexdigest()


def to_plain(value: Any) -> Any:
    """``value`` as JSON-ready Python: numpy scalars and arrays become numbers and lists."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, np.ndarray):
        return to_plain(value.tolist())
    if isinstance(value, Mapping):
        return {str(k): to_plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    raise RecordingFormatError(f"cannot record a {type(value).__name__}: {value!r}")


@dataclass
class Decision:
    """One decision: what the agents did and the fingerprint of what followed."""

    actions: list[Any]
    rewards: list[float]
    done: bool
    hash: str
    winner: str | None = None

    @classmethod
    def after(
        cls,
        actions: Sequence[Any],
        state: Any,
        rewards: Sequence[float],
        done: bool,
        info: Mapping[str, Any],
    ) -> Decision:
        """The record of a decision just played: its actions, what ``step`` returned and
        ``get_state()`` read straight after it."""
        plain_rewards = [float(r) for r in rewards]
        return cls(
            actions=to_plain(list(actions)),
            rewards=plain_rewards,
            done=bool(done),
            hash=decision_hash(state, plain_rewards, bool(done)),
            winner=info.get("winner") if done else None,
        )


@dataclass
class Recording:
    """One episode, as read from or written to a file."""

    arena_seed: int
    options: dict[str, Any]
    seed: int
    contexts: dict[str, Any] | None
    reset_hash: str
    decisions: list[Decision] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        """Whether the episode was played to its end."""
        return bool(self.decisions) and self.decisions[-1].done

    @property
    def winner(self) -> str | None:
        """The winner of a complete episode, else None."""
        return self.decisions[-1].winner if self.complete else None

    def header(self) -> dict[str, Any]:
        """The first line of the file."""
        return {
            "format": FORMAT,
            "version": VERSION,
            "arena_seed": self.arena_seed,
            "options": to_plain(self.options),
            "seed": self.seed,
            "contexts": to_plain(self.contexts),
            "meta": to_plain(self.meta),
            "hash": self.reset_hash,
        }


def _line(obj: Mapping[str, Any]) -> bytes:
    try:
        text = json.dumps(obj, allow_nan=False, separators=(",", ":"))
    except ValueError as exc:  # NaN or infinity: not strict JSON
        raise RecordingFormatError(f"cannot record a non-finite number: {exc}") from exc
    return text.encode() + b"\n"


def _decision_line(k: int, d: Decision) -> dict[str, Any]:
    row: dict[str, Any] = {
        "k": k,
        "actions": to_plain(d.actions),
        "rewards": to_plain(d.rewards),
        "done": bool(d.done),
        "hash": d.hash,
    }
    if d.done:
        row["winner"] = d.winner
    return row


def recording_name(prefix: str, n: int, seed: int) -> str:
    """The file name of the ``n``-th recording of a series, of an episode reset with
    ``seed``: ``{prefix}{n:05d}_s{seed}.jsonl.gz``."""
    return f"{prefix}{n:05d}_s{seed}{SUFFIX}"


def existing_recordings(folder: str | Path, prefix: str) -> list[Path]:
    """The files in ``folder`` named as :func:`recording_name` names a series with
    ``prefix``, sorted; empty when the folder does not exist."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    name = re.compile(re.escape(prefix) + r"\d{5,}_s\d+" + re.escape(SUFFIX))
    return sorted(p for p in folder.iterdir() if name.fullmatch(p.name))


class RecordingWriter:
    """Writes one recording line by line as the episode is played.

    Each line is flushed through gzip as it is written (a sync flush), so a run that dies
    mid-episode leaves a readable file of the decisions played so far. A file that exists
    is never overwritten (``InvalidOptionError``): recordings are data.
    """

    def __init__(self, path: str | Path, recording: Recording) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._raw: IO[bytes] = self.path.open("xb")
        except FileExistsError as exc:
            raise InvalidOptionError(
                f"{self.path} exists: a recording is never overwritten; record into another "
                "folder (or with another prefix)"
            ) from exc
        self._gz = gzip.GzipFile(fileobj=self._raw, mode="wb", mtime=0)
        self._k = 0
        self._write(recording.header())
        for d in recording.decisions:
            self.decision(d)

    def _write(self, obj: Mapping[str, Any]) -> None:
        self._gz.write(_line(obj))
        self._gz.flush(zlib.Z_SYNC_FLUSH)

    def decision(self, d: Decision) -> None:
        """Append the next decision."""
        self._k += 1
        self._write(_decision_line(self._k, d))

    @property
    def closed(self) -> bool:
        return self._raw.closed

    def close(self) -> None:
        """Finish the gzip stream and the file; safe to call twice."""
        if not self._raw.closed:
            self._gz.close()
            self._raw.close()


def write_recording(path: str | Path, recording: Recording) -> Path:
    """Write a whole recording at once; return its path."""
    writer = RecordingWriter(path, recording)
    writer.close()
    return writer.path


def _lines(path: Path, tail: dict[str, int] | None = None) -> Iterator[tuple[int, dict[str, Any]]]:
    """(line number, object) of each line; a truncated gzip tail ends the file quietly,
    noted in ``tail`` (see :func:`_tolerant`)."""
    try:
        with gzip.open(path, "rb") as f:
            for n, raw in enumerate(_tolerant(f, {} if tail is None else tail), start=1):
                try:
                    obj = json.loads(raw)
                except json.JSONDecodeError as exc:
                    raise RecordingFormatError(f"{path}:{n}: not JSON: {exc}") from exc
                if not isinstance(obj, dict):
                    raise RecordingFormatError(f"{path}:{n}: expected a JSON object")
                yield n, obj
    except gzip.BadGzipFile as exc:
        raise RecordingFormatError(f"{path}: not a gzip file: {exc}") from exc


def _tolerant(f: IO[bytes], tail: dict[str, int]) -> Iterator[bytes]:
    """Complete lines of a gzip stream, stopping at a tail cut short by a crash. ``tail``
    gets ``cut`` = 1 when the gzip stream ended early and ``partial`` = the bytes of an
    unfinished last line, so a reader can tell a truncated file from an empty one."""
    try:
        for raw in f:
            if raw.endswith(b"\n"):
                yield raw
            else:
                tail["partial"] = len(raw)
    except EOFError:
        tail["cut"] = 1
        return


def _get(obj: Mapping[str, Any], key: str, kind: type | tuple[type, ...], where: str) -> Any:
    if key not in obj or not isinstance(obj[key], kind):
        raise RecordingFormatError(f"{where}: missing or mistyped field {key!r}")
    return obj[key]


def read_recording(path: str | Path) -> Recording:
    """Read a recording; raise ``RecordingFormatError`` saying where it is wrong."""
    path = Path(path)
    if not path.is_file():
        raise RecordingFormatError(f"{path}: no such recording")
    tail: dict[str, int] = {}
    lines = _lines(path, tail)
    first = next(lines, None)
    if first is None:
        if tail:
            raise RecordingFormatError(
                f"{path}: truncated or corrupt: "
                + ("the gzip stream ends early" if tail.get("cut") else "")
                + (" and " if len(tail) == 2 else "")
                + (
                    f"the header line is cut short ({tail['partial']} bytes, no newline)"
                    if "partial" in tail
                    else ""
                )
                + "; no complete header line"
            )
        raise RecordingFormatError(f"{path}: empty file")
    _, head = first
    if head.get("format") != FORMAT:
        raise RecordingFormatError(f"{path}: not a {FORMAT} recording")
    if head.get("version") != VERSION:
        raise RecordingFormatError(
            f"{path}: format version {head.get('version')!r}; this NeuronsMAE reads {VERSION}"
        )
    where = f"{path}:1"
    rec = Recording(
        arena_seed=_get(head, "arena_seed", int, where),
        options=_get(head, "options", dict, where),
        seed=_get(head, "seed", int, where),
        contexts=_get(head, "contexts", (dict, type(None)), where),
        reset_hash=_get(head, "hash", str, where),
        meta=head.get("meta") or {},
    )
    for n, obj in lines:
        where = f"{path}:{n}"
        if _get(obj, "k", int, where) != len(rec.decisions) + 1:
            raise RecordingFormatError(f"{where}: decision {obj['k']} out of order")
        if rec.complete:
            raise RecordingFormatError(f"{where}: a decision after the episode ended")
        rec.decisions.append(
            Decision(
                actions=_get(obj, "actions", list, where),
                rewards=_get(obj, "rewards", list, where),
                done=_get(obj, "done", bool, where),
                hash=_get(obj, "hash", str, where),
                winner=obj.get("winner"),
            )
        )
    return rec

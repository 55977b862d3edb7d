"""The run's key: a keyed MAC on the messages that steer a run (feedback, positions, actions, heartbeats),
HMAC-SHA256 truncated to 128 bits, and the seal (run nonce, sender's incarnation) that ties a keyed message to
one run and one life of its sender. Why and what is refused: msgs_spec/README.md, "The run's key".
"""

from __future__ import annotations

import hashlib
import os
import secrets
import stat
import struct
import tempfile
from functools import lru_cache
from pathlib import Path

__all__ = ["KEY_BYTES", "MAC_WORDS", "SEAL_WORDS", "WORLD", "KeyFileError", "RunKey", "new_key_file", "write_key_file",
           "read_key", "mac_words", "mac_of", "primed", "new_run", "secret_of"]

KEY_BYTES = 32
MAC_WORDS = 4  # 128 bits as four 32-bit words, appended to the array's data
SEAL_WORDS = 3  # the run nonce's two 32-bit words (high, low), then the sender's incarnation, before the MAC
WORLD = 0  # the sender id of the world's messages in a RunKey (agents are 1..N)
_DOMAIN = b"cq_ros/mac/2\0"  # a MAC made for anything else (or by the unsealed form before) never matches
_WORDS = struct.Struct(f">{MAC_WORDS}I")  # the digest's first MAC_WORDS big-endian 32-bit words


class KeyFileError(ValueError):
    """The key file is missing, unreadable, malformed or readable by others: one line naming it."""


def new_key_file(directory: str | os.PathLike | None = None) -> Path:
    """A fresh random key in a new file readable by this user only (mode 0600, as mkstemp creates it)."""
    fd, path = tempfile.mkstemp(prefix="cq_ros_key_", suffix=".hex", dir=directory)
    _write_key(fd)
    return Path(path)


def write_key_file(path: str | os.PathLike) -> Path:
    """A fresh random key in the new file `path` (mode 0600; an existing file is never overwritten), for a
    system kept in a parameters file (`cq-ros key --out FILE`); KeyFileError naming the file otherwise."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as e:
        raise KeyFileError(f"cannot make key file {os.fspath(path)!r}: {e.strerror}") from None
    _write_key(fd)
    return Path(path)


def _write_key(fd: int) -> None:
    with os.fdopen(fd, "w") as f:
        f.write(secrets.token_hex(KEY_BYTES) + "\n")


def read_key(path: str | os.PathLike) -> bytes:
    """The key in `path`: hex, one line, in a file no one but its owner may read or write."""
    name = f"parameter key_file: {os.fspath(path)!r}"
    try:
        mode = os.stat(path).st_mode
        text = Path(path).read_text(encoding="ascii").strip()
    except OSError as e:
        raise KeyFileError(f"parameter key_file: cannot read {os.fspath(path)!r}: {e.strerror}") from None
    except UnicodeDecodeError as e:
        raise KeyFileError(f"{name} is not a key file: byte {e.start} is not text (0x{e.object[e.start]:02x}); a "
                           "key file is one line of hex, as `cq-ros key` makes it") from None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise KeyFileError(f"{name} is accessible to others (mode {stat.S_IMODE(mode):04o}); chmod 600 it")
    try:
        key = bytes.fromhex(text)
    except ValueError:
        key = b""
    if len(key) < 16:
        raise KeyFileError(f"{name} must hold at least 16 bytes as hex")
    return key


def mac_words(key: "bytes | RunKey", label: str, packed: bytes) -> tuple[int, ...]:
    """The MAC of one array payload (its layout label and its packed values) as MAC_WORDS unsigned 32-bit words,
    under a bare key or a RunKey's secret."""
    return mac_of(key.hashes(label) if type(key) is RunKey else primed(key, label), packed)


def mac_of(hashes: tuple, packed: bytes) -> tuple[int, ...]:
    """mac_words from the (inner, outer) hashes primed for its key and label (RunKey.hashes), copied."""
    inner, outer = hashes[0].copy(), hashes[1].copy()
    inner.update(packed)
    outer.update(inner.digest())
    return _WORDS.unpack_from(outer.digest())


@lru_cache(maxsize=64)
def primed(key: bytes, label: str) -> tuple:
    """HMAC-SHA256 under `key` (RFC 2104) as its inner hash, having read the domain and `label`, and its outer
    hash: both copied for each message, so the key's setup and the prefix are hashed once per layout. The two
    hashlib copies cost half of what copying an hmac.HMAC does (1.6 against 2.8 us a MAC here); the digest is
    the same (tests/test_msgs_spec.py checks it against hmac)."""
    block = hashlib.sha256().block_size
    padded = (hashlib.sha256(key).digest() if len(key) > block else key).ljust(block, b"\0")
    inner = hashlib.sha256(bytes(b ^ 0x36 for b in padded))
    inner.update(_DOMAIN + label.encode() + b"\0")
    return inner, hashlib.sha256(bytes(b ^ 0x5C for b in padded))


def new_run() -> int:
    """A fresh run nonce: 63 random bits (it travels as a ROS integer parameter, int64), never 0 (the run a bare
    key seals with, and the parameter's "none given")."""
    return secrets.randbits(63) or 1


class RunKey:
    """The run's key as one node holds it. Sealing: the `run` nonce (None: not learnt yet) and this node's own
    `incarnation`. Receiving: the incarnation held for each sender (WORLD, or an agent id), bound by the first
    valid message of each. The codec reads and binds it; one per node, from one executor thread."""

    __slots__ = ("secret", "run", "incarnation", "held", "retired", "replaced", "_hashes", "derived")

    def __init__(self, secret: bytes, run: int | None = None, incarnation: int | None = None):
        self.secret = secret
        self.run = run
        self.incarnation = secrets.randbits(32) if incarnation is None else incarnation
        self.held: dict[int, int] = {}  # sender -> the incarnation it speaks with now
        self.retired: dict[int, set[int]] = {}  # sender -> incarnations it spoke with before (an agent restarted)
        self.replaced = 0  # agent incarnations replaced by a newer one (restarts, or a twin)
        self._hashes: dict[str, tuple] = {}  # label -> (inner, outer) HMAC hashes, as primed
        # What the codec derives from the binding (the seal each sender's messages carry) to check it without
        # reading the binding again per message (msgs_spec.arrays): dropped whenever the binding changes.
        self.derived: dict = {}

    def __repr__(self) -> str:  # never the secret
        run = "unbound" if self.run is None else f"{self.run:016x}"
        return f"RunKey(run={run}, incarnation={self.incarnation:08x})"

    def seal(self, code: str, incarnation: int | None = None) -> bytes:
        """The seal's words (run high, run low, an incarnation: this node's own unless given) as an array of struct
        code `code` holds its values ('i' as unsigned ints, or 'd')."""
        if self.run is None:  # an agent acts only on a sealed feedback, which binds the run first
            raise ValueError("no run nonce yet: a node seals only after it knows its run")
        words = self.run >> 32, self.run & 0xFFFFFFFF, self.incarnation if incarnation is None else incarnation
        return struct.pack(f"<{SEAL_WORDS}{'I' if code == 'i' else 'd'}", *words)

    def hashes(self, label: str) -> tuple:
        """(inner, outer) HMAC-SHA256 hashes primed for `label`, to be copied per message."""
        h = self._hashes.get(label)
        if h is None:
            h = self._hashes[label] = primed(self.secret, label)
        return h

    def refusal(self, run: int, incarnation: int, sender: int) -> tuple[str, str] | None:
        """(kind, detail) when a sealed message (its MAC checked) is not of this run, or not from the
        incarnation of `sender` this receiver holds; None when it may be accepted."""
        if self.run is not None and run != self.run:
            return "other_run", f"run {run:016x}, this receiver's run is {self.run:016x}"
        held = self.held.get(sender)
        if held is None or held == incarnation:
            return None
        if sender == WORLD:
            return "other_incarnation", (f"world incarnation {incarnation:08x}, this receiver is bound to "
                                         f"{held:08x} (a world restarted, or a second one)")
        if incarnation in self.retired.get(sender, ()):
            return "other_incarnation", f"agent {sender} incarnation {incarnation:08x}, replaced by {held:08x}"
        return None

    def accept(self, run: int, incarnation: int, sender: int) -> None:
        """Bind to what an accepted message carried (refusal() was None for it)."""
        if self.run is None:
            self.run = run
            self.derived.clear()
        held = self.held.get(sender)
        if held != incarnation:
            self.derived.clear()
            if held is not None:
                self.retired.setdefault(sender, set()).add(held)
                self.replaced += 1
            self.held[sender] = incarnation


def secret_of(key: "bytes | RunKey | None") -> bytes | None:
    """The secret of a key given either way (a bare key, or a RunKey)."""
    return key.secret if type(key) is RunKey else key

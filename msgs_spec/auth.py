"""The run's key: a keyed MAC on the messages that steer a run (feedback, positions, actions, heartbeats).

The pip Fast DDS has no DDS-Security and rclpy 7.1.6's message info names no publisher, so a node cannot
tell who wrote a message. With a per-run key, shared through a file only the user can read, it can tell
who could not have: the codec appends HMAC-SHA256 (truncated to 128 bits, as RFC 2104 allows) over the
payload's layout label and values, and a receiver holding the key drops any message without a matching
one (`WireError("unauthenticated")`). The key authenticates; it does not hide (docs/ros.md, "Limits").
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

__all__ = ["KEY_BYTES", "MAC_WORDS", "KeyFileError", "new_key_file", "write_key_file", "read_key", "mac_words"]

KEY_BYTES = 32
MAC_WORDS = 4  # 128 bits as four 32-bit words, appended to the array's data
_DOMAIN = b"cq_ros/mac/1\0"  # a MAC made for anything else never matches
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
    try:
        mode = os.stat(path).st_mode
        text = Path(path).read_text().strip()
    except OSError as e:
        raise KeyFileError(f"parameter key_file: cannot read {os.fspath(path)!r}: {e.strerror}") from None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise KeyFileError(f"parameter key_file: {os.fspath(path)!r} is accessible to others (mode "
                        f"{stat.S_IMODE(mode):04o}); chmod 600 it")
    try:
        key = bytes.fromhex(text)
    except ValueError:
        key = b""
    if len(key) < 16:
        raise KeyFileError(f"parameter key_file: {os.fspath(path)!r} must hold at least 16 bytes as hex")
    return key


def mac_words(key: bytes, label: str, packed: bytes) -> tuple[int, ...]:
    """The MAC of one array payload (its layout label and its packed values) as MAC_WORDS unsigned 32-bit words."""
    inner, outer = _keyed(key, label)
    inner, outer = inner.copy(), outer.copy()
    inner.update(packed)
    outer.update(inner.digest())
    return _WORDS.unpack_from(outer.digest())


@lru_cache(maxsize=64)
def _keyed(key: bytes, label: str) -> tuple:
    """HMAC-SHA256 under `key` (RFC 2104) as its inner hash, having read the domain and `label`, and its outer
    hash: both copied for each message, so the key's setup and the prefix are hashed once per layout. The two
    hashlib copies cost half of what copying an hmac.HMAC does (1.6 against 2.8 us a MAC here); the digest is
    the same (tests/test_msgs_spec.py checks it against hmac)."""
    block = hashlib.sha256().block_size
    padded = (hashlib.sha256(key).digest() if len(key) > block else key).ljust(block, b"\0")
    inner = hashlib.sha256(bytes(b ^ 0x36 for b in padded))
    inner.update(_DOMAIN + label.encode() + b"\0")
    return inner, hashlib.sha256(bytes(b ^ 0x5C for b in padded))

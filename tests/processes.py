"""Test helper: the live processes of a test, found by a token in their command line (no orphan may
outlive its test)."""

import os
from pathlib import Path


def alive_with(token: str) -> list[str]:
    """Command lines of live processes that mention `token` (a namespace or path unique to one test)."""
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:  # gone meanwhile
            continue
        if token in cmdline and int(pid) != os.getpid():
            found.append(f"{pid}: {cmdline}")
    return found

"""A launch's own key (msgs_spec.auth), made fresh for each launch that is given none: a writer outside the
launch cannot steer the run, and no end of the launch, kill -9 of the launcher included, leaves the key behind
in a file.
"""

from __future__ import annotations

import os
import secrets
import tempfile
from pathlib import Path

from msgs_spec import new_key_file
from msgs_spec.auth import KEY_BYTES

__all__ = ["RunKeyFile"]


class RunKeyFile:
    """The launch's own key in a file without a name (O_TMPFILE where the kernel has it, else unlinked at once),
    mode 0600, which the nodes open through the launcher's descriptor (`path`, /proc/<pid>/fd/<n>) while the
    launcher lives: they read it once, at their start, and a node outlives the launcher by nothing (its
    PR_SET_PDEATHSIG). Without /proc, a named file (msgs_spec.auth.new_key_file) removed by `close`."""

    def __init__(self) -> None:
        self.named: Path | None = None
        self.file = tempfile.TemporaryFile("w+")
        self.file.write(secrets.token_hex(KEY_BYTES) + "\n")
        self.file.flush()
        self.path = Path(f"/proc/{os.getpid()}/fd/{self.file.fileno()}")
        if not self.path.exists():
            self.file.close()
            self.named = self.path = new_key_file()

    def close(self) -> None:
        self.file.close()
        if self.named is not None:
            self.named.unlink(missing_ok=True)

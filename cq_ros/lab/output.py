"""Where a command writes what it makes: checked before any work starts, so a folder that cannot take it (read
only, full, not a folder, not ours) is one line at once instead of a traceback after the work is done.

`check_folder` makes the folder if needed and writes a small probe file there (a read-only or full file
system refuses exactly that, whatever the permission bits say, and root passes every permission check);
`check_parent` does the same for the folder a file (or a bag directory) goes in. Both raise `OutputError` (a
ValueError: the CLI prints it as one line and exits 2) naming the folder and the operating system's reason, and
leave no folder they made. `made_by` says which folder making one would make, for a command that removes it when it
fails before its results (`removed_if_failing`).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

__all__ = ["OutputError", "PROBE_BYTES", "check_folder", "probe_folder", "check_parent", "os_reason", "made_by",
           "removed_if_failing"]

PROBE_BYTES = 4096  # one page: a file system with less free than this cannot take a result anyway


class OutputError(ValueError):
    """An output folder that cannot take the results; the message is one line naming it and why."""


def os_reason(e: OSError) -> str:
    """An OSError as one line: '[Errno 28] No space left on device' (the path is the caller's to name)."""
    return f"[Errno {e.errno}] {e.strerror}" if e.errno is not None else str(e)


def check_folder(folder: str | os.PathLike, what: str = "output folder") -> Path:
    """`folder`, made if missing (with its parents), once a probe file could be written there; OutputError if not."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{what} {folder}: is a file, not a folder")
    with removed_if_failing(folder):
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise OutputError(f"cannot make {what} {folder}: {os_reason(e)}") from None
        probe_folder(folder, what)
    return folder


def made_by(folder: str | os.PathLike) -> Path | None:
    """The outermost of `folder` and its parents that does not exist yet (what making `folder` makes), or None."""
    made = None
    for path in (Path(folder), *Path(folder).parents):
        if path.exists():
            break
        made = path
    return made


@contextmanager
def removed_if_failing(folder: str | os.PathLike, unless: Callable[[], bool] = lambda: False):
    """Removes what making `folder` made (see `made_by`, taken on entry) if the body raises, Ctrl-C included,
    unless `unless()` says it holds results by then: a command that fails before its results leaves no empty or
    half-made folder for its rerun to refuse."""
    made = made_by(folder)
    try:
        yield
    except BaseException:
        if made is not None and not unless():
            shutil.rmtree(made, ignore_errors=True)
        raise


def probe_folder(folder: str | os.PathLike, what: str = "output folder") -> None:
    """OutputError unless a file of PROBE_BYTES can be written (and synced) in the existing `folder`."""
    # By hand rather than NamedTemporaryFile: a failed write there leaves its delete to the garbage collector,
    # which then warns when the folder it made has been removed.
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".probe.")
    except OSError as e:
        raise OutputError(f"{what} {folder}: cannot write there: {os_reason(e)}") from None
    try:
        written = 0
        while written < PROBE_BYTES:  # a nearly full disk takes part, then refuses the rest
            written += os.write(fd, b"\0" * (PROBE_BYTES - written))
        os.fsync(fd)
    except OSError as e:
        raise OutputError(f"{what} {folder}: cannot write there: {os_reason(e)}") from None
    finally:
        os.close(fd)
        os.unlink(probe)


def check_parent(path: str | os.PathLike, what: str = "output") -> Path:
    """`path`, once the folder it goes in passes check_folder (a file, or a bag directory still to make)."""
    path = Path(path)
    check_folder(path.parent, f"{what} {path}: its folder")
    return path

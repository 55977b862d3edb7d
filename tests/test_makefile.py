"""`make`'s set-up checks the Python version before it makes .venv, and says in one line what to do."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.skipif(shutil.which("make") is None, reason="no make here")
@pytest.mark.parametrize("version", ["3.12.1", None])  # another Python, or none at that name
def test_setup_with_a_python_other_than_3_11_is_one_line_and_makes_no_venv(tmp_path, version):
    for name in ("Makefile", "pyproject.toml"):
        shutil.copy(ROOT / name, tmp_path / name)
    python = tmp_path / "python-other"
    if version is not None:  # a stand-in that answers as that Python would
        major, minor, _ = version.split(".")
        python.write_text(f"#!/bin/sh\n[ \"$1\" = --version ] && echo 'Python {version}' && exit 0\n"
                          f"[ \"$1\" = -c ] && exec python3 -c "
                          f"\"import sys; sys.version_info = ({major}, {minor}); $2\"\n"
                          "exit 1\n")
        python.chmod(0o755)
    # As a newcomer runs it: not inside another make (`make test` runs this test), whose level would show
    # in make's own lines (make[1]: ...).
    env = {k: v for k, v in os.environ.items() if k not in ("MAKELEVEL", "MAKEFLAGS", "MFLAGS")}
    done = subprocess.run(["make", f"PYTHON={python}", ".venv/.installed"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=60, env=env)
    assert done.returncode != 0
    said = [line for line in done.stderr.splitlines() if not line.startswith("make:")]
    assert len(said) == 1 and "make PYTHON=python3.11" in said[0], done.stderr
    assert (f"is Python {version}" if version else "is not found") in said[0]
    assert not (tmp_path / ".venv").exists()

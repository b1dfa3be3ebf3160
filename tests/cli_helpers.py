"""Running ``samfdi`` as a user would, for the tests of bad input."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: root writes into read-only folders, a user does not: as root, run without the capabilities
#: that override file permissions (util-linux setpriv)
_AS_USER = (["setpriv", "--bounding-set", "-dac_override,-dac_read_search", "--"]
            if os.geteuid() == 0 else [])


def samfdi(*args: str, cwd: Path | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    """``python -m samfdi ARGS`` in a fresh interpreter, with a user's file permissions."""
    if _AS_USER and not shutil.which(_AS_USER[0]):
        pytest.skip("running as root without setpriv: cannot test a read-only folder")
    return subprocess.run([*_AS_USER, sys.executable, "-m", "samfdi", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env={**os.environ, "PYTHONPATH": str(REPO)})


@contextmanager
def read_only_folder():
    """A folder :func:`samfdi` can read but not write."""
    folder = Path(tempfile.mkdtemp(prefix="samfdi-readonly-"))
    try:
        folder.chmod(0o555)
        yield folder
    finally:
        folder.chmod(0o755)
        shutil.rmtree(folder, ignore_errors=True)


def one_line_error(result: subprocess.CompletedProcess) -> str:
    """The error line of a refused command; fails the test unless it is exactly one line, exit 2."""
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("samfdi: error: "), result.stderr
    assert "Traceback" not in result.stderr
    return lines[0]

"""numba's cache is keyed by the project's sources: a changed callee re-compiles its callers."""

import subprocess
import sys
import textwrap
from pathlib import Path

from numba.core.registry import CPUDispatcher

import fdi.kernel
import sam.simulate
from sam import jitcache

CALLER = """
from numba import njit
from .callee import g

@njit(cache=True)
def f(x):
    return g(x)
"""
CALLEE = "from numba import njit\n\n@njit\ndef g(x):\n    return x + {}\n"
RUN = """
import sys
sys.path.insert(0, {parent!r})
if {register}:
    from sam.jitcache import register
    register(({pkg!r},))
from kernels.caller import f
print(f(1.0))
"""


def _run_twice(tmp_path: Path, register: bool) -> list[float]:
    """f(1) before and after the callee's file changes from x + 1 to x + 2, in fresh processes."""
    pkg = tmp_path / ("registered" if register else "plain") / "kernels"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "caller.py").write_text(CALLER)
    script = RUN.format(parent=str(pkg.parent), pkg=str(pkg), register=register)
    out = []
    for increment in ("1.0", "2.0"):
        (pkg / "callee.py").write_text(CALLEE.format(increment))
        done = subprocess.run([sys.executable, "-c", textwrap.dedent(script)], capture_output=True, text=True,
                              check=True)
        out.append(float(done.stdout.split()[-1]))
    return out


def test_a_changed_callee_recompiles_its_cached_caller(tmp_path):
    assert _run_twice(tmp_path, register=True) == [2.0, 3.0]


def test_numba_alone_runs_the_stale_callee(tmp_path):
    """The hazard the locator removes; if numba ever fixes it, sam/jitcache.py can go."""
    assert _run_twice(tmp_path, register=False) == [2.0, 2.0]


def test_the_projects_cached_kernels_use_the_source_tree_stamp():
    kernels = [obj for mod in (sam.simulate, fdi.kernel) for obj in vars(mod).values()
               if isinstance(obj, CPUDispatcher) and getattr(obj, "_cache", None) is not None
               and hasattr(obj._cache, "_impl")]
    assert kernels
    stamp = jitcache.tree_stamp(tuple(jitcache._PROJECT / p for p in jitcache.PACKAGES))
    for k in kernels:
        locator = k._cache._impl.locator
        assert type(locator).__name__.startswith("SourceTree"), k
        assert locator.get_source_stamp() == stamp


def test_the_stamp_sees_every_file_of_the_tree(tmp_path):
    root = tmp_path / "pkg"
    root.mkdir()
    (root / "a.py").write_text("A = 1\n")
    first = jitcache.tree_stamp.__wrapped__((root,))
    (root / "b.py").write_text("B = 2\n")
    second = jitcache.tree_stamp.__wrapped__((root,))
    (root / "a.py").write_text("A = 3\n")
    assert len({first, second, jitcache.tree_stamp.__wrapped__((root,))}) == 3

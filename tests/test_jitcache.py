"""numba's cache is keyed by the project's sources: a changed callee re-compiles its callers."""

import subprocess
import sys
import textwrap
from pathlib import Path

from numba.core.registry import CPUDispatcher

import fdi.kernel
import sam.dynamics
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


def test_the_projects_cached_kernels_are_stamped_by_what_they_import():
    kernels = [obj for mod in (sam.simulate, fdi.kernel) for obj in vars(mod).values()
               if isinstance(obj, CPUDispatcher) and getattr(obj, "_cache", None) is not None
               and hasattr(obj._cache, "_impl")]
    assert kernels
    roots = tuple((jitcache._PROJECT / p).resolve() for p in jitcache.PACKAGES)
    for k in kernels:
        locator = k._cache._impl.locator
        assert type(locator).__name__.startswith("SourceTree"), k
        own = Path(k.py_func.__code__.co_filename).resolve()
        assert locator.get_source_stamp() == jitcache.source_stamp(own, roots)
    # the filter's kernel is stamped by sam's step too, sam's kernels by nothing of fdi
    kernel_closure = jitcache.import_closure(Path(fdi.kernel.__file__).resolve(), roots)
    assert Path(sam.dynamics.__file__).resolve() in kernel_closure
    # ... and not by what sam's __init__ imports beside it: editing a reader re-compiles no kernel
    assert not {"recording.py", "scenario.py", "jitcache.py", "__init__.py"} & {f.name for f in kernel_closure}
    assert not any("fdi" in f.parts for f in jitcache.import_closure(Path(sam.simulate.__file__).resolve(), roots))


def test_the_stamp_follows_imports_and_nothing_else(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    files = {"__init__.py": "from .c import C as CC\nfrom .d import D\n", "a.py": "from .b import B\n",
             "b.py": "from pkg import CC\nB = 1\n", "c.py": "C = 2\n", "d.py": "D = 3\n"}
    for name, text in files.items():
        (pkg / name).write_text(text)
    roots = (pkg.resolve(),)

    def stamp():
        for cached in (jitcache._import_statements, jitcache._imports, jitcache.import_closure):
            cached.cache_clear()
        jitcache.source_stamp.cache_clear()
        return jitcache.source_stamp((pkg / "a.py").resolve(), roots)

    # b takes C through the package's __init__: its stamp follows c.py, not all the __init__ imports
    assert [f.name for f in jitcache.import_closure((pkg / "a.py").resolve(), roots)] == ["a.py", "b.py", "c.py"]
    first = stamp()
    (pkg / "d.py").write_text("D = 4\n")
    assert stamp() == first  # not imported by a: no re-compile
    (pkg / "c.py").write_text("C = 5\n")
    assert stamp() != first  # imported through b


def test_the_tests_own_kernels_are_stamped_by_sam_too():
    """A kernel compiled in a test file (test_model_step's Eq. (22) loop freezes the parameter
    vector's length) is re-compiled when sam changes, not only when its own file does."""
    import test_model_step

    locator = test_model_step._euler_loop._cache._impl.locator
    assert type(locator).__name__.startswith("SourceTree")
    own = Path(test_model_step.__file__).resolve()
    closure = jitcache.import_closure(own, locator.roots)
    assert Path(sam.dynamics.__file__).resolve() in closure
    assert locator.get_source_stamp() == jitcache.source_stamp(own, locator.roots)

"""Numba's on-disk cache, keyed by the sources of the whole project rather than one file.

Numba keys a cached function by the hash of its *own* file. A kernel that calls the step
function from another file (the filter in ``fdi/kernel.py`` compiles ``sam``'s step into
itself) would then run the old, frozen physics after ``sam/`` changed, with no error. Here
every cached function of the project is stamped with one hash over all the project's
package sources, so any change to any of them re-compiles every cached kernel once.

Importing this module registers the locator (``sam/__init__.py`` and the other packages with
cached kernels import it before their first ``@njit(cache=True)``). It only claims files under
its roots; other libraries' numba caches are untouched. Caches still live in each package's
``__pycache__``, next to the numba default.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path

from numba.core import caching



def _numba_class(name: str) -> type:
    return getattr(caching, name, None) or getattr(caching, "_" + name)  # underscored in older numba


# CacheImpl holds numba's list of locators: numba has no public hook for one but an env variable
CacheImpl, UserProvidedCacheLocator, InTreeCacheLocator, UserWideCacheLocator = map(
    _numba_class, ("CacheImpl", "UserProvidedCacheLocator", "InTreeCacheLocator", "UserWideCacheLocator"))

_PROJECT = Path(__file__).resolve().parent.parent
PACKAGES = ("sam", "fdi", "discrepancy", "rig")  # the packages with cached numba kernels


@lru_cache(maxsize=None)
def tree_stamp(roots: tuple[Path, ...]) -> str:
    """sha256 over every ``*.py`` under ``roots``, their paths relative to each root included."""
    digest = hashlib.sha256()
    for root in roots:
        for path in sorted(root.rglob("*.py")):
            digest.update(str(path.relative_to(root.parent)).encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def locators_for(roots: tuple[Path, ...]) -> list[type]:
    """numba's three file-backed locators (a user's NUMBA_CACHE_DIR, ``__pycache__``, the user's
    cache directory), each stamped with :func:`tree_stamp` and claiming only files under ``roots``."""

    def stamped(base: type) -> type:
        class Locator(base):
            def get_source_stamp(self):
                return tree_stamp(roots)

            @classmethod
            def from_function(cls, py_func, py_file):
                if not any(Path(py_file).resolve().is_relative_to(r) for r in roots):
                    return None  # not ours: numba's own locators decide
                return super().from_function(py_func, py_file)

        Locator.__name__ = Locator.__qualname__ = f"SourceTree{base.__name__}"
        Locator.roots = roots
        return Locator

    return [stamped(b) for b in (UserProvidedCacheLocator, InTreeCacheLocator, UserWideCacheLocator)]


def register(roots: tuple[Path, ...]) -> None:
    """Put the locators for ``roots`` before numba's own (once per set of roots)."""
    roots = tuple(Path(r).resolve() for r in roots)
    if any(getattr(c, "roots", None) == roots for c in CacheImpl._locator_classes):
        return
    CacheImpl._locator_classes = [*locators_for(roots), *CacheImpl._locator_classes]


register(tuple(_PROJECT / name for name in PACKAGES))

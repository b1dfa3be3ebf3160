"""Numba's on-disk cache, keyed by the sources a kernel imports rather than its own file alone.

Numba keys a cached function by the hash of its *own* file. A kernel that calls the step
function from another file (the filter in ``fdi/kernel.py`` compiles ``sam``'s step into
itself) would then run the old, frozen physics after ``sam/`` changed, with no error. Here a
cached function of the project is stamped with one hash over its file and every project module
that file imports, directly or through others (:func:`import_closure`; a name a package's
``__init__`` re-exports counts as the module defining it): the jitted functions it calls and the
constants it freezes all come from there. A change to any of them re-compiles it
once; a change elsewhere (a command line, a report) re-compiles nothing.

Importing this module registers the locators (``sam/__init__.py`` and the other packages with
cached kernels import it before their first ``@njit(cache=True)``). They only claim files under
their roots; other libraries' numba caches are untouched. Caches still live in each package's
``__pycache__``, next to the numba default.
"""

from __future__ import annotations

import ast
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


def _module_file(dotted: str, roots: dict[str, Path]) -> Path | None:
    """The file of module ``dotted`` if it lies under one of ``roots`` (package name -> folder)."""
    head, *rest = dotted.split(".")
    if head not in roots:
        return None
    path = roots[head].joinpath(*rest)
    for candidate in (path / "__init__.py", path.with_suffix(".py")):
        if candidate.is_file():
            return candidate
    return None


@lru_cache(maxsize=None)
def _import_statements(path: Path, roots: tuple[Path, ...]) -> tuple[tuple[str, str | None, str], ...]:
    """(module, name, bound as) of each import in ``path``, relative forms resolved: ``import a.b``
    gives ("a.b", None, "a"), ``from .m import n as k`` gives ("pkg.m", "n", "k"). Parsed once per
    process, as every kernel's closure shares most files."""
    package = list(path.relative_to(_root_of(path, {r.name: r for r in roots}).parent).with_suffix("").parts[:-1])
    found = []
    for node in ast.walk(ast.parse(path.read_bytes())):
        if isinstance(node, ast.Import):
            found += [(a.name, None, a.asname or a.name.split(".")[0]) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            found += [(base, a.name, a.asname or a.name) for a in node.names]
    return tuple(found)


def _defining_file(module: str, name: str, roots: dict[str, Path]) -> Path | None:
    """The project file whose code ``from module import name`` brings in: the submodule
    ``module.name`` if there is one; else, where ``module`` is a package whose ``__init__``
    re-exports ``name``, the module it comes from (``from sam import P`` depends on sam/params.py,
    not on everything sam's ``__init__`` imports); else ``module``'s own file."""
    sub = _module_file(f"{module}.{name}", roots)
    if sub is not None:
        return sub
    file = _module_file(module, roots)
    if file is None or file.name != "__init__.py":
        return file
    for source, source_name, bound in _import_statements(file, tuple(roots.values())):
        if bound == name and source_name is not None and source != module:
            return _defining_file(source, source_name, roots)
    return file


@lru_cache(maxsize=None)
def _imports(path: Path, roots: tuple[Path, ...]) -> frozenset[Path]:
    """The project files whose code ``path``'s imports bring in."""
    by_name = {r.name: r for r in roots}
    files = (_module_file(module, by_name) if name is None else _defining_file(module, name, by_name)
             for module, name, _ in _import_statements(path, roots))
    return frozenset(f for f in files if f is not None)


def _root_of(path: Path, roots: dict[str, Path]) -> Path:
    return next(r for r in roots.values() if path.is_relative_to(r))


@lru_cache(maxsize=None)
def import_closure(path: Path, roots: tuple[Path, ...]) -> tuple[Path, ...]:
    """``path`` and every module under ``roots`` it imports, directly or through others (sorted)."""
    seen, todo = {path}, [path]
    while todo:
        for found in _imports(todo.pop(), roots):
            if found not in seen:
                seen.add(found)
                todo.append(found)
    return tuple(sorted(seen))


@lru_cache(maxsize=None)
def source_stamp(path: Path, roots: tuple[Path, ...]) -> str:
    """sha256 over the files of :func:`import_closure`, each with its path relative to its root."""
    digest = hashlib.sha256()
    for f in import_closure(path, roots):
        digest.update(str(f.relative_to(_root_of(f, {r.name: r for r in roots}).parent)).encode())
        digest.update(f.read_bytes())
    return digest.hexdigest()


def locators_for(roots: tuple[Path, ...]) -> list[type]:
    """numba's three file-backed locators (a user's NUMBA_CACHE_DIR, ``__pycache__``, the user's
    cache directory), each stamped with :func:`source_stamp` and claiming only files under ``roots``."""

    def stamped(base: type) -> type:
        class Locator(base):
            def get_source_stamp(self):
                return source_stamp(Path(self._py_file).resolve(), roots)

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
    """Put the locators for ``roots`` (package folders) before numba's own (once per set of roots)."""
    roots = tuple(Path(r).resolve() for r in roots)
    if any(getattr(c, "roots", None) == roots for c in CacheImpl._locator_classes):
        return
    CacheImpl._locator_classes = [*locators_for(roots), *CacheImpl._locator_classes]


def register_folder(folder: str | Path) -> None:
    """Stamp the cached kernels of ``folder`` (a test suite, a user's scripts) by what they import
    from it and from the project's packages: a kernel there that calls sam's step or freezes its
    constants (the parameter vector's length) is re-compiled when they change."""
    register((Path(folder), *(_PROJECT / name for name in PACKAGES)))


register(tuple(_PROJECT / name for name in PACKAGES))

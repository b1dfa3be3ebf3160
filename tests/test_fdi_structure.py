"""The shape of fdi/: imports in one direction, small modules, and a public face whose every
function, class and configuration field is documented (as python-control's docstrings_test
checks its own). Cheap: the sources are parsed, nothing is run."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import io
import re
import tokenize
from pathlib import Path

import pytest

import fdi

FDI = Path(fdi.__file__).resolve().parent
MODULES = sorted(p.stem for p in FDI.glob("*.py"))
MAX_LINES = 600
PROJECT = ("fdi", "sam", "gsa", "discrepancy", "chunkstore", "rig", "samfdi")


def _tree(module: str) -> ast.Module:
    return ast.parse((FDI / f"{module}.py").read_text())


def _imported_modules(module: str) -> set[str]:
    """The fdi modules ``module`` imports at module level ("__init__" for the package itself)."""
    out = set()
    for node in _tree(module).body:
        if isinstance(node, ast.ImportFrom):
            absolute = node.level == 0 and (node.module or "").split(".")[0] == "fdi"
            if node.level == 1 or absolute:
                path = (node.module or "").split(".")[1 if absolute else 0:]
                if path and path[0]:
                    out.add(path[0])
                else:  # from . import x: a module, or a name of the package's face
                    out.update(a.name if a.name in MODULES else "__init__" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name.split(".")[1] if "." in a.name else "__init__"
                       for a in node.names if a.name.split(".")[0] == "fdi")
    return out - {module}


def _cycle(graph: dict) -> list | None:
    """One import cycle of ``graph`` (module -> imported modules) as a list, or None."""
    state, stack = {}, []

    def visit(m):
        state[m] = "open"
        stack.append(m)
        for n in sorted(graph.get(m, ())):
            if state.get(n) == "open":
                return stack[stack.index(n):] + [n]
            if n not in state and (found := visit(n)):
                return found
        state[m] = "done"
        stack.pop()
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_the_import_graph_of_fdi_has_no_cycle():
    graph = {m: _imported_modules(m) for m in MODULES}
    assert _cycle(graph) is None, " -> ".join(_cycle(graph))
    # the stages in one direction: the statistics know nothing of alarms or the bank, and so on
    for stage, later in (("filter", {"statistics", "alarms", "bank", "isolation", "diagnosis"}),
                         ("statistics", {"alarms", "bank", "isolation", "diagnosis"}),
                         ("alarms", {"bank", "isolation", "diagnosis"}),
                         ("bank", {"isolation", "diagnosis"}), ("isolation", {"diagnosis"})):
        assert not graph[stage] & later, (stage, graph[stage] & later)


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_no_module_is_longer_than_600_lines():
    long = {m: n for m in MODULES if (n := len((FDI / f"{m}.py").read_text().splitlines())) > MAX_LINES}
    assert not long, long


def test_no_import_of_the_project_hides_in_a_function():
    """A dependency on another module of the project is stated at the top of the module (only
    optional third-party packages, matplotlib or dask, are imported where they are used)."""
    hidden = []
    for m in MODULES:
        for fn in ast.walk(_tree(m)):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for node in ast.walk(fn):
                    names = ([node.module or ""] if isinstance(node, ast.ImportFrom) else
                             [a.name for a in node.names] if isinstance(node, ast.Import) else [])
                    if (isinstance(node, ast.ImportFrom) and node.level) or any(
                            n.split(".")[0] in PROJECT for n in names):
                        hidden.append(f"{m}.py:{node.lineno} in {fn.name}()")
    assert not hidden, hidden


# ---------------------------------------------------------------------------- the public face


def _comments(path: Path) -> dict[int, str]:
    """Line number -> the comment on that line."""
    toks = tokenize.generate_tokens(io.StringIO(path.read_text()).readline)
    return {t.start[0]: t.string for t in toks if t.type == tokenize.COMMENT}


def _documented_fields(cls) -> dict[str, bool]:
    """Each annotated field of the class -> whether a ``#:`` comment documents it (on its line,
    or on the lines right above it)."""
    path = Path(inspect.getsourcefile(cls))
    comments = _comments(path)
    lines = path.read_text().splitlines()
    node = next(n for n in ast.walk(ast.parse(path.read_text()))
                if isinstance(n, ast.ClassDef) and n.name == cls.__name__)
    out = {}
    for item in node.body:
        if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
            k = item.lineno
            ok = comments.get(k, "").startswith("#:") or comments.get(item.end_lineno, "").startswith("#:")
            j = k - 1
            while not ok and j >= 1 and lines[j - 1].strip().startswith("#"):
                ok = lines[j - 1].strip().startswith("#:")
                j -= 1
            out[item.target.id] = ok
    return out


def _classes(obj, seen: set) -> list:
    """A dataclass and, recursively, the dataclasses of its fields' default values (config groups)."""
    if obj in seen:
        return []
    seen.add(obj)
    out = [obj]
    for f in dataclasses.fields(obj):
        value = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
        if dataclasses.is_dataclass(value):
            out += _classes(type(value), seen)
    return out


def _face():
    return [(name, getattr(fdi, name)) for name in fdi.__all__]


def _words(text: str) -> set[str]:
    return set(re.findall(r"[A-Za-z_][A-Za-z_0-9]*", text or ""))


@pytest.mark.parametrize("name,obj", [(n, o) for n, o in _face() if inspect.isfunction(o)])
def test_every_function_of_the_face_documents_its_parameters(name, obj):
    doc = inspect.getdoc(obj)
    assert doc, f"fdi.{name} has no docstring"
    params = [p for p in inspect.signature(obj).parameters if p not in ("self", "cls")]
    missing = [p for p in params if p not in _words(doc)]
    assert not missing, f"fdi.{name}: parameters not in its docstring: {missing}"


@pytest.mark.parametrize("name,obj", [(n, o) for n, o in _face() if inspect.isclass(o)])
def test_every_class_of_the_face_and_each_field_is_documented(name, obj):
    assert inspect.getdoc(obj) and obj.__doc__ is not None, f"fdi.{name} has no docstring"
    for meth, fn in vars(obj).items():
        fn = fn.__func__ if isinstance(fn, (classmethod, staticmethod)) else fn
        if inspect.isfunction(fn) and not meth.startswith("_"):
            assert inspect.getdoc(fn), f"fdi.{name}.{meth} has no docstring"
    if dataclasses.is_dataclass(obj):
        for cls in _classes(obj, set()):
            undocumented = [f for f, ok in _documented_fields(cls).items() if not ok]
            assert not undocumented, f"{cls.__module__}.{cls.__name__}: fields without a #: comment: {undocumented}"


@pytest.mark.parametrize("name", [n for n, o in _face() if not (inspect.isfunction(o) or inspect.isclass(o))])
def test_every_constant_of_the_face_is_documented(name):
    """A constant of the face has a ``#:`` comment where it is defined."""
    for m in MODULES:
        path = FDI / f"{m}.py"
        for node in ast.parse(path.read_text()).body:
            targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
            if isinstance(node, (ast.Assign, ast.AnnAssign)) and any(
                    isinstance(n, ast.Name) and n.id == name for t in targets for n in ast.walk(t)):
                lines = path.read_text().splitlines()
                comments = _comments(path)
                assert comments.get(node.lineno, "").startswith("#:") or \
                    lines[node.lineno - 2].strip().startswith("#:"), f"fdi.{name} ({m}.py:{node.lineno})"
                return
    pytest.fail(f"fdi.{name}: not defined at the top of any fdi module")


def test_the_documentation_check_finds_what_is_missing():
    """The field check on a class of this file: one field documented, one not."""

    @dataclasses.dataclass
    class Probe:
        good: float = 1.0  #: s: documented
        bad: float = 2.0

    assert _documented_fields(Probe) == {"good": True, "bad": False}

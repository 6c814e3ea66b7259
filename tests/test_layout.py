"""The layout of the package: every name is imported from the module that defines it.

Read from the source (``ast``), nothing imported: every module of ``ngbet`` and of the studies
declares ``__all__`` with the names it defines; an import names the module that defines the name
(no module hands on a name it imported: a re-export), except the public API of the top-level
package ``ngbet``; no private name (``_x``) is imported from another module; the modules import
each other without a circle, imports for type checking included; the layers import downwards
only (:data:`LAYERS`); no module is much longer than 500 lines.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import ngbet
import ngbet.studies

ROOT = Path(__file__).resolve().parent.parent
#: the package the tests import (the source tree, or an install where the tests run without it) and its studies
PKG = Path(ngbet.__file__).resolve().parent
STUDIES = Path(ngbet.studies.__file__).resolve().parent
#: the public API of ``import ngbet``: gathered there from the modules that define it
PUBLIC_API = {
    "ConvergenceError",
    "Result",
    "Scene",
    "SceneError",
    "default_scene",
    "load_result",
    "simulate",
    "__version__",
    "__revision__",
}


#: written by setuptools-scm when the package is built (ignored by git): absent from a clone never built
GENERATED = "ngbet._version"


def _modules() -> dict[str, Path]:
    """Every module of the package by its dotted name; the studies are installed as ``ngbet.studies``."""
    out = {}
    for prefix, folder in (("ngbet", PKG), ("ngbet.studies", STUDIES)):
        for p in sorted(folder.rglob("*.py")):
            parts = list(p.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join([prefix, *parts])] = p
    out.pop(GENERATED, None)
    return out


MODULES = _modules()


def _target(module: str, path: Path, node: ast.ImportFrom) -> str:
    """The dotted name of the module an ``from ... import`` statement reads from."""
    if not node.level:
        return node.module or ""
    pkg = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    base = pkg[: len(pkg) - node.level + 1]
    return ".".join([*base, *([node.module] if node.module else [])])


def _top_level(tree: ast.Module) -> list[ast.stmt]:
    """The statements run at import, those under top-level ``if`` and ``try`` included."""
    out: list[ast.stmt] = []
    stack = list(tree.body)
    while stack:
        node = stack.pop(0)
        out.append(node)
        if isinstance(node, ast.If | ast.Try):
            stack += node.body + node.orelse + [s for h in getattr(node, "handlers", []) for s in h.body]
    return out


def _defined(tree: ast.Module) -> set[str]:
    """The names a module binds itself (functions, classes, assignments, plain ``import x``)."""
    names = set()
    for node in _top_level(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign | ast.AugAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
        elif isinstance(node, ast.Import):
            names |= {(a.asname or a.name).split(".")[0] for a in node.names}
    return names


def _all(tree: ast.Module) -> list[str] | None:
    for node in tree.body:
        targets = (
            node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        )
        if any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets):
            assert isinstance(node.value, ast.List | ast.Tuple), "__all__ is a literal list"
            return [e.value for e in node.value.elts if isinstance(e, ast.Constant)]
    return None


TREES = {m: ast.parse(p.read_text()) for m, p in MODULES.items()}
DEFINED = {m: _defined(t) for m, t in TREES.items()}


def _imports_from(files: dict[str, Path]):
    """(file, line, module imported from, name) of every ``from ngbet... import name``."""
    for module, path in files.items():
        tree = TREES.get(module) or ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                target = _target(module, path, node)
                if target == "ngbet" or target.startswith("ngbet."):
                    for a in node.names:
                        yield path, node.lineno, target, a.name


def _shown(path: Path) -> str:
    """A file as a message names it: relative to the clone, or to the installed package's folder."""
    for base in (ROOT, PKG.parent):
        if path.is_relative_to(base):
            return str(path.relative_to(base))
    return str(path)


def _outside_files() -> dict[str, Path]:
    """The tests, docs scripts, benchmarks and examples, which import ngbet by absolute names."""
    return {
        f"<{p.relative_to(ROOT)}>": p
        for d in ("tests", "docs", "bench", "examples")
        for p in sorted((ROOT / d).rglob("*.py"))
    }


def test_every_module_declares_what_it_defines_in_all():
    missing = [m for m, t in TREES.items() if _all(t) is None]
    assert not missing, f"modules without __all__: {missing}"
    for m, t in TREES.items():
        foreign = set(_all(t) or ()) - DEFINED[m] - (PUBLIC_API if m == "ngbet" else set())
        assert not foreign, f"{m}.__all__ lists names it does not define (a re-export): {sorted(foreign)}"


def test_every_import_names_the_module_that_defines_the_name():
    wrong = []
    for path, line, target, name in _imports_from({**MODULES, **_outside_files()}):
        if target == "ngbet" and (name in PUBLIC_API and not path.is_relative_to(PKG) or f"ngbet.{name}" in MODULES):
            continue  # the public API, for users, tests and scripts; or a subpackage
        if f"{target}.{name}" in MODULES or target == GENERATED:
            continue  # a submodule; the build's version record
        if target not in MODULES:
            wrong.append(f"{_shown(path)}:{line}: no module {target}")
        elif name not in DEFINED[target]:
            wrong.append(f"{_shown(path)}:{line}: {name} from {target}, which does not define it")
    assert not wrong, "\n".join(wrong)


def test_no_private_name_is_imported_from_another_module():
    wrong = []
    for path, line, target, name in _imports_from(MODULES):
        private = name.startswith("_") and not name.startswith("__")
        own_package = f"{target}.{name}" in MODULES  # a package's private module, from inside the package
        if private and not own_package:
            wrong.append(f"{_shown(path)}:{line}: {name} from {target}")
    assert not wrong, "\n".join(wrong)


def _edges(module: str) -> set[str]:
    """The modules of ngbet a module imports, at any depth: function-local and type-checking imports included."""
    out = set()
    path = MODULES[module]
    for node in ast.walk(TREES[module]):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            target = _target(module, path, node)
            out |= {target} | {f"{target}.{a.name}" for a in node.names}
    return {m for m in out if m in MODULES and m != module}


def test_no_import_circle():
    """A depth-first walk from every module never comes back to it; a package's ``__init__`` is left
    out (importing a module runs its package's ``__init__``, which then would close every circle)."""
    ours = [m for m, p in MODULES.items() if p.name != "__init__.py"]
    graph = {m: _edges(m) & set(ours) for m in ours}
    for start in ours:
        stack, seen = [(start, [start])], set()
        while stack:
            m, path = stack.pop()
            for n in graph[m]:
                assert n != start, "import circle: " + " -> ".join([*path, n])
                if n not in seen:
                    seen.add(n)
                    stack.append((n, [*path, n]))


#: what runs a scene or a set of them: the commands and the studies, above the runner and the figures
COMMANDS = (
    "ngbet.run",
    "ngbet.study",
    "ngbet.studies",
    "ngbet.calibration",
    "ngbet.api",
    "ngbet.cli",
    "ngbet.watch",
    "ngbet.commands",
)
#: the run folder, its writers and figures, and what runs them: the top of the import graph
OUTPUTS = ("ngbet.runner", "ngbet.run_folder", "ngbet.output", "ngbet.plot_process", "ngbet.figures", *COMMANDS)
#: what the modules of a package may not import (at any depth, type-only imports included): the
#: scene is the bottom (it knows no model), the reader of measured curves beside it; the numerics
#: are model-free (no scene, no model), and neither they nor the two models (continuum, network)
#: reach up to the runner, the run folder or the figures; the runner and the run folder's writer
#: know no command or study, and the figures none
LAYERS = {
    "ngbet.scene": ("ngbet.measured", "ngbet.numerics", "ngbet.continuum", "ngbet.discrete", *OUTPUTS),
    "ngbet.measured": ("ngbet.numerics", "ngbet.continuum", "ngbet.discrete", *OUTPUTS),
    "ngbet.numerics": ("ngbet.scene", "ngbet.continuum", "ngbet.discrete", *OUTPUTS),
    "ngbet.continuum": OUTPUTS,
    "ngbet.discrete": OUTPUTS,
    "ngbet.runner": COMMANDS,
    "ngbet.run_folder": ("ngbet.runner", "ngbet.figures", *COMMANDS),
    "ngbet.output": ("ngbet.runner", "ngbet.figures", *COMMANDS),
    "ngbet.figures": ("ngbet.runner", *COMMANDS),
}


def _inside(module: str, packages: tuple[str, ...] | str) -> bool:
    packages = (packages,) if isinstance(packages, str) else packages
    return any(module == p or module.startswith(p + ".") for p in packages)


def test_the_layers_import_downwards_only():
    wrong = [
        f"{m} imports {n}"
        for layer, banned in LAYERS.items()
        for m in MODULES
        if _inside(m, layer)
        for n in sorted(_edges(m))
        if _inside(n, banned)
    ]
    assert not wrong, "\n".join(wrong)


def test_modules_stay_small():
    """Every module holds at most 300 statements (the largest, the command line, holds 300; about 550 lines
    as ruff formats them): counted in the syntax tree, so that the formatter's line breaks do not count."""

    def statements(p: Path) -> int:
        return sum(isinstance(x, ast.stmt) for x in ast.walk(ast.parse(p.read_text())))

    big = {m: n for m, p in MODULES.items() if (n := statements(p)) > 300}
    assert not big, big


@pytest.mark.parametrize(
    "source, check, message",
    [
        (
            "from .a import helper\n__all__ = ['helper']\n",
            "test_every_module_declares_what_it_defines_in_all",
            r"ngbet.b.__all__ lists names it does not define \(a re-export\): \['helper'\]",
        ),
        (
            "from .a import helper\n__all__ = []\n",
            "test_every_import_names_the_module_that_defines_the_name",
            "c.py:1: helper from ngbet.b, which does not define it",
        ),
        (
            "from .a import _helper\n__all__ = []\n",
            "test_no_private_name_is_imported_from_another_module",
            "b.py:1: _helper from ngbet.a",
        ),
    ],
)
def test_the_checks_see_a_re_export_and_a_private_import(tmp_path, monkeypatch, source, check, message):
    """The checks fail on what they are there to catch: a module ``b`` handing on ``a``'s name,
    a module importing ``a``'s private name."""
    (tmp_path / "a.py").write_text("__all__ = ['helper']\n\ndef helper(): ...\n\ndef _helper(): ...\n")
    (tmp_path / "b.py").write_text(source)
    (tmp_path / "c.py").write_text("from .b import helper\n__all__ = []\n")
    files = {f"ngbet.{n}": tmp_path / f"{n}.py" for n in "abc"}
    trees = {m: ast.parse(p.read_text()) for m, p in files.items()}
    monkeypatch.setitem(globals(), "MODULES", files)
    monkeypatch.setitem(globals(), "TREES", trees)
    monkeypatch.setitem(globals(), "DEFINED", {m: _defined(t) for m, t in trees.items()})
    monkeypatch.setitem(globals(), "_outside_files", dict)
    monkeypatch.setattr("pathlib.Path.relative_to", lambda self, other: Path(self.name))
    with pytest.raises(AssertionError, match=message):
        globals()[check]()


def test_the_circle_check_sees_a_circle(monkeypatch, tmp_path):
    (tmp_path / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import B\n")
    (tmp_path / "b.py").write_text("def f():\n    from .a import A\n")
    files = {f"ngbet.{n}": tmp_path / f"{n}.py" for n in "ab"}
    monkeypatch.setitem(globals(), "MODULES", files)
    monkeypatch.setitem(globals(), "TREES", {m: ast.parse(p.read_text()) for m, p in files.items()})
    with pytest.raises(AssertionError, match="import circle: ngbet.a -> ngbet.b -> ngbet.a"):
        test_no_import_circle()


@pytest.mark.parametrize(
    "layer, source",
    [
        ("numerics", "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ..scene.document import Scene\n"),
        ("numerics", "def f():\n    from ..continuum.problem import ContinuumProblem\n"),
        ("continuum", "from ..figures import run\n"),
        ("continuum", "from ..runner.settings import newton_settings\n"),
        ("discrete", "def f():\n    from ..figures.run import start_plot\n"),
        ("discrete", "from ..runner.settings import step_control\n"),
        ("scene", "def f():\n    from ..continuum.problem import ContinuumProblem\n"),
        ("runner", "from ..study.runner import run_study\n"),
        (
            "figures",
            "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ..runner.settings import Settings\n",
        ),
        ("figures", "from ..study.runner import run_study\n"),
    ],
)
def test_the_layer_check_sees_an_import_that_climbs(monkeypatch, tmp_path, layer, source):
    """A numerics module that reads the scene (for type checking only) or a model, a continuum or
    network module that reaches for the figures or the runner, a scene module that reads a model,
    a runner or figures module that reaches for a study or the runner: each is named."""
    files = {
        f"ngbet.{layer}.a": tmp_path / "a.py",
        "ngbet.scene.document": tmp_path / "document.py",
        "ngbet.continuum.problem": tmp_path / "problem.py",
        "ngbet.figures.run": tmp_path / "run.py",
        "ngbet.runner.settings": tmp_path / "settings.py",
        "ngbet.study.runner": tmp_path / "study_runner.py",
    }
    for m, p in files.items():
        p.write_text(source if m == f"ngbet.{layer}.a" else "")
    monkeypatch.setitem(globals(), "MODULES", files)
    monkeypatch.setitem(globals(), "TREES", {m: ast.parse(p.read_text()) for m, p in files.items()})
    with pytest.raises(AssertionError, match=f"ngbet.{layer}.a imports ngbet"):
        test_the_layers_import_downwards_only()

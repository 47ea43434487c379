"""The layers of docs/architecture.md, checked on the source: which package may import which, and that no
library error message names a command-line flag. Each scanner takes a root directory (the repository's, or a
temporary tree with a violation planted in it, which shows that the scanner can fail)."""

from __future__ import annotations

import ast
import re
import shutil
import textwrap
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("shellsim", "neural")
FLAG = re.compile(r"--[a-z]")


def _within(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def _modules(root: Path) -> Iterator[tuple[str, Path, ast.Module]]:
    """(dotted name, path, syntax tree) of every module of :data:`PACKAGES` under ``root``."""
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            yield name, path, ast.parse(path.read_text(), str(path))


def _imported(module: str, path: Path, tree: ast.Module) -> Iterator[tuple[int, str]]:
    """(line, absolute name) of what every import statement of ``tree`` imports, at any depth (inside
    functions too); ``from a import b`` imports ``a`` and ``a.b``; relative imports are resolved."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            yield node.lineno, base
            for alias in node.names:
                yield node.lineno, f"{base}.{alias.name}"


def _forbidden(module: str) -> tuple[str, ...]:
    """The packages ``module`` may not import: neural none of shellsim, the library neither the command line
    nor the jobs, the jobs not the command line."""
    if _within(module, "neural"):
        return ("shellsim",)
    if _within(module, "shellsim.cli"):
        return ()
    if _within(module, "shellsim.jobs"):
        return ("shellsim.cli",)
    return ("shellsim.cli", "shellsim.jobs")


def import_violations(root: Path) -> list[str]:
    """``path:line: module imports name (a layer above it)`` for every import across the layers under
    ``root``, one per statement and forbidden package."""
    found = {}
    for module, path, tree in _modules(root):
        for line, name in _imported(module, path, tree):
            for package in _forbidden(module):
                if _within(name, package):
                    where = f"{path.relative_to(root)}:{line}"
                    found.setdefault((where, package), f"{where}: {module} imports {name} (layer {package})")
    return list(found.values())


def _library(root: Path) -> Iterator[tuple[Path, ast.Module]]:
    """The library's modules: neural and shellsim but the command line."""
    for module, path, tree in _modules(root):
        if not _within(module, "shellsim.cli"):
            yield path, tree


def _reports(call: ast.Call) -> bool:
    """Whether ``call`` makes an error of its arguments: an exception's constructor (a name ending in Error or
    Exception) or a checker (``check_range``, ``check_tet_mesh``, ...)."""
    name = getattr(call.func, "id", None) or getattr(call.func, "attr", "")
    return name.endswith(("Error", "Exception")) or name.startswith("check_")


_SCOPES = (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)


def _own(scope: ast.AST) -> Iterator[ast.AST]:
    """The nodes of ``scope`` outside the functions and classes defined in it."""
    stack = list(ast.iter_child_nodes(scope))
    while stack:
        node = stack.pop()
        yield node
        if not isinstance(node, _SCOPES):
            stack.extend(ast.iter_child_nodes(node))


def _assigned(scope: ast.AST) -> dict[str, list[ast.AST]]:
    """Name -> the values assigned to it in ``scope`` itself."""
    values: dict[str, list[ast.AST]] = {}
    for node in _own(scope):
        if isinstance(node, ast.Assign | ast.AnnAssign) and node.value is not None:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                if isinstance(target, ast.Name):
                    values.setdefault(target.id, []).append(node.value)
    return values


def _messages(tree: ast.Module) -> Iterator[ast.AST]:
    """What may become an error message: the expressions of each ``raise`` and the arguments of each call
    that reports (:func:`_reports`), with what their names are assigned in the same function or the module
    (``message = f"..."; raise ValueError(message)``; ``cage.build.APART_DILATED`` handed to
    ``check_tet_mesh``)."""
    module = _assigned(tree)
    functions = [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)]
    for scope in [tree, *functions]:
        local = _assigned(scope) if scope is not tree else {}
        for node in _own(scope):
            if isinstance(node, ast.Raise):
                found = [n for n in (node.exc, node.cause) if n is not None]
            elif isinstance(node, ast.Call) and _reports(node):
                found = [*node.args, *(k.value for k in node.keywords)]
            else:
                continue
            for expression in found:
                yield expression
                for name in ast.walk(expression):
                    if isinstance(name, ast.Name):
                        yield from local.get(name.id) or module.get(name.id, [])


def flag_messages(root: Path) -> list[str]:
    """``path:line: 'text'`` for every string literal (or f-string part) of a library error message under
    ``root`` that names a ``--flag``: the library speaks of settings (``SettingError``'s ``{field}``), the
    command line shows them as its options."""
    found = {}
    for path, tree in _library(root):
        for message in _messages(tree):
            for node in ast.walk(message):
                if isinstance(node, ast.Constant) and isinstance(node.value, str) and FLAG.search(node.value):
                    where = f"{path.relative_to(root)}:{node.lineno}"
                    found[(where, node.col_offset)] = f"{where}: {node.value!r}"
    return list(found.values())


def _copy(tmp_path: Path) -> Path:
    """A copy of the packages under ``tmp_path``."""
    for package in PACKAGES:
        shutil.copytree(ROOT / package, tmp_path / package, ignore=shutil.ignore_patterns("__pycache__"))
    return tmp_path


def _plant(root: Path, relative: str, code: str) -> None:
    path = root / relative
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as file:
        file.write("\n\n" + textwrap.dedent(code))


def test_no_module_imports_a_layer_above_it():
    assert import_violations(ROOT) == []


def test_a_planted_import_across_the_layers_is_reported(tmp_path):
    """Function-level and relative imports count; the jobs may import each other and the command line may
    import anything."""
    root = _copy(tmp_path)
    before = set(import_violations(root))
    _plant(root, "neural/losses.py", "def f():\n    from shellsim.settings import option\n")
    _plant(root, "shellsim/physics/planted.py", "from ..cli import options\n")
    _plant(root, "shellsim/io/planted.py", "import shellsim.jobs.wind\n")
    _plant(root, "shellsim/jobs/planted.py", "from shellsim.jobs import wind\nfrom shellsim import cli\n")
    _plant(root, "shellsim/cli/planted.py", "import shellsim.jobs.wind\n")
    planted = [v for v in import_violations(root) if v not in before]
    assert [v.split(": ", 1)[1] for v in planted] == [
        "shellsim.io.planted imports shellsim.jobs.wind (layer shellsim.jobs)",
        "shellsim.jobs.planted imports shellsim.cli (layer shellsim.cli)",
        "shellsim.physics.planted imports shellsim.cli (layer shellsim.cli)",
        "neural.losses imports shellsim.settings (layer shellsim)",
    ]
    assert planted[-1].startswith("neural/losses.py:")


def test_library_errors_name_no_flag():
    """Library messages speak of values and settings; ``shellsim.cli.options`` shows a setting as its flag."""
    assert flag_messages(ROOT) == []


def test_a_planted_flag_in_a_library_error_is_reported(tmp_path):
    """In a raise, an f-string, an exception built and raised later, a checker's argument, a message kept in
    a variable or a module constant; not in a log line, a docstring, an option's help or the command line."""
    root = _copy(tmp_path)
    before = set(flag_messages(root))
    _plant(
        root,
        "shellsim/physics/planted.py",
        '''
        from neural.errors import InputError
        from shellsim.settings import check_range, option

        ADVICE = "or give --margin"
        HELP = option(help="with --motion: more")

        def f(x, log):
            """Give --fps here, in a docstring."""
            log.info("--overwrite: replacing %s", x)
            if x:
                raise ValueError(f"{x}: give --frames " "more")
            what = f"a speed at --size {x}"
            check_range("spin", x, 0, 1, what)
            error = InputError("the asset needs --asset")
            message = "pick --out"
            if x > 1:
                raise ValueError(message + ADVICE)
            raise error
        ''',
    )
    _plant(root, "shellsim/cli/planted.py", 'raise ValueError("give --frames")\n')
    planted = [v for v in flag_messages(root) if v not in before]
    assert set(planted) == {
        "shellsim/physics/planted.py:7: 'or give --margin'",
        "shellsim/physics/planted.py:14: ': give --frames more'",
        "shellsim/physics/planted.py:15: 'a speed at --size '",
        "shellsim/physics/planted.py:17: 'the asset needs --asset'",
        "shellsim/physics/planted.py:18: 'pick --out'",
    }

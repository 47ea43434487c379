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

#: The layers of ``shellsim``, low to high: each a band of sub-packages or modules of ``shellsim`` (``""``:
#: ``shellsim/__init__.py``, the public API). A module imports its own layer and the bands below its band;
#: the members of a band import each other, but for the top band (the faces and the API), whose members
#: import only themselves. ``distributed`` (Ray tasks; it imports only ``errors``) is in the lowest band,
#: where its imports put it. ``neural`` imports no layer of ``shellsim``.
LAYERS = (
    ("errors", "world", "settings", "memory", "distributed"),
    ("io",),
    ("tetcage",),
    ("physics",),
    ("motion",),
    ("shot",),
    ("deform",),
    ("film",),
    ("viz",),
    ("jobs",),
    ("cli", "view", ""),
)
BAND = {layer: band for band, members in enumerate(LAYERS) for layer in members}
#: Imports across the top band that are allowed: the command line starts the browser viewer (``shellsim
#: view``), as it runs the jobs; the viewer never imports the command line.
FACES = {("cli", "view")}
TOP = len(LAYERS) - 1


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
    functions and ``if TYPE_CHECKING:`` too); ``from a.b import c`` imports ``a.b`` and ``a.b.c``, ``from a
    import c`` only ``a.c`` (every import of a sub-module loads the package ``a``: what counts is the name
    taken from it); relative imports are resolved."""
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
            if "." in base:
                yield node.lineno, base
            for alias in node.names:
                yield node.lineno, f"{base}.{alias.name}"


def _layer(name: str) -> str:
    """The layer of a name under ``shellsim`` (a module, or what an import takes): its sub-package or module
    (``shellsim.tetcage.build`` -> ``tetcage``), else ``""``, the public API (``shellsim`` itself, the names
    ``shellsim/__init__.py`` exports)."""
    part = name.split(".")[1] if "." in name else ""
    return part if part in BAND else ""


def _shown(layer: str) -> str:
    return f"layer {layer}" if layer else "layer shellsim/__init__.py"


def _violation(module: str, name: str) -> str | None:
    """Why ``module`` may not import ``name`` (``"layer A) imports ... (layer B, why"``), or None."""
    if _within(module, "neural"):
        if _within(name, "shellsim"):
            return f"package neural) imports {name} ({_shown(_layer(name))}: neural never imports shellsim"
        return None
    if not _within(name, "shellsim"):
        return None
    mine, theirs = _layer(module), _layer(name)
    if mine == theirs or BAND[theirs] < BAND[mine] or (BAND[theirs] == BAND[mine] < TOP):
        return None
    if (mine, theirs) in FACES:
        return None
    why = "above it" if BAND[theirs] > BAND[mine] else "beside it in the top band"
    return f"{_shown(mine)}) imports {name} ({_shown(theirs)}, {why}"


def import_violations(root: Path) -> list[str]:
    """``path:line: module (layer A) imports name (layer B, above it)`` for every import across the layers
    under ``root`` (:data:`LAYERS`), one per statement and layer imported; ``path: module is in no layer``
    for a module of ``shellsim`` outside :data:`LAYERS`."""
    found = {}
    for module, path, tree in _modules(root):
        where = path.relative_to(root)
        if _within(module, "shellsim") and module != "shellsim" and module.split(".")[1] not in BAND:
            found[(where, None)] = f"{where}: {module} is in no layer (tests/test_layers.py LAYERS)"
        for line, name in _imported(module, path, tree):
            why = _violation(module, name)
            if why is not None:
                at = f"{where}:{line}"
                found.setdefault((at, _layer(name)), f"{at}: {module} ({why})")
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
    (``message = f"..."; raise ValueError(message)``; ``tetcage.build.APART_DILATED`` handed to
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


def _plant(root: Path, relative: str, code: str) -> int:
    """Append ``code`` to the module ``relative`` under ``root`` (made if missing); the line of its first
    line there."""
    path = root / relative
    path.parent.mkdir(parents=True, exist_ok=True)
    first = (len(path.read_text().splitlines()) if path.exists() else 0) + 3
    with path.open("a") as file:
        file.write("\n\n" + textwrap.dedent(code))
    return first


def test_no_module_imports_a_layer_above_it():
    """Every import of every module keeps the order of :data:`LAYERS`."""
    assert import_violations(ROOT) == []


def test_a_planted_import_across_the_layers_is_reported(tmp_path):
    """Each import of a layer above (function-level, relative, under ``TYPE_CHECKING``, of the public API), of
    a member of the top band beside one, of shellsim from neural, and a module in no layer is reported with
    its file and line; imports within a layer, within the lowest band and downward are not."""
    root = _copy(tmp_path)
    before = set(import_violations(root))
    losses = _plant(root, "neural/losses.py", "def f():\n    from shellsim.settings import option\n")
    _plant(
        root,
        "shellsim/tetcage/planted.py",
        """\
        from shellsim.motion.format import Motion
        from shellsim.tetcage.geometry import tet_volumes
        from ..io.npz import save_npz
        from shellsim import errors, world
        import shellsim.tetcage.build
        """,
    )
    npz = _plant(
        root,
        "shellsim/io/npz.py",
        """\
        def planted():
            from shellsim.io.outputs import check_writable_file
            from shellsim.settings import option
            from shellsim.tetcage import geometry
        """,
    )
    _plant(
        root,
        "shellsim/settings.py",
        "def planted():\n    from shellsim.world import UP\n    from . import distributed\n",
    )
    _plant(root, "shellsim/physics/planted.py", "from ..cli import options\n")
    _plant(root, "shellsim/motion/planted.py", "from shellsim import simulate\n")
    _plant(
        root,
        "shellsim/film/planted.py",
        """\
        from typing import TYPE_CHECKING
        if TYPE_CHECKING:
            from shellsim.viz.inspect import show
        from shellsim.deform.inverse_map import InverseMap
        """,
    )
    _plant(root, "shellsim/jobs/planted.py", "from shellsim.jobs import wind\nfrom shellsim import cli\n")
    _plant(
        root,
        "shellsim/cli/planted.py",
        "import shellsim.jobs.wind\nfrom shellsim.film import frames\nfrom shellsim.view import viewer\n",
    )
    _plant(
        root,
        "shellsim/view/planted.py",
        "from shellsim.film.cameras import Shot\nfrom shellsim.jobs import render\nimport shellsim.cli\n",
    )
    api = _plant(root, "shellsim/__init__.py", "def planted():\n    from .cli import main\n")
    _plant(root, "shellsim/extra/planted.py", "from shellsim.world import UP\n")
    planted = [v for v in import_violations(root) if v not in before]
    assert len(planted) == len(set(planted))
    assert set(planted) == {
        f"neural/losses.py:{losses + 1}: neural.losses (package neural) imports shellsim.settings "
        "(layer settings: neural never imports shellsim)",
        "shellsim/tetcage/planted.py:3: shellsim.tetcage.planted (layer tetcage) imports "
        "shellsim.motion.format (layer motion, above it)",
        f"shellsim/io/npz.py:{npz + 3}: shellsim.io.npz (layer io) imports shellsim.tetcage "
        "(layer tetcage, above it)",
        "shellsim/physics/planted.py:3: shellsim.physics.planted (layer physics) imports shellsim.cli "
        "(layer cli, above it)",
        "shellsim/motion/planted.py:3: shellsim.motion.planted (layer motion) imports shellsim.simulate "
        "(layer shellsim/__init__.py, above it)",
        "shellsim/film/planted.py:5: shellsim.film.planted (layer film) imports shellsim.viz.inspect "
        "(layer viz, above it)",
        "shellsim/jobs/planted.py:4: shellsim.jobs.planted (layer jobs) imports shellsim.cli "
        "(layer cli, above it)",
        "shellsim/view/planted.py:5: shellsim.view.planted (layer view) imports shellsim.cli "
        "(layer cli, beside it in the top band)",
        f"shellsim/__init__.py:{api + 1}: shellsim (layer shellsim/__init__.py) imports shellsim.cli "
        "(layer cli, beside it in the top band)",
        "shellsim/extra/planted.py: shellsim.extra.planted is in no layer (tests/test_layers.py LAYERS)",
    }


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

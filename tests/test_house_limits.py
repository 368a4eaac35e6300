"""The house stays readable (issues 28 and 36): no module over 400 code lines, no function over 60 lines, no
folder over 16 modules, every module opening with a docstring that explains it, no import cycle.

Read from the source with ``ast`` and ``tokenize`` over the three installed folders (``fxc_env/``,
``baselines/`` as ``fxc_env.baselines``, ``training/`` as ``fxc_env.training``). A module's size counts its
code lines only: docstrings, comments and blank lines are explanation, never a reason to split a module. A
folder's modules are its ``.py`` files other than ``__init__.py``. An import inside a function counts: a
cycle hidden there is still a cycle. Only ``if TYPE_CHECKING:`` imports are left out (they never run).
"""

from __future__ import annotations

import ast
import io
import textwrap
import tokenize
import tomllib
from collections import Counter
from pathlib import Path

from helpers import ROOT, library_modules

MAX_MODULE_CODE_LINES = 400
MAX_FUNCTION_LINES = 60
MAX_FOLDER_MODULES = 16
#: Tokens that are no code: comments, line ends, indentation.
NOT_CODE = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT, tokenize.ENDMARKER}


MODULES = library_modules()
#: The compiled modules (pyproject.toml's ext-modules), by import name.
COMPILED = {
    module["name"]
    for module in tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["ext-modules"]
}


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


def docstring_nodes(tree: ast.Module) -> list[ast.Expr]:
    """The docstrings of the module, its classes and functions (each one's first statement, a string)."""
    owners = [
        tree,
        *(n for n in ast.walk(tree) if isinstance(n, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)),
    ]
    return [
        owner.body[0]
        for owner in owners
        if owner.body
        and isinstance(owner.body[0], ast.Expr)
        and isinstance(owner.body[0].value, ast.Constant)
        and isinstance(owner.body[0].value.value, str)
    ]


def code_lines(source: str) -> int:
    """The lines that hold code: not blank, not only a comment, not part of a docstring."""
    tokens = tokenize.generate_tokens(io.StringIO(source).readline)
    lines = {line for t in tokens if t.type not in NOT_CODE for line in range(t.start[0], t.end[0] + 1)}
    for node in docstring_nodes(ast.parse(source)):
        lines -= set(range(node.lineno, node.end_lineno + 1))
    return len(lines)


def test_code_lines_leave_out_docstrings_comments_and_blank_lines():
    source = '''
    """A module.

    Explained at length.
    """

    # a comment
    X = 1  # counted


    def f(a):
        """Its docstring,
        on two lines."""
        return (a +
                X)


    TEXT = """a string that is no docstring
    counts"""
    '''
    assert code_lines(textwrap.dedent(source)) == 6  # X, def, return (2 lines), TEXT (2 lines)


def test_no_module_is_over_400_code_lines():
    long = {_rel(p): n for p in MODULES.values() if (n := code_lines(p.read_text())) > MAX_MODULE_CODE_LINES}
    assert not long, f"modules over {MAX_MODULE_CODE_LINES} code lines (split them by topic): {long}"


def test_no_folder_holds_more_than_16_modules():
    counts = Counter(_rel(p.parent) for p in MODULES.values() if p.name != "__init__.py")
    crowded = {folder: n for folder, n in counts.items() if n > MAX_FOLDER_MODULES}
    assert not crowded, f"folders over {MAX_FOLDER_MODULES} modules (__init__.py not counted): {crowded}"


def explains(text: str | None) -> bool:
    """A docstring that explains: a summary of five words or more, and more than pointers to the docs after it."""
    if not text:
        return False
    summary, *rest = [" ".join(part.split()) for part in text.split("\n\n")]
    pointer = ("more:", "more ", "docs:", "see ", "(docs:")
    only_pointers = bool(rest) and all(part.lower().startswith(pointer) for part in rest)
    return len(summary.split()) >= 5 and not summary.lower().startswith(pointer) and not only_pointers


def test_explains_refuses_a_pointer_only_docstring():
    assert not explains(None)
    assert not explains('More: docs: training.md, "fxc_env.training.rings".')
    assert not explains(
        "The engine's clock: which sampling instant each episode is at.\n\nMore: docs: architecture.md."
    )
    assert not explains('The goal table: medians against the noise floor.\n\nDocs: optimality.md, "Filtering".')
    assert explains("The engine's clock: which sampling instant each episode is at.\n\nEpisodes start together.")
    assert explains("The largest absolute value over the padded in-neighbour slots.")


def test_every_module_opens_with_a_docstring_that_explains_it():
    bare = [_rel(p) for p in MODULES.values() if not explains(ast.get_docstring(ast.parse(p.read_text())))]
    assert not bare, f"modules without a docstring that explains them (not a pointer to the docs): {bare}"


def test_no_function_is_over_60_lines():
    long = []
    for path in MODULES.values():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    long.append(f"{_rel(path)}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines: {long}"


def _imported(name: str, path: Path) -> set[str]:
    """The package's modules ``name`` imports anywhere in its body (functions included; not TYPE_CHECKING)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    targets: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                for inner in child.orelse:
                    visit(inner)
                continue
            if isinstance(child, ast.Import):
                targets.update(alias.name for alias in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    up = package.split(".")[: len(package.split(".")) - child.level + 1]
                    base = ".".join([*up, *([child.module] if child.module else [])])
                targets.update(f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in child.names)
            visit(child)

    visit(ast.parse(path.read_text()))
    resolved = set()
    for target in targets - COMPILED:  # a compiled module imports nothing of the library
        while target and target not in MODULES:
            target = target.rpartition(".")[0]
        if target and target != name:
            resolved.add(target)
    return resolved


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while (w := stack.pop()) != v:
                component.append(w)
            if component:
                found.append(sorted([v, *component]))

    for v in graph:
        if v not in index:
            connect(v)
    return found


def test_the_cycle_finder_sees_an_import_hidden_in_a_function(tmp_path):
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]
    hidden = tmp_path / "m.py"
    hidden.write_text("def f():\n    from fxc_env.policies import learned\n")
    assert "fxc_env.policies.learned" in _imported("fxc_env.x", hidden)


def test_no_import_cycle_between_modules_counting_imports_inside_functions():
    graph = {name: _imported(name, path) for name, path in MODULES.items()}
    cycles = _cycles(graph)
    edges = [f"{a} -> {b}" for cycle in cycles for a in cycle for b in sorted(graph[a]) if b in cycle]
    assert not cycles, f"import cycles {cycles}; their imports: {edges}"

"""The package's imports: no cycles between modules, and every import inside a function says why.

The graph has an edge for every import statement of a module, at module level or inside a
function (relative imports and ``from jaxgrasp import mcmc`` included), so a function-local
import cannot hide a cycle. Imports under ``if TYPE_CHECKING:`` never run and are left out.
"""

import ast
import graphlib
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "jaxgrasp"


def module_files(root: Path) -> dict:
    """{dotted module name: file} of the package in directory ``root``."""
    mods = {}
    for path in sorted(root.rglob("*.py")):
        parts = (root.name, *path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = path
    return mods


def _type_checking(node) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree):
    """Every import statement that can run, at any depth."""
    todo = [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        elif isinstance(node, ast.If) and _type_checking(node):
            todo.extend(node.orelse)
        else:
            todo.extend(ast.iter_child_nodes(node))


def _imported_names(node, module: str, is_package: bool) -> list:
    """Dotted names an import statement loads: ``from a import b`` gives ``a.b``, which is a
    module or else a name defined in the module ``a``."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    base = node.module or ""
    if node.level:  # relative: resolved against the importing module's package
        package = module if is_package else module.rpartition(".")[0]
        for _ in range(node.level - 1):
            package = package.rpartition(".")[0]
        base = f"{package}.{base}" if base else package
    return [f"{base}.{a.name}" for a in node.names] + [base]


def import_graph(root: Path) -> dict:
    """{module: set of the package's modules it imports} for the package in ``root``."""
    mods = module_files(root)

    def resolve(name):
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name

    graph = {}
    for module, path in mods.items():
        deps = set()
        for node in _imports(ast.parse(path.read_text(), str(path))):
            names = _imported_names(node, module, path.name == "__init__.py")
            if isinstance(node, ast.ImportFrom):
                # ``from a import b``: the submodule a.b when there is one, else a itself.
                subs = [n for n in names[:-1] if n in mods]
                names = subs if len(subs) == len(names) - 1 else subs + [names[-1]]
            deps.update(filter(None, map(resolve, names)))
        deps.discard(module)
        graph[module] = deps
    return graph


def find_cycle(graph: dict) -> list | None:
    """One import cycle ``[m1, m2, ..., m1]`` of ``graph``, or None."""
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as err:
        return err.args[1]
    return None


def _statement_lists(tree):
    for node in ast.walk(tree):
        for field in ("body", "orelse", "finalbody"):
            stmts = getattr(node, field, None)
            if isinstance(stmts, list) and stmts and isinstance(stmts[0], ast.stmt):
                yield node, stmts


def _is_reason(comment: str) -> bool:
    text = comment.strip().lstrip("#").strip()
    return bool(text) and not text.startswith(("noqa", "type:", "pragma"))


def uncommented_local_imports(root: Path) -> list:
    """``file:line`` of every import inside a function that has no comment giving a reason:
    on the line above, or at the end of the import. The imports of one block (consecutive
    statements, blank lines between them allowed) share the first one's comment."""
    bad = []
    for path in module_files(root).values():
        lines = path.read_text().splitlines()
        tree = ast.parse("\n".join(lines), str(path))
        local = {id(n) for f in ast.walk(tree) if isinstance(f, ast.FunctionDef |
                 ast.AsyncFunctionDef) for n in ast.walk(f) if n is not f}
        for owner, stmts in _statement_lists(tree):
            in_function = isinstance(owner, ast.FunctionDef | ast.AsyncFunctionDef)
            if not (in_function or id(owner) in local):
                continue
            ok_above = False
            for i, s in enumerate(stmts):
                if not isinstance(s, ast.Import | ast.ImportFrom):
                    ok_above = False
                    continue
                own = [ln.partition("#")[2] for ln in lines[s.lineno - 1:s.end_lineno]]
                above = lines[s.lineno - 2].strip()
                ok = (any(_is_reason("#" + c) for c in own if c)
                      or (above.startswith("#") and _is_reason(above))
                      or (ok_above and not any(ln.strip() for ln in
                                               lines[stmts[i - 1].end_lineno:s.lineno - 1])))
                if not ok:
                    bad.append((str(path.relative_to(root.parent)), s.lineno))
                ok_above = ok
    return [f"{f}:{line}" for f, line in sorted(bad)]


# --------------------------------------------------------------------------------------------


def test_jaxgrasp_has_no_import_cycle():
    graph = import_graph(PACKAGE)
    assert "jaxgrasp.bench.cli" in graph["jaxgrasp.bench"]  # function-local imports count
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_cycle_detector_finds_a_cycle_through_relative_and_local_imports(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from pkg.sub.b import f\n")
    (pkg / "a.py").write_text("from pkg import sub\n")
    (pkg / "sub" / "b.py").write_text("def f():\n    from .. import a\n    return a\n")
    (pkg / "c.py").write_text("import pkg.a\nfrom pkg.sub import b\n")
    graph = import_graph(pkg)
    assert graph["pkg.a"] == {"pkg.sub"} and graph["pkg.sub.b"] == {"pkg.a"}
    assert graph["pkg.c"] == {"pkg.a", "pkg.sub.b"}
    cycle = find_cycle(graph)
    assert cycle is not None and set(cycle) == {"pkg.a", "pkg.sub", "pkg.sub.b"}
    assert uncommented_local_imports(pkg) == ["pkg/sub/b.py:2"]
    # Once each local import gives its reason, the comment check passes.
    (pkg / "sub" / "b.py").write_text("def f():\n    # why\n    from .. import a\n\n"
                                      "    import os\n    return a, os\n\n\n"
                                      "def g():\n    x = 1\n    import os  # why\n"
                                      "    import sys\n    return x, os, sys\n")
    assert uncommented_local_imports(pkg) == []
    assert find_cycle({"x": {"y"}, "y": set()}) is None


def test_function_local_imports_give_their_reason():
    bad = uncommented_local_imports(PACKAGE)
    assert not bad, ("imports inside functions need a one-line comment (line above or end of "
                     "line) saying why they are not at module level: " + ", ".join(bad))

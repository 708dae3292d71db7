"""The package's own imports, read with ast: no module reaches itself through them (imports
inside functions count), and an import inside a function says beside it why it is there."""

import ast
import re
from pathlib import Path
from typing import Dict, Iterator, List, Mapping, Set, Tuple

SRC = Path(__file__).resolve().parents[2] / "src"
PACKAGE = SRC / "docker_ros"


def module_name(path: Path) -> str:
    parts = path.relative_to(SRC).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def named_modules(node: ast.AST, current: str) -> Set[str]:
    """The package's modules an import statement loads (`from pkg import mod` names mod)."""
    if isinstance(node, ast.Import):
        return {alias.name for alias in node.names if alias.name in MODULES}
    assert isinstance(node, ast.ImportFrom)
    base = node.module or ""
    if node.level:  # relative: from the module's package up
        package = current.split(".")
        if MODULES[current].name != "__init__.py":
            package = package[:-1]
        package = package[:len(package) - node.level + 1]
        base = ".".join([*package, *([node.module] if node.module else [])])
    found = {f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in MODULES}
    if base in MODULES and len(found) < len(node.names):
        found.add(base)
    return found


def is_type_checking(node: ast.AST) -> bool:
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)


def imports(tree: ast.AST, in_function: bool = False) -> Iterator[Tuple[ast.AST, bool]]:
    """Every import statement that runs (none under `if TYPE_CHECKING:`), and whether it is
    inside a function."""
    for child in ast.iter_child_nodes(tree):
        if is_type_checking(child):
            continue
        if isinstance(child, (ast.Import, ast.ImportFrom)):
            yield child, in_function
        inner = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef,
                                                  ast.Lambda))
        yield from imports(child, inner)


def import_graph() -> Dict[str, Set[str]]:
    graph: Dict[str, Set[str]] = {}
    for name, path in MODULES.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        graph[name] = set().union(*[named_modules(node, name) for node, _ in imports(tree)])
        graph[name].discard(name)
    return graph


def cycles(graph: Mapping[str, Set[str]]) -> List[List[str]]:
    """One path round each strongly connected group of modules (Tarjan)."""
    index: Dict[str, int] = {}
    low: Dict[str, int] = {}
    stack: List[str] = []
    found: List[List[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            group = []
            while True:
                member = stack.pop()
                group.append(member)
                if member == node:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def function_imports() -> List[Tuple[str, int, str]]:
    """(file, line, the line and the one above) of every import inside a function."""
    found = []
    for path in MODULES.values():
        lines = path.read_text().splitlines()
        for node, in_function in imports(ast.parse("\n".join(lines))):
            if in_function:
                above = lines[node.lineno - 2] if node.lineno > 1 else ""
                found.append((str(path.relative_to(SRC)), node.lineno,
                              above + "\n" + lines[node.lineno - 1]))
    return found


def test_no_module_reaches_itself_through_its_imports() -> None:
    assert cycles(import_graph()) == []


def test_the_graph_holds_imports_inside_functions_and_finds_a_circle() -> None:
    graph = import_graph()
    assert "docker_ros.host.build" in graph["docker_ros.host.lock"]
    assert "docker_ros.core.settings" in graph["docker_ros.host.build"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_an_import_inside_a_function_says_why() -> None:
    """Only where it saves start-up time or keeps an optional, non-standard-library module
    out of the images' code: a comment on its line or the line above says which."""
    silent = [f"{file}:{line}" for file, line, text in function_imports()
              if not re.search(r"(^|\s)#\s", text)]
    assert silent == []

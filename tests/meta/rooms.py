"""The rules of the house (docs/concepts.md, "Where things live"), as checkers over a source tree.

Each checker takes the repository root and returns every violation as a sentence, so the same
code checks the real tree (tests/meta/test_rooms.py) and small fake trees that break one rule on
purpose (to show each rule can fail).
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

#: Source folders and the package each one is.
FOLDERS = {"toolkit": "tendonkit", "plugins": "tendonkit.plugins", "fmu": "tendonkit.fmu"}

#: Rooms, by module-name prefix (longest first wins); "core" is everything else in tendonkit.
ROOMS = {
    "tendonkit.diagnose": "diagnose",
    "tendonkit.mpc": "mpc",
    "tendonkit.robot": "robot",
    "tendonkit.cli": "cli",
    "tendonkit.plugins": "plugins",
    "tendonkit.fmu": "fmu",
}
GENERIC = {"core", "diagnose", "mpc"}
#: Rooms each room must never import.
FORBIDDEN = {
    "core": {"diagnose", "mpc", "robot", "cli", "fmu", "plugins"},
    "diagnose": {"mpc", "robot", "cli", "fmu", "plugins"},
    "mpc": {"diagnose", "robot", "cli", "fmu", "plugins"},
    "robot": {"cli", "plugins"},
    "fmu": {"cli", "plugins", "diagnose", "mpc"},
    "plugins": {"robot", "cli", "fmu"},  # and diagnose/mpc only through their doors (DOORS)
    "cli": set(),
}
#: Doors: the only modules of a room that plugins may import.
DOORS = {"tendonkit.diagnose", "tendonkit.mpc"}
#: Libraries an import inside a function may defer.
HEAVY = {
    "cvxpy", "pysindy", "fmpy", "pythonfmu", "matplotlib", "control", "slycot", "scipy",
    "clarabel", "osqp", "tqdm", "threadpoolctl", "libcosimpy", "ecospy", "distributed",
    "dask", "numba", "cloudpickle",
}  # fmt: skip
#: The one module allowed to name other rooms (as strings) and to import inside functions.
COMPAT = "tendonkit._compat"


def room(module: str) -> str:
    """The room of a tendonkit module name."""
    for prefix in sorted(ROOMS, key=len, reverse=True):
        if module == prefix or module.startswith(prefix + "."):
            return ROOMS[prefix]
    return "core"


@dataclass(frozen=True)
class Import:
    """One import statement, resolved."""

    path: Path
    line: int
    module: str  # the importing module
    target: str  # the imported module (absolute)
    names: tuple[str, ...]
    relative: bool
    in_function: bool
    type_checking: bool
    comment: bool  # a '# lazy:' comment on its first line or the line(s) just above


def modules(root: Path) -> Iterator[tuple[str, Path]]:
    """Every module of the tree: (dotted name, path)."""
    for folder, package in FOLDERS.items():
        base = root / folder
        for path in sorted(base.rglob("*.py")):
            parts = list(path.relative_to(base).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            yield ".".join([package, *parts]), path


def _is_package(path: Path) -> bool:
    return path.name == "__init__.py"


def _lazy_comment(lines: list[str], first: int) -> bool:
    if "# lazy:" in lines[first - 1]:
        return True
    k = first - 2
    while k >= 0 and lines[k].strip().startswith(("#", "from ", "import ")):
        if "# lazy:" in lines[k]:
            return True
        k -= 1
    return False


def _visit(
    node: ast.AST, where: tuple[Path, str, str, list[str]], flags: tuple[bool, bool], out: list
) -> None:
    path, module, package, lines = where
    for child in ast.iter_child_nodes(node):
        fn = flags[0] or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef)
        tc = flags[1] or (isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test))
        if isinstance(child, ast.Import | ast.ImportFrom):
            if isinstance(child, ast.Import):
                targets: list[tuple[str, tuple[str, ...]]] = [(a.name, ()) for a in child.names]
                relative = False
            else:
                base = child.module or ""
                relative = child.level > 0
                if relative:
                    up = package.split(".")
                    up = up[: len(up) - (child.level - 1)]
                    base = ".".join([*up, base]) if base else ".".join(up)
                targets = [(base, tuple(a.name for a in child.names))]
            for target, names in targets:
                comment = _lazy_comment(lines, child.lineno)
                out.append(
                    Import(path, child.lineno, module, target, names, relative, *flags, comment)
                )
        _visit(child, where, (fn, tc), out)


def imports(root: Path) -> list[Import]:
    """Every import of the tree, resolved to absolute module names."""
    out: list[Import] = []
    for module, path in modules(root):
        text = path.read_text()
        package = module if _is_package(path) else module.rpartition(".")[0]
        _visit(ast.parse(text), (path, module, package, text.splitlines()), (False, False), out)
    return out


def _own(imp: Import) -> bool:
    return imp.target == "tendonkit" or imp.target.startswith("tendonkit.")


def _resolve(imp: Import, name: str, known: set[str]) -> str:
    """``from pkg import name``: the submodule when ``name`` is one, else the module itself."""
    sub = f"{imp.target}.{name}"
    return sub if sub in known else imp.target


def _where(imp: Import, root: Path) -> str:
    return f"{imp.path.relative_to(root)}:{imp.line}"


def room_violations(root: Path) -> list[str]:
    """Rooms importing rooms they must not (TYPE_CHECKING imports are allowed)."""
    known = {m for m, _ in modules(root)}
    bad = []
    for imp in imports(root):
        if not _own(imp) or imp.type_checking or imp.module == COMPAT:
            continue
        src = room(imp.module)
        for name in imp.names or ("",):
            target = _resolve(imp, name, known) if name else imp.target
            dst = room(target)
            if imp.module == "tendonkit" and target in DOORS:
                continue  # the package's public API re-exports the generic rooms' doors
            if dst in FORBIDDEN[src]:
                bad.append(f"{_where(imp, root)}: {src} imports {target} ({dst})")
            elif src == "plugins" and dst in {"diagnose", "mpc"} and target not in DOORS:
                bad.append(f"{_where(imp, root)}: plugins import {target}, not a room's door")
    return sorted(set(bad))


def style_violations(root: Path) -> list[str]:
    """Relative imports inside toolkit/, absolute ones across toolkit/, plugins/, fmu/."""
    bad = []
    for imp in imports(root):
        if imp.module == "tendonkit" and imp.target == "tendonkit" and imp.relative:
            continue
        folder = imp.path.relative_to(root).parts[0]
        if folder == "toolkit" and _own(imp) and not imp.relative:
            dst = room(imp.target)
            if dst not in {"plugins", "fmu"}:
                bad.append(f"{_where(imp, root)}: absolute import of {imp.target} inside toolkit/")
        if imp.relative and folder == "toolkit" and room(imp.target) in {"plugins", "fmu"}:
            bad.append(f"{_where(imp, root)}: relative import of {imp.target} across folders")
        if imp.relative and folder != "toolkit":
            own = FOLDERS[folder]
            if not (imp.target == own or imp.target.startswith(own + ".")):
                bad.append(f"{_where(imp, root)}: relative import of {imp.target} across folders")
    return sorted(set(bad))


def private_violations(root: Path) -> list[str]:
    """Underscore names (or modules) imported from another room."""
    known = {m for m, _ in modules(root)}
    bad = []
    for imp in imports(root):
        if not _own(imp) or COMPAT in (imp.module, imp.target):
            continue  # the 0.1 shims are for every room to use
        for name in imp.names:
            target = _resolve(imp, name, known)
            if room(target) == room(imp.module):
                continue
            parts = [*target.split(".")[1:], *([name] if target == imp.target else [])]
            if any(p.startswith("_") and not p.startswith("__") for p in parts):
                bad.append(f"{_where(imp, root)}: {imp.module} imports private {imp.target}.{name}")
    return sorted(set(bad))


def lazy_violations(root: Path) -> list[str]:
    """Imports inside functions that defer nothing heavy, or do not say why."""
    bad = []
    for imp in imports(root):
        if not imp.in_function or imp.module == COMPAT:
            continue
        if imp.target == "tendonkit._compat":
            continue  # a module __getattr__ delegating to the 0.1 shims
        top = imp.target.split(".")[0]
        reason_ok = top in HEAVY or imp.target.startswith("tendonkit.fmu")
        if not reason_ok:
            bad.append(f"{_where(imp, root)}: {imp.target} imported inside a function")
        elif not imp.comment:
            bad.append(f"{_where(imp, root)}: lazy import of {imp.target} without '# lazy:'")
    return sorted(set(bad))


def cycles(root: Path) -> list[list[str]]:
    """Import cycles among tendonkit modules (module-level imports), as lists of modules."""
    known = {m for m, _ in modules(root)}
    graph: dict[str, set[str]] = {m: set() for m in known}
    for imp in imports(root):
        if imp.in_function or imp.type_checking or not _own(imp):
            continue
        for name in imp.names or ("",):
            target = _resolve(imp, name, known) if name else imp.target
            if target in known and target != imp.module:
                graph[imp.module].add(target)
                # importing a.b.c runs a and a.b first
                parts = target.split(".")
                for k in range(2, len(parts)):
                    parent = ".".join(parts[:k])
                    if parent in known and parent != imp.module:
                        if not imp.module.startswith(parent + "."):
                            graph[imp.module].add(parent)
    return _strongly_connected(graph)


def _strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def strong(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out

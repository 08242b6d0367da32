"""The package's architecture rules, checked on its source (no imports run).

* No import cycle between the package's modules (module-level and deferred
  imports alike: a cycle that only works because of import order is a cycle).
* No ``_private`` name is imported from another module.
* Each subpackage's ``__init__`` declares ``__all__``.
* ``core/`` imports nothing from ROS or from the rest of the package.
"""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "circle_collision_ros"
NAME = PACKAGE.name


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, ast.Module]:
    return {
        _module_name(p): ast.parse(p.read_text(), str(p)) for p in sorted(PACKAGE.rglob("*.py"))
    }


def _imports(name: str, tree: ast.Module, modules: dict) -> list[tuple[str, str | None, int]]:
    """(imported module, imported name or None, line) for every import in ``tree``."""
    is_pkg = (PACKAGE.parent / name.replace(".", "/") / "__init__.py").exists()
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, None, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = name.split(".") if is_pkg else name.split(".")[:-1]
                pkg = pkg[: len(pkg) - node.level + 1]
                base = ".".join(pkg + ([base] if base else []))
            for a in node.names:
                sub = f"{base}.{a.name}"
                out.append(
                    (sub, None, node.lineno) if sub in modules else (base, a.name, node.lineno)
                )
    return [x for x in out if x[0] == NAME or x[0].startswith(NAME + ".")]


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    graph = {}
    for name, tree in modules.items():
        deps = set()
        for mod, _, _ in _imports(name, tree, modules):
            # importing a.b.c runs a/__init__ and a/b/__init__ first
            parts = mod.split(".")
            deps |= {".".join(parts[:k]) for k in range(2, len(parts) + 1)}
        graph[name] = {d for d in deps if d in modules and d != name}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
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
            visit(v)
    return out


def _is_package_init_chain(importer: str, mod: str) -> bool:
    """A package's ``__init__`` importing its own submodules is the one allowed direction."""
    return mod.startswith(importer + ".")


def test_no_import_cycles():
    graph = _graph()
    # a package __init__ that re-exports its submodules depends on them; a submodule
    # importing a sibling runs the package __init__ first, which is not a cycle of
    # the code's own making, so edges into a package's own __init__ from below it
    # are left out.
    for name in graph:
        graph[name] = {d for d in graph[name] if not name.startswith(d + ".")}
    assert _cycles(graph) == []


def test_no_private_name_is_imported_from_another_module():
    modules = _modules()
    bad = [
        f"{name}:{line} imports {mod}.{imp}"
        for name, tree in modules.items()
        for mod, imp, line in _imports(name, tree, modules)
        if imp is not None
        and imp.startswith("_")
        and not imp.startswith("__")
        or imp is None
        and any(p.startswith("_") and not p.startswith("__") for p in mod.split(".")[1:-1])
    ]
    assert bad == []


def test_every_subpackage_declares_all():
    missing = [
        str(p.relative_to(PACKAGE.parent))
        for p in PACKAGE.rglob("__init__.py")
        if "__all__" not in p.read_text()
    ]
    assert missing == []


def test_core_imports_neither_ros_nor_the_rest_of_the_package():
    modules = _modules()
    bad = []
    for name, tree in modules.items():
        if not name.startswith(f"{NAME}.core"):
            continue
        for node in ast.walk(tree):
            roots = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom) and not node.level
                else []
            )
            for r in roots:
                top = r.split(".")[0]
                if (
                    top
                    in ("rclpy", "rosidl_runtime_py", "builtin_interfaces", "std_msgs",
                        "circle_collision_msgs", "nav_msgs", "geometry_msgs")
                    or r.startswith(NAME + ".")
                    and not r.startswith(f"{NAME}.core")
                ):
                    bad.append(f"{name}:{node.lineno} imports {r}")
    assert bad == []


def test_package_xml_lists_every_ros_package_the_code_imports():
    """A ROS workspace resolves exec_depend: a missing one is a node that fails to start."""
    import re

    xml = (PACKAGE.parent / "package.xml").read_text()
    declared = set(re.findall(r"<exec_depend>([\w-]+)</exec_depend>", xml))
    ros = re.compile(r"\w+_msgs$|rclpy$|builtin_interfaces$|launch(_ros)?$|ament_index_python$")
    used: dict[str, str] = {}
    files = [*PACKAGE.rglob("*.py"), *(PACKAGE.parent / "launch").glob("*.py")]
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            roots = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module] if isinstance(node, ast.ImportFrom) and not node.level
                     and node.module else [])
            for r in roots:
                if r == "rclpy.lifecycle" or r.startswith("rclpy.lifecycle."):
                    used.setdefault("lifecycle_msgs", str(path))  # its services' types
                top = r.split(".")[0]
                if ros.match(top):
                    used.setdefault(top, str(path))
    missing = {p: where for p, where in used.items() if p not in declared}
    assert missing == {}, f"package.xml lacks exec_depend for {missing}"

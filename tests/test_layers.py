"""The package layout holds: each subpackage imports only the layers below it, no module cycles.

The layer order is the one ``DEVELOPERS.md`` draws; an import anywhere in a
module (top level, inside a function, under ``TYPE_CHECKING``) counts.
"""

from __future__ import annotations

import ast
from pathlib import Path

import calib_oed

PACKAGE = Path(calib_oed.__file__).parent
#: Bottom to top; a package may import itself, the base modules and the packages before it.
LAYERS = ("model", "measurement", "feasibility", "scene", "io", "calibration", "solver",
          "oed", "program", "viz", "study", "cli")
#: Base modules every layer may import.
BASE = ("exceptions", "units", "values", "_version")
#: Packages that may import only the base modules (generic code that knows no robot).
ISOLATED = ("solver",)
MAX_LINES = 450


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path) -> set[str]:
    """calib_oed modules imported by the file at ``path`` (``from X import y`` counts X.y if a module)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("calib_oed"))
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("calib_oed"):
            assert node.level == 0, f"{path}: relative import"
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                out.add(sub if sub in _MODULES else node.module)
    return out


_FILES = sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)
_MODULES = {_module_name(p): p for p in _FILES}


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def test_every_package_is_a_known_layer():
    found = {_layer(m) for m in _MODULES if m.count(".") >= 1 and (PACKAGE / _layer(m)).is_dir()}
    assert found - {"urdf"} <= set(LAYERS), found - set(LAYERS)


def test_top_level_has_few_modules():
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert top == ["__init__.py", "__main__.py", "_version.py", "exceptions.py", "units.py", "values.py"], top


def test_layers_import_only_downwards():
    bad = []
    for module, path in _MODULES.items():
        layer = _layer(module)
        if layer not in LAYERS:  # the package face and __main__ may import anything
            assert module in ("calib_oed", "calib_oed.__main__") or layer in BASE, module
            if layer in BASE:
                extra = {_layer(m) for m in _imports(path)} - set(BASE)
                if extra:
                    bad.append(f"{module} -> {sorted(extra)}")
            continue
        if layer in ISOLATED:
            allowed = {layer, *BASE}
        else:
            allowed = {*LAYERS[: LAYERS.index(layer) + 1], *BASE}
        for target in _imports(path):
            if target == "calib_oed":
                bad.append(f"{module} -> the package face calib_oed (import from the module)")
            elif _layer(target) not in allowed:
                bad.append(f"{module} -> {target}")
    assert not bad, "imports against the layer order:\n" + "\n".join(bad)


def test_no_import_cycles_between_modules():
    graph = {m: {t for t in _imports(p) if t in _MODULES and t != m} for m, p in _MODULES.items()}
    # a package's __init__ importing its own modules is not a cycle of concepts
    for m in graph:
        graph[m] = {t for t in graph[m] if not m.startswith(t + ".") and not (
            _MODULES[t].name == "__init__.py" and m.startswith(t))}
    state: dict[str, int] = {}
    cycles = []

    def visit(node, stack):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


#: The one exceptions module (STYLE.md: every error class in one place) is a flat list of
#: small classes; it gets its own, larger limit rather than being split by responsibility.
MAX_LINES_EXCEPTIONS = 700


def test_no_module_too_long():
    def limit(m):
        return MAX_LINES_EXCEPTIONS if m == "calib_oed.exceptions" else MAX_LINES

    long = {m: n for m, p in _MODULES.items() if (n := len(p.read_text().splitlines())) > limit(m)}
    assert not long, f"modules over {MAX_LINES} lines (split by responsibility): {long}"


def test_the_checks_can_fail(tmp_path):
    """The import scanner sees function-level and TYPE_CHECKING imports (so the checks can fail)."""
    f = tmp_path / "m.py"
    f.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                 "    from calib_oed.cli import main\n"
                 "def g():\n    import calib_oed.oed.design\n")
    assert _imports(f) == {"calib_oed.cli", "calib_oed.oed.design"}

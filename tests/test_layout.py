"""The product's structure: imports point down the layers, no import circle, modules small or
saying which one thing they are, and the README's Layout naming every module."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Each layer may import the ones after it only; benchmarks may import every layer.
LAYERS = ("experiments", "agents", "checker", "jaxgrid")
PACKAGES = ("benchmarks", *LAYERS)
MAX_LINES = 500


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            mods[name.removesuffix(".__init__")] = path
    return mods


MODULES = _modules()


def _imports(path: Path) -> set[str]:
    """Product modules ``path`` imports (``from pkg import mod`` names ``pkg.mod``)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name in MODULES}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            subs = {f"{node.module}.{a.name}" for a in node.names} & MODULES.keys()
            out |= subs or ({node.module} & MODULES.keys())
    return out


GRAPH = {name: _imports(path) - {name} for name, path in MODULES.items()}


def test_imports_point_down_the_layers():
    allowed = {layer: set(LAYERS[i:]) for i, layer in enumerate(LAYERS)}
    allowed["benchmarks"] = set(PACKAGES)
    wrong = sorted((m, t) for m, ts in GRAPH.items() for t in ts
                   if t.split(".")[0] not in allowed[m.split(".")[0]])  # fmt: skip
    assert not wrong, wrong


def test_no_import_circle():
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(m, path):
        state[m] = 1
        for t in sorted(GRAPH[m]):
            if state.get(t) == 1:
                pytest.fail(f"import circle: {' -> '.join([*path[path.index(t) :], t])}")
            if t not in state:
                visit(t, [*path, t])
        state[m] = 2

    for m in sorted(GRAPH):
        if m not in state:
            visit(m, [m])


def test_long_modules_say_which_one_thing_they_are():
    long = {m: len(p.read_text().splitlines()) for m, p in MODULES.items()}
    said = {m: "One thing" in (ast.get_docstring(ast.parse(p.read_text())) or "")
            for m, p in MODULES.items()}  # fmt: skip
    unsaid = [(m, n) for m, n in long.items() if n > MAX_LINES and not said[m]]
    assert not unsaid, unsaid


def test_the_readme_layout_names_every_module():
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Layout\n.*?```\n(.*?)```", text, re.S).group(1)
    words = set(re.findall(r"[a-z_]+", block))
    missing = sorted(m for m in MODULES if m.split(".")[-1] not in words | {"__main__"}
                     and m not in PACKAGES)  # fmt: skip
    assert not missing, missing

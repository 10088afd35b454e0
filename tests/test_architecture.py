"""The package's layers: each subpackage imports only from those below it, no import cycle
between modules, and no private name imported across modules.

The order, bottom to top, is the one ``docs/architecture.md`` draws; imports under
``if TYPE_CHECKING:`` (annotations only, never run) are not counted. Imports inside functions
are counted like any other: a cycle hidden in a function is still a cycle.
"""

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "src" / "bayesmotion"

#: bottom to top; modules on one rung may import each other (within their package), never upward
LAYERS = (
    ("errors", "_config", "_version", "shapes", "validate", "compile_cache"),
    ("data",),
    ("datasets",),
    ("features",),
    ("codecs",),
    ("gp",),
    ("optim",),
    ("model",),
    ("inference",),
    ("emotion",),
    ("baselines",),
    ("evaluation",),
    ("viz",),
    ("app",),
    ("__init__", "__main__"),
)
RANK = {name: i for i, rung in enumerate(LAYERS) for name in rung}


def module_name(path: Path) -> str:
    parts = path.relative_to(PKG).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" and len(parts) > 1 else parts)


def _type_checking_nodes(tree) -> set[int]:
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for inner in node.body:
                skip.update(id(n) for n in ast.walk(inner))
    return skip


def imports_of(path: Path):
    """(imported module, [names]) of every bayesmotion import in ``path``, outside
    TYPE_CHECKING blocks. Relative imports are resolved against the module's package."""
    tree = ast.parse(path.read_text())
    skip = _type_checking_nodes(tree)
    me = module_name(path).split(".")
    pkg = me if path.name == "__init__.py" else me[:-1]
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[: len(pkg) - (node.level - 1)] if node.level > 1 else pkg
                mod = ".".join(base + ([node.module] if node.module else []))
            elif node.module and node.module.split(".")[0] == "bayesmotion":
                mod = node.module.partition(".")[2]
            else:
                continue
            yield mod, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "bayesmotion":
                    yield a.name.partition(".")[2], []


def all_modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PKG.rglob("*.py"))}


def edges() -> dict[str, set[str]]:
    """module -> the package's modules it imports (a name imported from a package that is a
    submodule counts as that submodule)."""
    mods = all_modules()
    out = {}
    for name, path in mods.items():
        targets = set()
        for mod, names in imports_of(path):
            subs = [f"{mod}.{n}" if mod else n for n in names]
            hit = [s for s in subs if s in mods]
            targets.update(hit)
            if len(hit) < len(names) or not names:
                targets.add(mod or "__init__")
        targets.discard(name)
        out[name] = targets
    return out


def rank(module: str) -> int:
    top = module.split(".")[0] or "__init__"
    return RANK[top]


def test_every_module_has_a_layer():
    unknown = sorted(m for m in all_modules() if (m.split(".")[0] or "__init__") not in RANK)
    assert not unknown, f"modules outside the declared layers: {unknown}"


def test_no_upward_import():
    bad = [f"{m} -> {t}" for m, ts in edges().items() for t in sorted(ts)
           if rank(t) > rank(m)
           or (rank(t) == rank(m) and t.split(".")[0] != m.split(".")[0]
               and rank(m) != 0)]
    assert not bad, "imports that go up (or sideways across packages):\n" + "\n".join(bad)


def test_no_import_cycle():
    graph = edges()
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for t in sorted(graph.get(m, ())):
            if state.get(t) == 1:
                cycles.append(stack[stack.index(t):] + [t])
            elif t not in state:
                visit(t)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_no_private_name_imported_across_modules():
    bad = []
    for name, path in all_modules().items():
        for mod, names in imports_of(path):
            bad += [f"{name}: from {mod} import {n}" for n in names
                    if n.startswith("_") and not n.startswith("__")
                    and f"{mod}.{n}".strip(".") not in all_modules()]
    assert not bad, "private names imported across modules:\n" + "\n".join(bad)


@pytest.mark.parametrize("fixture", ["up", "cycle", "private"])
def test_the_checks_can_fail(tmp_path, monkeypatch, fixture):
    """The three checks above catch what they claim, on a planted package."""
    pkg = tmp_path / "bayesmotion"
    (pkg / "data").mkdir(parents=True)
    (pkg / "model").mkdir()
    for d in (pkg, pkg / "data", pkg / "model"):
        (d / "__init__.py").write_text("")
    if fixture == "up":
        (pkg / "data" / "a.py").write_text("from bayesmotion.model.b import f\n")
        (pkg / "model" / "b.py").write_text("def f():\n    pass\n")
        check = test_no_upward_import
    elif fixture == "cycle":
        (pkg / "model" / "a.py").write_text("def g():\n    from bayesmotion.model import b\n")
        (pkg / "model" / "b.py").write_text("from bayesmotion.model.a import g\n")
        check = test_no_import_cycle
    else:
        (pkg / "model" / "a.py").write_text("from bayesmotion.model.b import _helper\n")
        (pkg / "model" / "b.py").write_text("def _helper():\n    pass\n")
        check = test_no_private_name_imported_across_modules
    monkeypatch.setattr(f"{__name__}.PKG", pkg)
    with pytest.raises(AssertionError):
        check()


def test_every_package_has_an_init():
    """setuptools installs only regular packages: a folder of modules without __init__.py
    would import from a source tree but be missing from the wheel."""
    missing = sorted(str(d.relative_to(PKG)) for d in PKG.rglob("*")
                     if d.is_dir() and any(d.glob("*.py")) and not (d / "__init__.py").exists())
    assert not missing, f"packages without __init__.py: {missing}"


def test_long_modules_say_they_are_one_concept():
    """A module over ~500 lines usually holds two concepts; one that does not says so first."""
    long = []
    for name, path in all_modules().items():
        text = path.read_text()
        doc = ast.get_docstring(ast.parse(text)) or ""
        if text.count("\n") > 550 and "One concept:" not in doc:
            long.append(f"{name} ({text.count(chr(10))} lines)")
    assert not long, f"split these, or name their one concept in the docstring: {long}"

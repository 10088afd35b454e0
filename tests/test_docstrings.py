"""Every documented parameter exists: the API pages are built from the docstrings (mkdocs
--strict rejects an ``Args:`` entry that is not in the signature), so the suite checks the same
rule on every public function and method of the package."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re

import bayesmotion

_ENTRY = re.compile(r"^(\*{0,2}[A-Za-z_]\w*)\s*(\([^)]*\))?\s*:")


def _documented(doc: str) -> list[str]:
    lines = inspect.cleandoc(doc).splitlines()
    names, indent, inside = [], None, False
    for line in lines:
        stripped = line.strip()
        if stripped in ("Args:", "Arguments:", "Parameters:"):
            inside, indent = True, None
            continue
        if not inside:
            continue
        if not stripped:
            continue
        depth = len(line) - len(line.lstrip())
        if depth == 0:
            inside = False
            continue
        if indent is None:
            indent = depth
        if depth == indent:
            m = _ENTRY.match(stripped)
            if m is None:
                names.append(stripped.split(":")[0])
            else:
                names.append(m.group(1).lstrip("*"))
    return names


def _public_callables():
    for info in pkgutil.walk_packages(bayesmotion.__path__, "bayesmotion."):
        if info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if name.startswith("_") or getattr(obj, "__module__", None) != module.__name__:
                continue
            if inspect.isfunction(obj):
                yield f"{module.__name__}.{name}", obj
            elif inspect.isclass(obj):
                for attr, member in vars(obj).items():
                    if attr.startswith("_") and attr != "__init__":
                        continue
                    if isinstance(member, (staticmethod, classmethod)):
                        member = member.__func__
                    if inspect.isfunction(member):
                        yield f"{module.__name__}.{name}.{attr}", member


def test_every_documented_parameter_is_in_the_signature():
    wrong = []
    for qualname, fn in _public_callables():
        if not fn.__doc__:
            continue
        params = set(inspect.signature(fn).parameters)
        for documented in _documented(fn.__doc__):
            if documented not in params:
                wrong.append(f"{qualname}: {documented!r}")
    assert not wrong, "documented but not in the signature:\n" + "\n".join(wrong)


def test_the_check_finds_a_grouped_entry():
    def f(a, b):
        """Sum.

        Args:
            a, b: numbers.
        Returns:
            a + b.
        """

    assert _documented(f.__doc__) == ["a, b"]
    assert "a, b" not in inspect.signature(f).parameters

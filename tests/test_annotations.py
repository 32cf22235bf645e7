"""Type hints on the public functions of ``scpainter_blender/core`` and ``backend``: at least ``FLOOR`` of them fully
annotated, counted over the git-tracked sources.

What counts (the rule the test applies, stated once here):

- a *public function* is a module-level ``def`` or a method of a module-level class, in a ``.py`` file under
  ``scpainter_blender/core/`` or ``backend/``, whose name and whose class's name do not start with ``_``.
  ``__init__`` counts too (its parameters are the public signature of the class, as the annotation counts of
  diffusers-style tools take them); the other dunders (``__repr__``, ``__enter__``, ...) do not. Nested functions
  and classes do not.
- it is *fully annotated* when every parameter (``*args`` and ``**kwargs`` included) except the first of a method
  (``self`` / ``cls``; a ``@staticmethod`` has none) has an annotation and the function has a return annotation.

The share was 270 of 759 (0.36) when this test was written.
"""

import ast
import collections

from tests_support import tracked_sources

FLOOR = 0.75
ROOTS = ("scpainter_blender/core/", "backend/")


def _public_functions(tree: ast.Module):
    """(name, is a method, node) of each public function of a module, as the module docstring defines them."""
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node.name, False, node
        elif isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
            for item in node.body:
                if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    yield f"{node.name}.{item.name}", True, item


def _counted(name: str) -> bool:
    last = name.rsplit(".", 1)[-1]
    return not last.startswith("_") or last == "__init__"


def fully_annotated(node: ast.FunctionDef, method: bool) -> bool:
    """Every parameter but a method's ``self``/``cls`` annotated, and the return annotated."""
    a = node.args
    params = a.posonlyargs + a.args
    static = any(isinstance(d, ast.Name) and d.id == "staticmethod" for d in node.decorator_list)
    if method and not static:
        params = params[1:]
    params = params + a.kwonlyargs + [p for p in (a.vararg, a.kwarg) if p is not None]
    return node.returns is not None and all(p.annotation is not None for p in params)


def annotation_counts() -> dict:
    """{module path: (public functions, fully annotated)} over ``ROOTS``."""
    counts = {}
    for path, text in tracked_sources().items():
        if not path.startswith(ROOTS):
            continue
        total = done = 0
        for name, method, node in _public_functions(ast.parse(text, path)):
            if _counted(name):
                total += 1
                done += fully_annotated(node, method)
        if total:
            counts[path] = (total, done)
    return counts


def test_rule_on_examples():
    """The rule itself, on signatures whose answer is known."""
    tree = ast.parse(
        "def a(x: int, *r: int, k: str = '', **kw: float) -> None: ...\n"
        "def b(x: int): ...\n"
        "def c(x) -> int: ...\n"
        "def _private(x): ...\n"
        "class K:\n"
        "    def __init__(self, x: int) -> None: ...\n"
        "    def __repr__(self): ...\n"
        "    @staticmethod\n"
        "    def s(x) -> int: ...\n"
        "    @classmethod\n"
        "    def m(cls, x: int) -> 'K': ...\n"
        "    def n(self, *args) -> None: ...\n"
        "class _Hidden:\n"
        "    def f(self): ...\n")
    seen = {name: fully_annotated(node, method) for name, method, node in _public_functions(tree) if _counted(name)}
    assert seen == {"a": True, "b": False, "c": False, "K.__init__": True, "K.s": False, "K.m": True, "K.n": False}


def test_public_functions_are_annotated():
    counts = annotation_counts()
    total = sum(t for t, _ in counts.values())
    done = sum(d for _, d in counts.values())
    share = done / total
    print(f"fully annotated: {done} of {total} public functions ({share:.3f})")
    assert total > 500, f"only {total} public functions found: the counter lost the sources"
    if share < FLOOR:
        worst = collections.Counter({p: t - d for p, (t, d) in counts.items()}).most_common(15)
        listing = "\n".join(f"  {missing:3d} of {counts[p][0]:3d} not annotated: {p}" for p, missing in worst)
        raise AssertionError(f"{done} of {total} public functions fully annotated ({share:.3f} < {FLOOR}); "
                             f"the modules with the most left:\n{listing}")

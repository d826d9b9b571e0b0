"""The package's layout: imports only downward through the stages, no cycle, no private name
borrowed from another module.

Every import of every module of ``identify`` is read from its source (those inside
functions too: an import moved into a function still ties the two modules). A module may
import from its own stage or from a stage below it (:data:`LAYERS`, bottom first), never
from one above; the modules, with all their imports, form no cycle; and no module takes a
name beginning with ``_`` from another module (``from x import _y`` or ``x._y``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "identify"
MODEL = PACKAGE.parent / "model"

#: The stages, bottom first: a module imports only from its own stage and the ones before it.
#: ``identify`` itself is the Python API (its face, on top); ``model`` is below all of them.
#: ``identify.logs`` (the ``identify`` logger and ``-v/-q``, standard library only) is in
#: the base layer because every stage logs through it, from the record loader to the CLI.
LAYERS = (
    ("identify.version", "identify.defaults", "identify.commands", "identify.logs"),
    ("identify.data",),
    ("identify.fitting",),
    ("identify.diagnosis",),
    ("identify.output",),
    ("identify.workflows",),
    ("identify.export",),
    ("identify.bench",),
    ("identify.cli",),
    ("identify.__main__", "identify"),
)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def layer(module: str) -> int:
    best, best_len = None, -1
    for index, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best_len:
                best, best_len = index, len(prefix)
    if best is None:
        raise AssertionError(f"{module} is in no layer of LAYERS: add its stage there")
    return best


def _absolute(module: str, is_package: bool, level: int, target: str | None) -> str:
    if level == 0:
        return target or ""
    base = module.split(".")
    base = base if is_package else base[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join(base + ([target] if target else []))


def imports_of(module: str) -> list[tuple[str, str | None, int]]:
    """``(imported module, name taken from it or None, line)`` for every import in ``module``."""
    path = MODULES[module]
    tree = ast.parse(path.read_text(), str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, None, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            source = _absolute(module, path.name == "__init__.py", node.level, node.module)
            for alias in node.names:
                submodule = f"{source}.{alias.name}"
                if submodule in MODULES:
                    found.append((submodule, None, node.lineno))
                else:
                    found.append((source, alias.name, node.lineno))
    return found


def _inside(module: str) -> bool:
    return module == "identify" or module.startswith("identify.")


def graph() -> dict[str, set[str]]:
    edges = {}
    for module in MODULES:
        edges[module] = set()
        for target, _, _ in imports_of(module):
            while target and target not in MODULES and _inside(target):
                target = target.rpartition(".")[0]  # an attribute path: its module
            if target in MODULES and target != module:
                edges[module].add(target)
    return edges


def test_every_module_is_in_a_layer():
    for module in MODULES:
        layer(module)


def test_no_module_imports_from_a_layer_above_it():
    upward = []
    for module in MODULES:
        for target, name, line in imports_of(module):
            if not _inside(target):
                continue
            if layer(target) > layer(module):
                upward.append(
                    f"{MODULES[module].relative_to(PACKAGE.parent)}:{line} imports {target}"
                    + (f".{name}" if name else "")
                )
    assert not upward, "imports from a higher stage:\n" + "\n".join(upward)


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(edges.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(edges):
        if node not in index:
            visit(node)
    return found


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle():
    cycles = _cycles(graph())
    assert not cycles, "import cycles (imports inside functions count):\n" + "\n".join(" <-> ".join(c) for c in cycles)


def _private(name: str | None) -> bool:
    return bool(name) and name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def test_no_private_name_is_taken_from_another_module():
    borrowed = []
    for module in MODULES:
        path = MODULES[module]
        for target, name, line in imports_of(module):
            if _inside(target) and target != module and _private(name):
                borrowed.append(f"{path.relative_to(PACKAGE.parent)}:{line} from {target} import {name}")
        # `from . import plots` ... `plots._figure`: an attribute of an imported module
        tree = ast.parse(path.read_text())
        aliases = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                source = _absolute(module, path.name == "__init__.py", node.level, node.module)
                for alias in node.names:
                    if f"{source}.{alias.name}" in MODULES:
                        aliases[alias.asname or alias.name] = f"{source}.{alias.name}"
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if _inside(alias.name) and alias.asname:
                        aliases[alias.asname] = alias.name
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and node.value.id in aliases
                and _private(node.attr)
            ):
                borrowed.append(
                    f"{path.relative_to(PACKAGE.parent)}:{node.lineno} {aliases[node.value.id]}.{node.attr}"
                )
    assert not borrowed, "private names used outside their module:\n" + "\n".join(borrowed)


def test_model_does_not_import_identify():
    for path in sorted(MODEL.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else ([node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
            )
            assert not any(_inside(n) for n in names), f"{path}: model imports identify"


@pytest.mark.parametrize("path", sorted((MODEL / "effects").glob("*.py")), ids=lambda p: p.name)
def test_the_effects_package_modules_are_small_say_what_they_hold_and_import_at_the_top(path):
    """``model/effects/``: the protocol, one module per effect and the shared filters, none
    over 1,000 lines, each opening with a docstring, every import at the module's top."""
    text = path.read_text()
    tree = ast.parse(text)
    assert len(text.splitlines()) <= 1000, f"{path.name}: {len(text.splitlines())} lines"
    assert ast.get_docstring(tree), f"{path.name}: no module docstring"
    top = {id(node) for node in tree.body}
    nested = [
        node.lineno for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom)) and id(node) not in top
    ]
    assert not nested, f"{path.name}: imports inside functions or classes at lines {nested}"


def undeclared_deferred_imports(text: str) -> list[int]:
    """Lines of the imports inside functions of ``text`` with no ``deferred`` comment: on the
    import's own line, or on the line just above it or just above the run of consecutive
    import lines it belongs to (one comment may head a block of imports)."""
    lines = text.splitlines()
    tree = ast.parse(text)
    found = set()
    for function in ast.walk(tree):
        if not isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(function):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            first = node.lineno - 1
            while first > 0 and lines[first - 1].lstrip().startswith(("import ", "from ")):
                first -= 1
            above = {lines[node.lineno - 2], lines[first - 1]} if first > 0 else set()
            comments = [line for line in above if line.lstrip().startswith("#")]
            if "deferred" not in lines[node.lineno - 1] and not any("deferred" in c for c in comments):
                found.add(node.lineno)
    return sorted(found)


def test_imports_inside_functions_say_why_they_are_deferred():
    """Imports belong at the module's top, where a reader sees what a module needs and an import
    error shows at once; an import inside a function of ``identify/`` or ``model/`` is kept
    there only for a reason worth stating (a measured start-up cost on a path that must start
    fast, such as ``--help``; an optional extra; a genuine cycle), and a comment containing
    ``deferred`` on its line, or just above it or the block of imports it opens, states it."""
    bad = {}
    for path in sorted([*PACKAGE.rglob("*.py"), *MODEL.rglob("*.py")]):
        lines = undeclared_deferred_imports(path.read_text())
        if lines:
            bad[str(path.relative_to(PACKAGE.parent))] = lines
    assert not bad, f"imports inside functions without a '# deferred: why' comment (move them to the top): {bad}"


def test_the_deferred_import_check_can_fail():
    """The check sees an unexplained import inside a function and accepts an explained block."""
    assert undeclared_deferred_imports("def f():\n    import os\n    return os\n") == [2]
    explained = "def f():\n    # deferred: an optional extra\n    import a\n    from b import c\n    return a, c\n"
    assert undeclared_deferred_imports(explained) == []
    assert undeclared_deferred_imports("import os\n\n\ndef f():\n    return os\n") == []


@pytest.mark.parametrize("bad", ["identify.data.records imports identify.cli", "cycle"])
def test_the_checks_can_fail(bad, monkeypatch):
    """The checks see a planted upward import and a planted cycle."""
    if bad == "cycle":
        edges = graph()
        edges["identify.fitting.noise"].add("identify.fitting.lsq")  # lsq imports noise
        assert _cycles(edges)
    else:
        real = imports_of

        def planted(module):
            extra = [("identify.cli", "main", 1)] if module == "identify.data.records" else []
            return real(module) + extra

        monkeypatch.setitem(globals(), "imports_of", planted)
        with pytest.raises(AssertionError, match="identify.data.records|data/records"):
            test_no_module_imports_from_a_layer_above_it()


def test_the_names_the_help_shows_are_the_models():
    """identify.defaults holds the effect and reading names for --help (no model import): the model's."""
    import model
    from identify import defaults

    assert defaults.EFFECT_NAMES == tuple(model.EFFECTS)
    assert set(defaults.READINGS) == set(model.READINGS)
    assert defaults.INPUT_READINGS == tuple(model.INPUT_READINGS)


ROOT = PACKAGE.parent


@pytest.mark.parametrize("check", [["check", "."], ["format", "--check", "."]], ids=["lint", "format"])
def test_the_code_passes_ruff(check):
    """The one formatter and linter, configured in ``pyproject.toml`` (``[tool.ruff]``): the
    whole tree is formatted and lint-clean, with no per-line skips."""
    import shutil
    import subprocess

    ruff = shutil.which("ruff")
    assert ruff is not None, "ruff is not installed: python -m pip install -e '.[test]'"
    done = subprocess.run([ruff, *check], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr


#: the per-line escapes (spelled in two parts, so this file does not hold them)
MARKERS = ("# fmt" + ": skip", "# fmt" + ": off", "# no" + "qa")


def test_no_formatter_skips():
    """No per-line formatter or linter escapes (:data:`MARKERS`): the rules live in ``pyproject.toml``."""
    marked = []
    for path in sorted(ROOT.rglob("*.py")):
        if any(part in {".git", "reports", "build"} or part.startswith(".") for part in path.relative_to(ROOT).parts):
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if any(marker in line for marker in MARKERS):
                marked.append(f"{path.relative_to(ROOT)}:{number}")
    assert not marked, marked


def test_the_diagnosis_modules_and_functions_stay_small():
    """The diagnosis shows its method (issue 63): no module of identify/diagnosis over 800
    lines, no function over 80."""
    long_modules, long_functions = [], []
    for path in sorted((PACKAGE / "diagnosis").glob("*.py")):
        text = path.read_text(encoding="utf-8")
        if text.count("\n") > 800:
            long_modules.append(f"{path.name}: {text.count(chr(10))} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno >= 80:
                long_functions.append(f"{path.name}:{node.name}: {node.end_lineno - node.lineno + 1} lines")
    assert not long_modules and not long_functions, long_modules + long_functions


# ----------------------------------------------------------------------------- module length

#: No module of ``identify`` or ``model`` is longer than this: split a longer one by what the
#: code does, each new module's docstring saying what it holds.
MAX_MODULE_LINES = 1000


def _line_counts() -> dict[str, int]:
    counts = {}
    for root in (PACKAGE, MODEL):
        for path in sorted(root.rglob("*.py")):
            counts[path.relative_to(ROOT).as_posix()] = len(path.read_text(encoding="utf-8").splitlines())
    return counts


def test_no_module_is_over_1000_lines():
    """Every module of ``identify`` and ``model`` has at most :data:`MAX_MODULE_LINES` lines."""
    long = [f"{path}: {n} lines" for path, n in _line_counts().items() if n > MAX_MODULE_LINES]
    assert not long, f"modules over {MAX_MODULE_LINES} lines (split them by what the code does): {long}"


# ----------------------------------------------------------------------------- private names in tests

TESTS = ROOT / "tests"

_FILTERS = (
    "model.effects' shared filters are one private module by design (issue 69); the test checks its "
    "table of steps against the direct step, which has no public name"
)

#: ``(test file, private name)`` -> why the test reads it. Only for a name with no public
#: equivalent; the list only shrinks (an entry no test uses any more fails the test).
PRIVATE_NAMES_IN_TESTS = {
    ("test_effects.py", "model.effects._filters"): _FILTERS,
    ("test_effects.py", "model.effects.creep._creep_kernel"): (
        "the test swaps creep's compiled kernel for its Python function (numba's py_func) as the "
        "oracle of the step table; a kernel is its effect module's internal by design"
    ),
}


def _library(dotted: str) -> bool:
    return dotted.split(".")[0] in {"identify", "model"}


def _up_to_private(dotted: str) -> str | None:
    """``dotted`` cut after its first private component (``a._b.c`` -> ``a._b``), or None."""
    parts = dotted.split(".")
    for k, part in enumerate(parts):
        if _private(part):
            return ".".join(parts[: k + 1])
    return None


def private_names_used(source: str) -> list[tuple[str, int]]:
    """``(private name, line)`` for every private name of ``identify`` or ``model`` that the
    test module ``source`` imports (``from x import _y``, ``from x._m import y``,
    ``import x._m``) or reads as an attribute of an imported library name (``lsq._y``)."""
    tree = ast.parse(source)
    bound, found = {}, []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and _library(node.module or ""):
            for alias in node.names:
                full = f"{node.module}.{alias.name}"
                bound[alias.asname or alias.name] = full
                if _up_to_private(full):
                    found.append((_up_to_private(full), node.lineno))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if not _library(alias.name):
                    continue
                bound[alias.asname or alias.name.split(".")[0]] = (
                    alias.name if alias.asname else alias.name.split(".")[0]
                )
                if _up_to_private(alias.name):
                    found.append((_up_to_private(alias.name), node.lineno))
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute):
            continue
        chain, inner = [], node
        while isinstance(inner, ast.Attribute):
            chain.append(inner.attr)
            inner = inner.value
        if isinstance(inner, ast.Name) and inner.id in bound and _private(node.attr):
            dotted = ".".join([bound[inner.id], *reversed(chain)])
            found.append((_up_to_private(dotted), node.lineno))
    return found


def test_the_private_name_finder_sees_the_three_forms():
    source = (
        "import identify.fitting.lsq as lsq\n"
        "from model.gpi import _tanh, gpi\n"
        "from model.effects._filters import distinct_steps\n"
        "from identify.fitting import noise\n"
        "lsq._fit_one_sign(1)\nnoise.whiten(2)\ngpi.__doc__\n"
    )
    assert sorted(private_names_used(source)) == [
        ("identify.fitting.lsq._fit_one_sign", 5),
        ("model.effects._filters", 3),
        ("model.gpi._tanh", 2),
    ]


def test_tests_use_no_private_name_of_the_library():
    """A test reaches the library through its public names; a private one only where the
    library has no public equivalent, listed with its reason in :data:`PRIVATE_NAMES_IN_TESTS`."""
    used = {}
    for path in sorted(TESTS.rglob("*.py")):
        for name, line in private_names_used(path.read_text(encoding="utf-8")):
            used.setdefault((path.name, name), line)
    unexpected = [
        f"{file}:{line} {name}" for (file, name), line in used.items() if (file, name) not in PRIVATE_NAMES_IN_TESTS
    ]
    stale = [key for key in PRIVATE_NAMES_IN_TESTS if key not in used]
    assert not unexpected, "tests use private names (make a public name or test the public API):\n" + "\n".join(
        unexpected
    )
    assert not stale, f"no test uses these any more: remove them from PRIVATE_NAMES_IN_TESTS: {stale}"
    assert all(reason.strip() for reason in PRIVATE_NAMES_IN_TESTS.values())

"""The architecture as a contract: no import circles between modules.

The layer contract itself (no module imports a layer above it) is ``[tool.importlinter]`` in
pyproject.toml, checked by ``make lint`` (``lint-imports``). This test adds what a layer
contract cannot see: circles between modules of one package (e.g. usecases.anomaly <->
usecases.monitoring). Every import counts, also inside functions and under TYPE_CHECKING.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "cnctwin"


def _module(path: Path) -> str:
    parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _graph() -> dict[str, set[str]]:
    modules = {_module(p): p for p in SRC.rglob("*.py")}
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for mod, path in modules.items():
        pkg = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names: list[str] = []
            if isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                                    + ([base] if base else []))
                names = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                         for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for n in names:
                while n and n not in modules:
                    n = n.rpartition(".")[0]
                # importing a package's own __init__ from inside it is not a dependency
                if n and n != mod and n != "cnctwin" and not mod.startswith(n + "."):
                    graph[mod].add(n)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
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


def test_no_import_circles() -> None:
    cycles = _cycles(_graph())
    assert cycles == [], f"import circles: {cycles}"


def test_the_cycle_finder_finds_a_circle() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_the_graph_sees_function_level_imports() -> None:
    g = _graph()
    # usecases.trials moved to the validation layer: its lazy simulator imports are edges
    assert "cnctwin.sim.scenarios" in g["cnctwin.validation.trials"]
    with pytest.raises(KeyError):
        g["cnctwin.usecases.trials"]


def test_no_test_skips_on_the_projects_own_modules() -> None:
    """``pytest.importorskip("cnctwin...")`` turns an import bug into a silent skip (issue 16)."""
    hits = [str(p.relative_to(SRC.parents[1])) for p in (SRC.parents[1] / "tests").rglob("*.py")
            if 'importorskip("cnctwin' in p.read_text(encoding="utf-8")
            and p.name != "test_architecture.py"]
    assert hits == []


def test_the_edge_runtime_does_not_load_matplotlib() -> None:
    """Footprint at the edge (issue 16): importing the runtime loads no plotting library."""
    import subprocess
    import sys

    code = "import sys, cnctwin.edge, cnctwin.cli.edge; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "False"


def test_no_frozen_or_hand_written_copies_in_the_package() -> None:
    """Issue 16, point 6: the frozen reference kernels live in tests/, the classifiers come
    from scikit-learn (no hand-written logistic regression in the installed package)."""
    import cnctwin

    root = Path(cnctwin.__file__).parent
    assert not list(root.rglob("*reference*.py"))
    hits = [p.name for p in root.rglob("*.py")
            if "def logistic_fit" in p.read_text(encoding="utf-8")]
    assert hits == []


def test_one_public_function_per_name() -> None:
    """Issue 16, point 6: no two modules of the package define a public function of the same
    name (two ``fit_friction`` and two ``moving_average`` did different things)."""
    import cnctwin

    root = Path(cnctwin.__file__).parent
    seen: dict[str, list[str]] = {}
    for p in root.rglob("*.py"):
        tree = ast.parse(p.read_text(encoding="utf-8"))
        for node in tree.body:
            if isinstance(node, ast.FunctionDef) and not node.name.startswith("_"):
                seen.setdefault(node.name, []).append(p.relative_to(root).as_posix())
    # each CLI module's `register` hook; the web package's lazy `create_app` (no FastAPI import)
    allowed = {"register", "create_app"}
    twice = {name: where for name, where in seen.items() if len(where) > 1
             and name not in allowed}
    assert twice == {}


def test_edge_import_does_not_load_plotting_or_cluster_libraries() -> None:
    """Footprint at the edge (issue 16, point 4): the runtime does not load matplotlib,
    Dask or FastAPI by being imported (each would add 30-100 MB to every edge process)."""
    import subprocess
    import sys

    code = ("import sys, cnctwin.edge, cnctwin.edge.runtime, cnctwin.edge.plant; "
            "print(sorted(m for m in ('matplotlib', 'distributed', 'fastapi', 'sklearn') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"


def test_make_demo_installs_the_package_without_extras() -> None:
    """`make demo` installs cnctwin and its run-time dependencies only (no test tools, no
    extras); `make test` adds them (issue 16, point 4; sizes in BENCHMARKS.md)."""
    text = (Path(__file__).parents[1] / "Makefile").read_text(encoding="utf-8")
    demo_rule = text.split("\n$(DEMO_STAMP):", 1)[1].split("\n\n", 1)[0]
    assert "pip install --quiet -e .\n" in demo_rule + "\n"
    assert "\ndemo: $(DEMO_STAMP)\n" in text

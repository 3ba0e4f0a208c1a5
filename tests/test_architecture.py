"""The package's import graph, read from the source (module-level and in-function imports alike):
no circle, and the layers in their order (data and agents below the config, the config below
the planner, the planner used by the command lines only)."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "r2pac_jax"


def _graph() -> dict[str, set[str]]:
    mods = {}
    for p in ROOT.rglob("*.py"):
        name = ".".join(p.relative_to(ROOT.parent).with_suffix("").parts)
        mods[name.removesuffix(".__init__")] = p

    def resolve(name: str) -> str:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name

    edges: dict[str, set[str]] = {m: set() for m in mods}
    for m, p in mods.items():
        tree = ast.parse(p.read_text())
        # `if TYPE_CHECKING:` imports name a type for the reader; nothing imports them at run time
        typing_only = {id(n) for block in ast.walk(tree) if isinstance(block, ast.If)
                       and getattr(block.test, "id", None) == "TYPE_CHECKING"
                       for n in ast.walk(block)}
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            targets = []
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("r2pac_jax"):
                targets = [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names if a.name.startswith("r2pac_jax")]
            edges[m] |= {t for t in map(resolve, targets) if t and t != m}
    return edges


def _cycle(edges):
    """One import circle as a list of modules, or None."""
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(v):
        state[v] = 1
        path.append(v)
        for w in sorted(edges[v]):
            if state.get(w) == 1:
                return path[path.index(w):] + [w]
            if w not in state and (found := visit(w)):
                return found
        state[v] = 2
        path.pop()
        return None

    for v in sorted(edges):
        if v not in state and (found := visit(v)):
            return found
    return None


def test_the_import_graph_has_no_circle():
    edges = _graph()
    assert len(edges) > 50  # the walk found the package
    assert _cycle(edges) is None, " -> ".join(_cycle(edges))


def test_a_circle_is_found_where_there_is_one():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_layers_import_only_downwards():
    edges = _graph()
    above_agents = {"r2pac_jax.config", "r2pac_jax.planner", "r2pac_jax.loop", "r2pac_jax.train",
                    "r2pac_jax.table", "r2pac_jax.sweep", "r2pac_jax.lanes"}
    for m, deps in edges.items():
        if m.startswith(("r2pac_jax.agents", "r2pac_jax.data", "r2pac_jax.envs")):
            assert not deps & above_agents, f"{m} imports {sorted(deps & above_agents)}"
    clis = {"r2pac_jax.train", "r2pac_jax.table", "r2pac_jax.sweep"}
    users = {m for m, deps in edges.items() if "r2pac_jax.planner" in deps}
    assert users == clis, f"the planner is used by {sorted(users)}; only the command lines plan"
    assert "r2pac_jax.planner" not in edges["r2pac_jax.config"]

"""The package's shape, read from its source: the floors of docs/extending.md (each imports only
from its own floor or below), no import circle, and private names shared only inside a wing."""

import ast
import collections
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1] / "ppr_jax"

#: the floors, top first, as docs/extending.md draws them; a room is a top-level module or a wing
FLOORS = [
    ("command line", ["_cli"]),
    ("studies", ["_studies"]),
    ("scenes", ["_scenes"]),
    ("solvers and signals", ["_simulate", "_lean", "_rosw", "_esdirk", "_statics", "_modes",
                             "_metrics", "_tabulated"]),
    ("actuation and paths", ["_actuation", "_trajectory", "_paths"]),
    ("dynamics and kinematics", ["_dynamics", "_kinematics", "_paper_eom", "_assembly"]),
    ("models", ["_models", "_mjcf"]),
    ("chain geometry", ["_geometry", "_linalg", "_fusion"]),
    ("robot and joint", ["_robot", "_prb", "_params", "_params_file", "_prb_table", "_prb_fit",
                         "elastica"]),
    ("infrastructure", ["_errors", "_custom_types", "_data", "_cache", "_devices", "_programs",
                        "_labels", "_names", "_files", "_dispatch", "_host_split"]),
]
FLOOR = {room: len(FLOORS) - i for i, (_, rooms) in enumerate(FLOORS) for room in rooms}


def _modules():
    mods = {}
    for p in ROOT.rglob("*.py"):
        parts = list(p.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = p
    return mods


def _imports():
    """(module, target module, imported name) for every relative import, top level or inside a
    function (a lazy import is still a dependency)."""
    mods = _modules()
    out = []
    for m, p in mods.items():
        pkg = m.split(".") if p.name == "__init__.py" else m.split(".")[:-1]
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                base = pkg[:len(pkg) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
                for alias in node.names:
                    full = f"{target}.{alias.name}"
                    out.append((m, full if full in mods else target, alias.name,
                                full in mods))
    return mods, out


def _room(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def test_every_room_has_a_floor():
    mods, _ = _modules(), None
    rooms = {_room(m) for m in mods if m != "ppr_jax"}
    assert rooms - set(FLOOR) == set(), "a new module needs a floor in FLOORS and the docs"
    assert set(FLOOR) - rooms == set(), "a floor names a module that is gone"


def test_no_upward_import():
    _, imports = _imports()
    up = sorted({(m, t) for m, t, _, _ in imports
                 if m != "ppr_jax" and t != "ppr_jax" and _room(m) != _room(t)
                 and FLOOR[_room(t)] > FLOOR[_room(m)]})
    assert up == [], f"imports from a higher floor: {up}"


def test_no_import_circle():
    mods, imports = _imports()
    edges = collections.defaultdict(set)
    for m, t, _, _ in imports:
        if t in mods and t != m:
            edges[m].add(t)
    state, circles = {}, []

    def visit(u, path):
        state[u] = "open"
        path.append(u)
        for v in sorted(edges[u]):
            if state.get(v) == "open":
                circles.append(path[path.index(v):] + [v])
            elif v not in state:
                visit(v, path)
        path.pop()
        state[u] = "done"

    for m in sorted(mods):
        if m not in state:
            visit(m, [])
    assert circles == []


def test_private_names_stay_inside_their_wing():
    _, imports = _imports()
    crossing = sorted((m, t, name) for m, t, name, is_module in imports
                      if name.startswith("_") and not is_module and _room(m) != _room(t))
    assert crossing == []


@pytest.mark.parametrize("wing", ["_scenes", "_studies", "_cli"])
def test_other_rooms_use_a_wing_through_its_front(wing):
    """Outside a wing, its modules are reached through the wing's `__init__` only."""
    _, imports = _imports()
    inside = sorted({(m, t) for m, t, _, _ in imports
                     if _room(t) == wing and _room(m) != wing and t != f"ppr_jax.{wing}"
                     and m != "ppr_jax"})
    assert inside == []

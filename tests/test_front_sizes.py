"""The studies' entry points are thin fronts over their helpers (as optimistix's
`least_squares` over one `iterative_solve`), read from the source: at most 150 lines each,
docstring included, and a bounded number of parameters (the choices grouped in option objects,
as diffrax's `diffeqsolve` takes them: `SceneOptions`, `FitOptions`)."""

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1] / "ppr_jax"

#: (module, function, most lines, most parameters: every one, `*args` and `**kwargs` included;
#: None: not bounded)
FRONTS = [
    ("_studies/_identify/_identify.py", "identify", 150, 15),
    ("_studies/_design/_design.py", "design", 150, None),
    ("_studies/_sweep.py", "sweep", 150, None),
    ("_studies/_sensitivity.py", "sensitivity", 150, None),
    ("_studies/_identify/_synthesize.py", "synthesize", 150, None),
    ("_studies/_compensate.py", "compensate", 150, None),
]


def _function(path: str, name: str) -> ast.FunctionDef:
    tree = ast.parse((ROOT / path).read_text(encoding="utf-8"))
    found = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == name]
    assert len(found) == 1, f"{path} defines {name} {len(found)} times at its top level"
    return found[0]


def _parameters(fn: ast.FunctionDef) -> list:
    a = fn.args
    names = [p.arg for p in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    return names + [p.arg for p in (a.vararg, a.kwarg) if p is not None]


@pytest.mark.parametrize("path, name, most_lines, most_params", FRONTS,
                         ids=[f[1] for f in FRONTS])
def test_front_is_thin(path, name, most_lines, most_params):
    fn = _function(path, name)
    first = min([fn.lineno, *(d.lineno for d in fn.decorator_list)])
    lines = fn.end_lineno - first + 1
    assert lines <= most_lines, f"{name} ({path}) is {lines} lines, at most {most_lines}"
    params = _parameters(fn)
    assert most_params is None or len(params) <= most_params, (
        f"{name} takes {len(params)} parameters, at most {most_params}: {params}")


def test_size_reading_counts_every_parameter_and_line():
    """The reading itself, on a function written here: 3 lines, 5 parameters (a positional,
    a keyword-only, *args and **kwargs counted too)."""
    fn = ast.parse("def f(a, /, b, *c, d=1, **e):\n    x = 1\n    return x\n").body[0]
    assert _parameters(fn) == ["a", "b", "d", "c", "e"]
    assert fn.end_lineno - fn.lineno + 1 == 3

"""Every public function with more than three parameters documents them in diffrax's dialect:
an `**Arguments:**` section and a `**Returns:**` section in its docstring (the API pages render
them). Nothing is compiled: the docstrings are read from the imported functions."""

import inspect

import ppr_jax

#: public functions still to be rewritten into the sections (emptied as they are)
PENDING: set = set()


def _long_functions():
    """The public functions (`ppr_jax.__all__`) with more than three parameters."""
    out = {}
    for name in ppr_jax.__all__:
        obj = getattr(ppr_jax, name)
        if inspect.isfunction(obj) and len(inspect.signature(obj).parameters) > 3:
            out[name] = obj
    return out


def test_long_functions_have_arguments_and_returns():
    missing = []
    for name, fn in sorted(_long_functions().items()):
        doc = fn.__doc__ or ""
        lacks = [s for s in ("**Arguments:**", "**Returns:**") if s not in doc]
        if lacks and name not in PENDING:
            missing.append(f"{name} ({inspect.getsourcefile(fn)}): no {', '.join(lacks)}")
    assert not missing, "docstrings without their sections:\n" + "\n".join(missing)


def test_pending_list_is_current():
    # a name that is documented (or no longer public) leaves the allowlist, so it cannot hide
    # a later regression
    funcs = _long_functions()
    stale = sorted(
        name for name in PENDING
        if name not in funcs
        or all(s in (funcs[name].__doc__ or "") for s in ("**Arguments:**", "**Returns:**"))
    )
    assert not stale, f"documented or gone, remove from PENDING: {stale}"

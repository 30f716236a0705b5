"""The metric catalogue is the one list of metrics: every study's and the command line's lists
are read from it, and a new metric is one entry there (docs/extending.md's recipe).

The entry added here (the largest error of the platform's x against the path) is checked
against numpy on the scene's own run (`run_scene`), through a sweep's column and a
sensitivity's value (whose `Evaluation` a design evaluates too; tests/test_extending.py's slow
test checks the derivative against central differences). Cheap settings: L1 under L0's
torques on 0.3 s of the paper circle."""

import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._errors import PPRError
from ppr_jax._names import PATH_SENSITIVITY_METRICS, SENSITIVITY_METRICS
from ppr_jax._studies import (
    CATALOGUE,
    METRICS,
    Metric,
    allowed_metrics,
    design_metrics,
    sweep_metrics,
)

STUDIES = ("sweep", "sensitivity", "design")
#: the new metric, as the page writes it
NEW = Metric("m", "the largest error of the platform's x against the path",
             lambda i: jnp.max(jnp.abs(i.result.X[:, 0] - i.result.X_nominal[:, 0])),
             tracking=True)
LINE = pj.Line(start=(0.40, 0.27, 0.0), end=(0.49, 0.24, 0.03), duration=1.0)
KW = dict(model="reduced", torque_model="rigid", options=pj.SceneOptions(t_end=0.3, n_out=7))


@pytest.fixture
def added(monkeypatch):
    monkeypatch.setitem(CATALOGUE, "x_error_max_m", NEW)


def test_every_list_is_the_catalogue():
    """No compilation: the sweep's columns, the sensitivity's and the design's metrics, the
    defaults and `DESIGN_METRICS` are catalogue entries, nested as the studies' fields say,
    and a path that is not a circle drops the radial errors."""
    circle = pj.Circle()
    for study in STUDIES:
        names = allowed_metrics(circle, study)
        assert names and set(names) <= set(CATALOGUE)
        assert all(study in CATALOGUE[n].studies for n in names)
        line = allowed_metrics(LINE, study)
        assert set(line) == {n for n in names if not CATALOGUE[n].circle}
    assert sweep_metrics(circle) == METRICS == allowed_metrics(circle, "sweep")
    assert set(sweep_metrics(circle)) < set(allowed_metrics(circle, "sensitivity"))
    assert set(allowed_metrics(circle, "sensitivity")) < set(design_metrics(circle))
    assert set(design_metrics(circle)) == set(CATALOGUE) == set(pj.DESIGN_METRICS)
    # without a scene: what needs neither a path nor a run
    assert set(design_metrics()) == {n for n, m in CATALOGUE.items()
                                     if m.needs in ("robot", "pose")}
    assert set(SENSITIVITY_METRICS) <= set(allowed_metrics(circle, "sensitivity"))
    assert set(PATH_SENSITIVITY_METRICS) <= set(allowed_metrics(LINE, "sensitivity"))
    with pytest.raises(PPRError, match="unknown study 'fit'"):
        allowed_metrics(circle, "fit")


def test_one_entry_is_allowed_by_every_study(added):
    for study in STUDIES:
        assert "x_error_max_m" in allowed_metrics(pj.Circle(), study)
        assert "x_error_max_m" in allowed_metrics(LINE, study)
    assert "x_error_max_m" not in design_metrics()  # it needs a scene's run


@pytest.mark.slow  # second tier: docs/getting_started.md, 'The two tiers'
def test_one_entry_is_computed_by_every_study(added):
    rep = pj.run_scene("paper-circle", **KW)
    X, Xn = np.asarray(rep.result.X), np.asarray(rep.result.X_nominal)
    ref = float(np.abs(X[:, 0] - Xn[:, 0]).max())
    assert ref > 1e-6  # L1 under L0's torques leaves the circle
    sw = pj.sweep("paper-circle", vary={"t": [float(rep.params.t)]}, **KW)
    assert "x_error_max_m" in sw.columns
    np.testing.assert_allclose(sw.rows[0]["x_error_max_m"], ref, rtol=1e-9)
    s = pj.sensitivity("paper-circle", parameters=["t"], metrics=["x_error_max_m"], **KW)
    np.testing.assert_allclose(s.values["x_error_max_m"], ref, rtol=1e-9)
    assert np.isfinite(s.jacobian[0, 0]) and s.jacobian[0, 0] != 0

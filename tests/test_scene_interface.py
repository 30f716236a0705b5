"""The scene interface: a user's own scene (here a straight line, not a circle) runs through the
same `AbstractScene.run` as the built-in ones, and failures are told by their cause."""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj


class Line(eqx.Module):
    """A straight segment from `start` to `end` (x, y, phi) with a cosine time law over
    `duration` seconds (rest to rest): the closed form the test compares with."""

    start: jax.Array = eqx.field(default_factory=lambda: jnp.array([0.40, 0.27, 0.0]))
    end: jax.Array = eqx.field(default_factory=lambda: jnp.array([0.49, 0.24, 0.03]))
    duration: float = 1.0

    def __call__(self, t):
        s = 0.5 * (1 - jnp.cos(jnp.pi * jnp.clip(t / self.duration, 0.0, 1.0)))
        return self.start + s * (self.end - self.start)


class LineScene(pj.AbstractScene):
    """Torques of L1's inverse dynamics along the line (exact, not tabulated)."""

    name: ClassVar[str] = "line"
    thickness: ClassVar[float] = 0.3e-3
    reference: ClassVar[dict] = {}

    def trajectory(self):
        return Line()

    def commands(self, model, robot, traj, ts, panels):
        return pj.SceneInput(pj.TorqueDriven(pj.InverseDynamicsTorque(pj.Reduced(), robot, traj)))

    def follows_its_input(self, model):
        return "its own inverse-dynamics torques" if model.name == "reduced" else ""


OPTIONS = pj.SceneOptions(t_end=1.0, n_out=21)


def _closed_form(ts):
    line = Line()
    s = 0.5 * (1 - np.cos(np.pi * np.clip(ts / line.duration, 0.0, 1.0)))
    return np.asarray(line.start) + s[:, None] * (np.asarray(line.end) - np.asarray(line.start))


@pytest.fixture(scope="module")
def line_report():
    return pj.run_scene(LineScene(), model="reduced", t_end=OPTIONS.t_end, n_out=OPTIONS.n_out)


def test_own_scene_with_a_line_follows_the_closed_form(line_report):
    """L1 driven by its own inverse-dynamics torques follows the path it was computed for: the
    pose at every output time is the closed-form line to the integrator's tolerance."""
    r = line_report.result
    assert r.ok and r.scene == "line" and r.model == "reduced"
    ref = _closed_form(np.asarray(r.ts))
    err = np.abs(np.asarray(r.X) - ref).max()
    assert err < 1e-7, err
    # and the gap is the integrator's: it shrinks with the tolerance (same program: tolerances
    # are inputs)
    tight = pj.solve_scene(LineScene(), model="reduced",
                           options=pj.SceneOptions(t_end=1.0, n_out=21, rtol=1e-11, atol=1e-13))
    err_tight = np.abs(np.asarray(tight.X) - ref).max()
    assert err_tight < err / 20, (err_tight, err)
    # the nominal pose the result carries is the scene's path
    np.testing.assert_allclose(r.X_nominal, ref, rtol=0, atol=1e-15)
    # the path moves: a wrong scene (a held pose) would not pass the comparison above
    assert np.abs(ref[-1] - ref[0]).max() > 0.02


def test_metric_table_of_a_path_that_is_not_a_circle(line_report):
    """The circle's radial errors are not reported for a line; the path-generic ones are, and
    agree with the same quantities computed here from the signals."""
    m = line_report.metrics
    assert "radial_error_max_m" not in m
    r = line_report.result
    ref = _closed_form(np.asarray(r.ts))
    pos = np.hypot(*(np.asarray(r.X)[:, :2] - ref[:, :2]).T).max()
    np.testing.assert_allclose(m["position_error_max_m"], pos, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(m["torque_peak_Nm"], np.abs(np.asarray(r.tau)).max(), rtol=1e-14)
    np.testing.assert_allclose(m["constraint_residual_max_m"], np.max(r.residual), rtol=1e-14)


def test_solve_scene_takes_the_scene_instance_and_options(line_report):
    r = pj.solve_scene(LineScene(), model="reduced", options=OPTIONS)
    np.testing.assert_allclose(r.X, line_report.result.X, rtol=0, atol=1e-14)


def test_scene_options_name_the_bad_argument():
    with pytest.raises(pj.PPRError, match=r"rtol.*1e-14.*0\.01"):
        pj.SceneOptions(rtol=0.5).check()
    with pytest.raises(pj.PPRError, match="n_out"):
        pj.solve_scene("paper-circle", options=pj.SceneOptions(n_out=1))


def test_unknown_scene_lists_the_known_ones():
    with pytest.raises(pj.PPRError, match="paper-circle, servo-circle"):
        pj.solve_scene("square")


def test_a_solver_failure_says_where_it_stopped_not_a_residual():
    """A step budget too small for the horizon: the reason is the solver's, with the last
    output time reached, and no loop-closure residual of the unreached (inf) times."""
    res = pj.paper_circle(model="rigid", t_end=0.5, n_out=11, max_steps=3, throw=False)
    (reason,) = res.failures().values()
    assert "maximum number of solver steps" in reason, reason
    assert "last output time reached is t = " in reason, reason
    assert "nan" not in reason and "inf" not in reason and "residual" not in reason, reason


def test_an_invalid_parameter_inside_a_program_is_named():
    """A parameter set past `RobotParams`' checks (as a transformation may) is reported as an
    invalid parameter naming it and its allowed range, not as a residual."""
    p = eqx.tree_at(lambda q: q.t, pj.scene_params("paper-circle"), jnp.asarray(-1e-3))
    with pytest.raises(pj.SimulationError, match=r"t = -0\.001 m not in \[1e-06, 0\.01\]"):
        pj.paper_circle(p, model="rigid", t_end=0.5, n_out=11, max_steps=3)

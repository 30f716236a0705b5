"""Bad and extreme inputs, as a user types them by mistake or explores on purpose.

For each one: a `PPRError` (the library's base error, a `ValueError`) naming the cause, or a result
whose checks pass; the CLI answers with one line on stderr and exit status 2, never a traceback.
The eager checks run before anything is compiled, so most of this module costs no compilation;
the compiled cases share one small program per scene.
"""

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import ppr_jax as pj
from ppr_jax._cli import main
from ppr_jax._params import PARAM_RANGES, parse_value

NAMES = sorted(PARAM_RANGES)


# ---------------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(
    name=st.sampled_from(NAMES),
    value=st.one_of(
        st.floats(allow_nan=True, allow_infinity=True),
        st.floats(min_value=-1e3, max_value=1e3),
        st.sampled_from([0.0, -0.0, 1e-300, -1e-9, math.nan, math.inf, -math.inf]),
    ),
)
def test_any_parameter_value_is_accepted_iff_in_range(name, value):
    lo, hi, _, _ = PARAM_RANGES[name]
    ok = math.isfinite(value) and lo <= value <= hi
    if ok:
        assert float(getattr(pj.RobotParams(**{name: value}), name)) == value
        return
    with pytest.raises(pj.PPRError) as info:
        pj.RobotParams(**{name: value})
    msg = str(info.value)
    assert repr(name) in msg and "allowed range" in msg
    if not math.isfinite(value):
        assert "not finite" in msg


@pytest.mark.parametrize("sigma", [0, 2, 0.5, True, -3])
def test_sigma_must_be_plus_or_minus_one(sigma):
    with pytest.raises(pj.PPRError, match="sigma"):
        pj.RobotParams(sigma=sigma)


@pytest.mark.parametrize("text", ["1.5", "-0.9", "0", "nan", "one"])
def test_sigma_on_the_command_line_is_not_truncated(text):
    with pytest.raises(pj.PPRError, match="sigma.*-1 or \\+1"):
        parse_value("sigma", text)


def test_stack_params_names_the_bad_member():
    good = pj.RobotParams()
    # tree_at bypasses the constructor's check, as a user's own pytree surgery would
    bad = eqx.tree_at(lambda p: p.t, good, jnp.asarray(-1e-3))
    with pytest.raises(pj.PPRError, match=r"member 2:.*'t'"):
        pj.stack_params([good, good, bad])
    with pytest.raises(pj.PPRError, match="member 1 has sigma"):
        pj.stack_params([good, good.replace(sigma=1)])
    with pytest.raises(pj.PPRError, match="member 1 gives gamma"):
        pj.stack_params([good, good.replace(gamma=0.85)])
    with pytest.raises(pj.PPRError, match="at least one"):
        pj.stack_params([])


# ---------------------------------------------------------------------------------------------
# Scene arguments: checked before any compilation
# ---------------------------------------------------------------------------------------------

BAD_SCENE_ARGS = [
    (dict(t_end=-1.0), "t_end"),
    (dict(t_end=0.0), "t_end"),
    (dict(t_end=math.nan), "t_end must be finite"),
    (dict(t_end=math.inf), "t_end must be finite"),
    (dict(n_out=1), "n_out"),
    (dict(n_out=2.5), "n_out must be an integer"),
    (dict(rtol=0.0), "rtol"),
    (dict(rtol=-1e-6), "rtol"),
    (dict(rtol=0.5), "rtol"),
    (dict(rtol=math.nan), "rtol must be finite"),
    (dict(atol=-1.0), "atol"),
    (dict(max_steps=0), "max_steps"),
    (dict(max_steps=10.5), "max_steps must be an integer"),
    (dict(solver="rk45"), "unknown solver"),
    (dict(model="L2"), "unknown model"),
]


@pytest.mark.parametrize("scene", [pj.paper_circle, pj.servo_circle])
@pytest.mark.parametrize("kw,msg", BAD_SCENE_ARGS)
def test_scene_arguments_are_validated_first(scene, kw, msg):
    with pytest.raises(pj.PPRError, match=msg) as info:
        scene(**kw)
    assert "allowed" in str(info.value)


def _simulate_args():
    p = pj.RobotParams()
    m = pj.Rigid()
    z0 = m.coords_from_pose(pj.Robot(p), pj.home_pose(p))
    return m, p, pj.TorqueDriven(pj.Hold(jnp.zeros(3))), z0, jnp.zeros_like(z0), \
        jnp.linspace(0.0, 0.1, 3)


@pytest.mark.parametrize("kw,msg", [
    (dict(rtol=-1), r"rtol = -1 is out of its allowed range"),
    (dict(rtol=1), r"rtol = 1 is out of its allowed range"),
    (dict(rtol=0.0, atol=0.0), r"rtol and atol are both 0"),
    (dict(rtol=math.nan), r"rtol must be finite: nan is not finite"),
    (dict(atol=math.inf), r"atol must be finite: inf is not finite"),
    (dict(max_steps=0), r"max_steps = 0 is out of its allowed range"),
    (dict(z0=math.nan), r"z0 is not finite \(NaN or inf at entries 1\)"),
    (dict(zdot0=math.inf), r"zdot0 is not finite"),
    (dict(wrench=[0.0, math.nan, 0.0]), r"wrench is not finite \(NaN or inf at entries 1\)"),
    (dict(wrench=[0.0, 1.0]), r"wrench must have shape \(3,\)"),
    (dict(ts=[0.0, math.nan]), r"ts is not finite"),
])
def test_simulate_arguments_are_validated_first(kw, msg):
    """Before, rtol=-1 was accepted, and NaN in a tolerance, the state or the wrench ran
    200,000 steps to report "maximum number of solver steps" with advice about stiffness."""
    m, p, act, z0, zd0, ts = _simulate_args()
    if "z0" in kw:
        z0, kw = z0.at[1].set(kw["z0"]), {}
    if "zdot0" in kw:
        zd0, kw = zd0.at[0].set(kw["zdot0"]), {}
    if "ts" in kw:
        ts, kw = kw["ts"], {}
    with pytest.raises(pj.PPRError, match=msg):
        pj.simulate(m, p, act, z0, zd0, ts, **kw)


def test_kinematics_of_nan_inputs_are_named():
    """Before, inverse kinematics of a NaN pose returned NaN angles without a word."""
    p = pj.RobotParams()
    with pytest.raises(pj.PPRError, match=r"X is not finite \(NaN or inf at entries 2\)"):
        pj.inverse_kinematics(p, [0.45, 0.26, math.nan])
    with pytest.raises(pj.PPRError, match=r"X is not finite \(NaN or inf at entries \(1, 0\)"):
        pj.inverse_kinematics(p, [[0.45, 0.26, 0.0], [math.nan, 0.26, 0.0]])
    with pytest.raises(pj.PPRError, match=r"th_a is not finite"):
        pj.forward_kinematics(p, [0.1, math.inf, 0.2])
    with pytest.raises(pj.PPRError, match=r"X_guess is not finite"):
        pj.forward_kinematics(p, [0.1, 0.1, 0.2], X_guess=[math.nan, 0.0, 0.0])
    with pytest.raises(pj.PPRError, match=r"th_a_path is not finite"):
        pj.forward_kinematics_path(p, [[0.1, 0.1, 0.2], [0.1, math.nan, 0.2]])
    with pytest.raises(pj.PPRError, match=r"X must be an array of numbers"):
        pj.inverse_kinematics(p, "0.45, 0.26, 0")
    batch = pj.stack_params([p, pj.RobotParams(t=0.4e-3)])
    with pytest.raises(pj.PPRError, match=r"inverse_kinematics takes one robot, got a batch of 2"):
        pj.inverse_kinematics(batch, [0.45, 0.26, 0.0])
    with pytest.raises(pj.PPRError, match=r"forward kinematics takes one robot"):
        pj.forward_kinematics(batch, [0.1, 0.1, 0.2])


@pytest.mark.parametrize("n", [0, 1, 2.5, 10_000, "eight"])
def test_beam_element_count_has_bounds(n):
    with pytest.raises(pj.PPRError, match="elements"):
        pj.get_model("beam", n)


@pytest.mark.parametrize("kw,msg", [
    (dict(rtol=math.nan), "rtol must be finite"),
    (dict(rtol=1.0), "rtol = 1.0 is out of its allowed range"),
    (dict(max_steps=0), "max_steps = 0 is out of its allowed range"),
    (dict(t_end=math.nan), "t_end must be finite"),
])
def test_sweep_and_sensitivity_check_the_scene_arguments(kw, msg):
    """Before, a sweep at rtol NaN ran every member to max_steps, max_steps 0 failed every member
    inside diffrax, and rtol 1 was accepted by both."""
    with pytest.raises(pj.PPRError, match=msg):
        pj.sweep("paper-circle", vary={"t": [0.3e-3, 0.4e-3]}, **kw)
    with pytest.raises(pj.PPRError, match=msg):
        pj.sensitivity("paper-circle", **kw)


def test_strings_poses_and_noise_are_checked_at_the_door():
    """Before: t_end "0.5" ended in a raw JAX TypeError; a two-number pose gave the home modes
    (or blamed the load); a NaN noise wrote a file whose x and y were all NaN."""
    with pytest.raises(pj.PPRError, match=r"t_end must be a number, got '0.5'"):
        pj.paper_circle(t_end="0.5")
    with pytest.raises(pj.PPRError, match=r"X must have shape \(3,\), got \(2,\)"):
        pj.modes(pj.Double1R(), pj.RobotParams(), [0.45, 0.26], actuators="free")
    with pytest.raises(pj.PPRError, match=r"X is not finite"):
        pj.modes(pj.Double1R(), pj.RobotParams(), [0.45, math.nan, 0.0])
    with pytest.raises(pj.DataError, match=r"noise_pos must be finite: nan is not finite"):
        pj.synthesize(noise_pos=math.nan)


# ---------------------------------------------------------------------------------------------
# The command line: one line on stderr, exit status 2
# ---------------------------------------------------------------------------------------------

BAD_CLI = [
    (["simulate", "--set", "t=-1"], "'t'"),
    (["simulate", "--set", "t=nan"], "finite"),
    (["simulate", "--set", "sigma=1.5"], "sigma"),
    (["simulate", "--rtol", "-1"], "rtol"),
    (["simulate", "--rtol", "0"], "rtol"),
    (["simulate", "--t-end", "-1"], "t_end"),
    (["simulate", "--t-end", "nan"], "t_end"),
    (["simulate", "--n-out", "1"], "n_out"),
    (["simulate", "--max-steps", "0"], "max_steps"),
    (["simulate", "--model", "beam", "--elements", "0"], "elements"),
    (["simulate", "--model", "beam", "--elements", "100000"], "elements"),
    (["simulate", "--model", "L2"], "unknown model"),
    (["simulate", "--out", "FILE"], "is a file"),
    (["torques", "--out", "FILE"], "is a file"),
    (["modes", "--set", "E=-5"], "'E'"),
    (["sweep", "--vary", "t=0.3e-3,0.4e-3", "--rtol", "nan", "--out", "OUT"], "rtol"),
    (["sweep", "--vary", "t=0.3e-3,0.4e-3", "--rtol", "1", "--out", "OUT"], "rtol"),
    (["sweep", "--vary", "t=0.3e-3,0.4e-3", "--max-steps", "0", "--out", "OUT"], "max_steps"),
    (["sensitivity", "--rtol", "1", "--out", "OUT"], "rtol"),
    (["modes", "--pose", "0.45,0.26"], "--pose expects x,y,phi"),
    (["synth", "--noise-pos", "nan", "--out", "OUT"], "noise_pos must be finite"),
]


@pytest.mark.parametrize("argv,msg", BAD_CLI)
def test_cli_user_errors_are_one_line(tmp_path, capsys, argv, msg):
    f = tmp_path / "a_file"
    f.write_text("x")
    argv = [str(f) if a == "FILE" else str(tmp_path / "out") if a == "OUT" else a for a in argv]
    if "--out" not in argv and argv[0] in ("simulate", "torques"):
        argv += ["--out", str(tmp_path / "out")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("ppr-jax: error:") and msg in lines[0]
    assert "Traceback" not in err


# ---------------------------------------------------------------------------------------------
# Physics preconditions inside compiled scenes: status codes per member, nothing lost
# ---------------------------------------------------------------------------------------------

SHORT = dict(t_end=0.3, n_out=31)


@pytest.fixture(scope="module")
def open_chain_batch():
    """A batch with a robot whose chains cannot close (base side a = 3 m) between two good ones:
    the case that used to 'simulate' a perfect circle on a 1.8 m open loop."""
    p = pj.scene_params("paper-circle")
    batch = pj.stack_params([p, p.replace(a=3.0), p.replace(t=0.4e-3)])
    return pj.paper_circle(batch, model="reduced", throw=False, **SHORT)


def test_open_chain_fails_its_member_and_keeps_the_others(open_chain_batch):
    r = open_chain_batch
    np.testing.assert_array_equal(r.ok, [True, False, True])
    f = r.failures()
    # The residual named is the stretched chain's gap: L1's closed form clips the chain's
    # cosine at full stretch, so the farthest chain misses its platform joint by
    # |E_i - A_i| - (r1 + r2 + r3) (here from the geometry at the path's start), to within
    # the 0.01 rad its diverging Newton correction may turn the links.
    p = pj.scene_params("paper-circle").replace(a=3.0)
    rob, X = pj.Robot(p), np.asarray(pj.Circle()(0.0))
    a = float(p.a)
    A = np.array([[0.0, 0.0], [a, 0.0], [a / 2, a * np.sqrt(3) / 2]])
    beta = np.array([7, -1, 3]) * np.pi / 6
    E = X[:2] + float(rob.rho_E) * np.stack([np.cos(beta + X[2]), np.sin(beta + X[2])], -1)
    gap = float(np.max(np.linalg.norm(E - A, axis=1) - float(rob.r1 + rob.r2 + rob.r3)))
    assert list(f) == [1] and "reach" in f[1] and f"residual {gap:.3g} m" in f[1], (f[1], gap)
    for i in (0, 2):
        assert np.all(np.isfinite(r.X[i])) and float(np.max(r.residual[i])) < 1e-9
        # the good members still follow the circle to a few mm in 0.3 s of open loop
        er = np.linalg.norm(r.X[i][:, :2] - r.X_nominal[i][:, :2], axis=-1)
        assert float(er.max()) < 5e-3


def test_open_chain_raises_with_the_result_attached(open_chain_batch):
    p = pj.scene_params("paper-circle")
    batch = pj.stack_params([p, p.replace(a=3.0), p.replace(t=0.4e-3)])
    with pytest.raises(pj.SimulationError, match=r"1 of 3 batch members.*member 1:.*reach"
                       ) as info:
        pj.paper_circle(batch, model="reduced", **SHORT)
    kept = info.value.result
    np.testing.assert_allclose(kept.X[0], open_chain_batch.X[0], rtol=0, atol=1e-12)


def test_circle_partly_outside_the_workspace_is_an_error():
    """Motion-driven L1 (kinematics only): a circle of radius 0.32 m starts inside the chains'
    reach and leaves it after about 0.06 s; a circle of 0.3 m stays inside and succeeds."""
    p = pj.scene_params("servo-circle")
    with pytest.raises(pj.SimulationError, match="servo-circle.*leaves the chains. reach"):
        pj.servo_circle(p, model="reduced", **SHORT,
                        trajectory=pj.Circle(radius=jnp.asarray(0.32), omega=jnp.asarray(5.0)))
    r = pj.servo_circle(p, model="reduced", **SHORT,
                        trajectory=pj.Circle(radius=jnp.asarray(0.3), omega=jnp.asarray(5.0)))
    assert float(np.max(r.residual)) < 1e-9
    np.testing.assert_allclose(r.X, r.X_nominal, atol=1e-9)

"""Our generic (Kane) equations of motion against two independent formulations: the paper's
closed form (eqs 30-35, 41, 47, 54) and automatic differentiation of the Lagrangian."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import ppr_jax as pj
from ppr_jax._dynamics import lagrangian_eom
from ppr_jax._paper_eom import paper_constants, paper_workspace_eom
from tests.helpers import coords_from_pose

STATES = [
    ([0.45, 0.2598, 0.0], [0.05, -0.08, 0.3]),
    ([0.52, 0.30, -0.04], [-0.2, 0.1, -0.5]),
    ([0.41, 0.22, 0.05], [0.3, 0.25, 0.8]),
]


@pytest.mark.parametrize("X,Xd", STATES)
@pytest.mark.parametrize("J_rotor", [0.0, 2e-3])
def test_L1_matches_paper_closed_form(params, X, Xd, J_rotor):
    p = params.replace(J_rotor=J_rotor)
    robot = pj.Robot(p)
    X, Xd = jnp.asarray(X), jnp.asarray(Xd)
    eom = pj.eom_terms(pj.Reduced(), robot, X, Xd)
    Me, CeXd, spring = paper_workspace_eom(p, X, Xd)
    np.testing.assert_allclose(eom.M, Me, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(eom.h, CeXd, rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(-eom.Q_passive, spring, rtol=1e-9, atol=1e-13)


def test_paper_constants_by_hand(params, robot):
    k = paper_constants(params)
    m1, m2, m3 = float(robot.m1), float(robot.m2), float(robot.m3)
    r1, r2, s = float(robot.r1), float(robot.r2), float(robot.s)
    I1 = m1 * (0.366**2 + 0.023**2) / 12
    np.testing.assert_allclose(k["alpha1"], I1 + m1 * 0.183**2 + (m2 + m3) * r1**2, rtol=1e-14)
    np.testing.assert_allclose(k["beta13"], m3 * r1 * (s + 0.183), rtol=1e-14)
    np.testing.assert_allclose(k["beta12"], m2 * r1 * r2 / 2 + m3 * r1 * r2, rtol=1e-14)


@pytest.mark.parametrize("model", [pj.Rigid(), pj.Reduced(), pj.Double1R()])
def test_kane_equals_autodiff_lagrangian(robot, model):
    X = jnp.array([0.47, 0.24, 0.03])
    z = coords_from_pose(model, robot, X)
    zd = jnp.linspace(-0.4, 0.5, model.n_dof)
    eom = pj.eom_terms(model, robot, z, zd)
    # compiled: evaluated eagerly, the Lagrangian's second derivatives are hundreds of
    # compilations of single operations
    M, f = eqx.filter_jit(lagrangian_eom)(model, robot, z, zd)
    np.testing.assert_allclose(eom.M, M, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(eom.h - eom.Q_passive, f, rtol=1e-9, atol=1e-13)

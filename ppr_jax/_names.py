"""The library's names and defaults, without its numerics: plain Python, no JAX.

The command line builds its parser (choices, defaults, help texts) from this module alone, so
that `ppr-jax --help` answers without importing JAX or the numerical modules. Each quantity is
written here once and imported by the module that owns it (`_params`, `_models`, `_simulate`,
`_scenes`, `_studies`). The registries that hold classes (`MODELS`, `SOLVERS`,
`SCENE_CLASSES`) keep their own dicts; `tests/test_imports.py` checks that their names are the
ones listed here, so a new model, solver or scene adds its name in both places.
"""

from __future__ import annotations

# -- robot parameters (`_params`) ----------------------------------------------------------

#: Physical ranges of every settable parameter: name -> (low, high, unit, meaning).
#: Bounds are open at 0 where the quantity must be strictly positive.
PARAM_RANGES: dict[str, tuple[float, float, str, str]] = {
    "a": (1e-3, 100.0, "m", "base side"),
    "h": (1e-4, 10.0, "m", "platform side"),
    "t_p": (1e-5, 1.0, "m", "platform plate thickness"),
    "l1": (1e-3, 100.0, "m", "drive link length"),
    "l3": (1e-3, 100.0, "m", "connecting link length"),
    "b_r": (1e-5, 1.0, "m", "link width (in plane)"),
    "t_r": (1e-5, 1.0, "m", "link thickness"),
    "r": (1e-5, 1.0, "m", "compliant joint radius (actual strip)"),
    "theta_c": (1e-3, 3.0, "rad", "compliant joint arc angle"),
    "w": (1e-5, 1.0, "m", "strip width"),
    "t": (1e-6, 1e-2, "m", "strip thickness"),
    "E": (1e6, 1e13, "Pa", "Young's modulus"),
    "rho_m": (1.0, 1e5, "kg/m^3", "density"),
    "gamma": (0.5, 1.0, "-", "PRB characteristic radius factor"),
    "rho": (0.1, 1.5, "-", "PRB characteristic radius (fraction of half length)"),
    "K_theta": (0.5, 5.0, "-", "PRB stiffness coefficient"),
    "J_rotor": (0.0, 10.0, "kg m^2", "reflected actuator rotor inertia"),
    "c_spring": (0.0, 100.0, "N m s/rad", "viscous damping of each compliant-joint spring"),
    "c_act": (0.0, 100.0, "N m s/rad", "viscous friction of each actuated joint"),
}


def settable_names() -> list[str]:
    """Names accepted by `RobotParams.replace` and the CLI's ``--set``."""
    return list(PARAM_RANGES) + ["sigma", "joint_geometry"]


# -- model levels (`_models`) --------------------------------------------------------------

#: the names of `MODELS`, in order of fidelity (L0 ... L3)
MODEL_NAMES = ("rigid", "reduced", "double1r", "beam")
#: the models whose coordinates are the platform pose (no actuated coordinate:
#: `actuated_index is None`), which can give a scene's inverse-dynamics torques
KINEMATIC_MODELS = ("rigid", "reduced")
#: how L3's strips move: in static equilibrium for their clamp poses (`QuasiStaticBeam`, the
#: default) or with their own inertia and modes (`Beam`, stiff)
STRIP_DYNAMICS = ("quasi-static", "full")
#: beam elements per strip of L3 when none is given, and the most allowed
DEFAULT_ELEMENTS = 8
MAX_ELEMENTS = 256

# -- ODE solvers (`_simulate.SOLVERS`) -----------------------------------------------------

SOLVER_NAMES = ("tsit5", "dopri5", "dopri8", "kvaerno5", "kvaerno3", "kvaerno5-kept",
                "ros34pw2")
#: the names among them of solvers for stiff problems (implicit or linearly implicit)
STIFF_SOLVER_NAMES = ("kvaerno5", "kvaerno3", "kvaerno5-kept", "ros34pw2")

# -- scenes (`_scenes`) --------------------------------------------------------------------

#: the scenes' defaults, written once: one turn of the circle of eq 55 (2 pi / omega = 7.54 s),
#: output every 10 ms, tolerances that put L2's error near 1e-8 m, and a step budget that no
#: default scene comes near
T_END = 7.54
N_OUT = 755
RTOL = 1e-8
ATOL = 1e-10
MAX_STEPS = 200_000
#: default tolerances of the full L3: rtol 1e-8 (the scenes' default) would resolve the undamped
#: kHz strip vibration for hours; at rtol 1e-4 the whole paper-circle (N = 16) runs in 72 s on a
#: 2-core CPU and its platform ends 3.3e-7 m from an rtol-1e-5 run, against the 3.5e-5 m that
#: the strips' own dynamics puts between it and the quasi-static L3 (docs/theory/strips.md)
FULL_L3_RTOL = 1e-4
FULL_L3_ATOL = 1e-6
#: the names of the built-in scenes (`_scenes._registry.SCENES`)
SCENE_NAMES = ("paper-circle", "servo-circle")
#: what `simulate --scene` runs: the scenes and `modes` (a static solve: `modes_scene`)
SIMULATE_CHOICES = (*SCENE_NAMES, "modes")

# -- studies (`_studies`) ------------------------------------------------------------------

#: the metrics a sensitivity table reports (rows) by default on a circle, SI units
SENSITIVITY_METRICS = (
    "radial_error_max_m",
    "radial_error_min_m",
    "end_rotation_diff_max_deg",
    "torque_peak_Nm",
    "base_frequency_hz",
)
#: ... and on any other path: the tracking error's largest position and orientation error
PATH_SENSITIVITY_METRICS = (
    "position_error_max_m",
    "phi_error_max_rad",
    "end_rotation_diff_max_deg",
    "torque_peak_Nm",
    "base_frequency_hz",
)
#: robust losses of an identification
LOSSES = ("linear", "huber", "cauchy")
#: least-squares solvers of an identification
ID_SOLVERS = ("lm", "optimistix-lm", "optimistix-gn")
#: what drives a named motion-driven scene's model: the measured angles when the data hold them
#: (auto), the scene's commands for the parameters of the model that computed them, or the
#: measured angles (without a scene, the data's own angles or torques drive it)
ACTUATIONS = ("auto", "commanded", "measured")
#: what of each experiment's initial state is estimated (number of unknowns per experiment):
#: nothing (the scene's quasi-static state), the platform pose (x0, y0, phi0), or the pose and
#: the platform velocity
INITIAL_STATES = {"scene": 0, "pose": 3, "pose-velocity": 6}

# -- design (`_studies._design`) -----------------------------------------------------------

#: the constrained optimisers of a design (scipy.optimize.minimize's methods)
DESIGN_OPTIMIZERS = ("slsqp", "trust-constr")
#: a design's defaults: starts run by the optimiser, candidates screened for them, points of
#: the verification grid, the grid's tolerance on the objective (relative), the finite
#: difference check's tolerance (relative)
DESIGN_STARTS = 4
DESIGN_CANDIDATES = 64
DESIGN_GRID = 10_000
DESIGN_GRID_RTOL = 0.01
DESIGN_FD_RTOL = 1e-5

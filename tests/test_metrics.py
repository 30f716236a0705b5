"""Scene metrics (MODEL.md section 6) on synthetic outputs with known values, one robot and a
batch in one vectorised pass."""

import numpy as np

from ppr_jax._metrics import Outputs, metric_arrays, metrics


def _synthetic(offset, amp, n=201):
    """A platform on a circle of radius R + offset around c, phi = amp sin(s), end rotations
    (amp, -amp/2) cos(s) rad, energies 1 + s/10 J and 2 J."""
    c, R = np.array([0.1, 0.05]), 0.02
    s = np.linspace(0.0, 2 * np.pi, n)
    X = np.stack([c[0] + (R + offset) * np.cos(s), c[1] + (R + offset) * np.sin(s),
                  amp * np.sin(s)], -1)
    Xn = np.stack([c[0] + R * np.cos(s), c[1] + R * np.sin(s), np.zeros_like(s)], -1)
    out = Outputs(X=X, end_rot=np.stack([amp * np.cos(s), -amp / 2 * np.cos(s)], -1),
                  residual=np.full(n, 1e-16), kinetic=1 + s / 10, potential=np.full(n, 2.0))
    return out, Xn, c, R


def test_metrics_closed_form():
    out, Xn, c, R = _synthetic(1e-4, 0.01)
    m = metrics(out, Xn, c, R)
    assert np.isclose(m["radial_error_max_m"], 1e-4) and np.isclose(m["radial_error_min_m"], 1e-4)
    assert np.isclose(m["radial_error_max_relative_percent"], 1e-4 / R * 100)
    assert np.isclose(m["position_error_max_m"], 1e-4)
    assert np.isclose(m["phi_error_max_rad"], 0.01, rtol=1e-3)
    assert np.isclose(m["phi_error_rms_rad"], 0.01 / np.sqrt(2), rtol=1e-2)
    assert np.isclose(m["end_rotation_diff_max_deg"], np.degrees(0.015))
    assert np.isclose(m["end_rotation_diff_max_relative_percent"], 150.0)
    assert np.isclose(m["energy_initial_J"], 3.0)
    assert np.isclose(m["energy_final_J"], 3 + 2 * np.pi / 10)
    assert all(isinstance(v, float) for v in m.values())


def test_metrics_batched_equal_members():
    members = [_synthetic(o, a) for o, a in [(1e-4, 0.01), (-3e-5, 0.2), (0.0, 1e-3)]]
    stack = lambda f: np.stack([f(o) for o, *_ in members])  # noqa: E731
    out = Outputs(X=stack(lambda o: o.X), end_rot=stack(lambda o: o.end_rot),
                  residual=stack(lambda o: o.residual), kinetic=stack(lambda o: o.kinetic),
                  potential=stack(lambda o: o.potential))
    _, _, c, R = members[0]
    Xn = np.stack([m[1] for m in members])
    batch = metric_arrays(out, Xn, c, R)
    for i, (o, xn, _, _) in enumerate(members):
        one = metrics(o, xn, c, R)
        for k, v in one.items():
            assert batch[k].shape == (3,)
            assert np.isclose(batch[k][i], v, rtol=1e-14, atol=0.0), k

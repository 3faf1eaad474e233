"""Identifiability diagnostics on maps with a known structure, and on CVSim-6."""
import numpy as np
import pytest

from cvsim6.model import identifiability as idf
from cvsim6.data import priors
from cvsim6 import registry


def test_cumulative_energy_and_modes():
    s = np.array([3.0, 2.0, 1.0, 0.0])
    np.testing.assert_allclose(idf.cumulative_energy(s), [9 / 14, 13 / 14, 1.0, 1.0])
    assert idf.modes_for_energy(s, 0.9) == (2, pytest.approx(13 / 14))
    assert idf.modes_for_energy(s, 0.99)[0] == 3
    assert idf.modes_for_energy(np.zeros(4), 0.99) == (0, 1.0)  # samples that do not vary
    np.testing.assert_array_equal(idf.cumulative_energy(np.zeros(3)), 1.0)


def test_manifold_svd_of_samples_on_a_plane():
    rng = np.random.default_rng(0)
    basis = np.linalg.qr(rng.normal(size=(23, 2)))[0]  # a 2-D subspace of R^23
    X = rng.normal(size=(500, 2)) @ basis.T
    s = idf.manifold_svd(X)
    assert s[2] < 1e-10 * s[0]
    assert idf.modes_for_energy(s, 0.999999)[0] == 2


def test_manifold_svd_standardized_does_not_depend_on_units():
    """Three independent columns, one in units a million times larger: raw, one mode holds
    99% of the energy; standardized, all three are needed (the paper's scaling)."""
    rng = np.random.default_rng(2)
    X = rng.uniform(-1.0, 1.0, size=(2000, 3))
    X[:, 0] = X[:, 0] * 1e6 + 5e6
    assert idf.modes_for_energy(idf.manifold_svd(X, scaling="none"), 0.99)[0] == 1
    s = idf.manifold_svd(X)
    assert idf.modes_for_energy(s, 0.99)[0] == 3
    np.testing.assert_allclose(s, np.sqrt(2000.0), rtol=0.1)  # unit-variance columns, near-orthogonal
    np.testing.assert_allclose(idf.manifold_svd(X * [1.0, 1e-3, 7.0]), s)
    with pytest.raises(ValueError, match="scaling"):
        idf.manifold_svd(X, scaling="minmax")


def test_jacobian_rank_of_a_map_with_known_null_space():
    """y = A v with A (16 x 23) of rank 10 and columns 4, 9 zero: rank 10, a null space
    of dimension 13 that contains e_4 and e_9 whole (share 1/13 each)."""
    rng = np.random.default_rng(1)
    A = rng.normal(size=(16, 10)) @ rng.normal(size=(10, 23))
    A[:, [4, 9]] = 0.0  # parameters 4 and 9 do not affect the outputs
    f = lambda v: v @ A.T  # noqa: E731
    widths = rng.uniform(0.5, 2.0, 23)
    v = rng.normal(size=(3, 23))
    J = idf.finite_difference_jacobian(f, v, widths, rel_step=1e-3)
    np.testing.assert_allclose(J, np.broadcast_to(A, (3, 16, 23)), rtol=1e-8, atol=1e-9)
    Js = idf.scaled_jacobian(J, widths, output_scale=np.ones(16))
    sv, ranks, shares = idf.local_identifiability(Js, rtol=1e-8)
    assert (ranks == 10).all()
    assert (sv[:, 10:] < 1e-8 * sv[:, :1]).all()
    np.testing.assert_allclose(shares.sum(axis=1), 1.0)
    np.testing.assert_allclose(shares[:, [4, 9]], 1 / 13, rtol=1e-6)
    assert (shares[:, [0, 1, 2]] < 1 / 13).all()


def test_parameter_outside_the_range_is_fully_unidentifiable():
    rng = np.random.default_rng(2)
    B = rng.normal(size=(16, 23))
    B[:, 7] = 0.0
    f = lambda v: np.tanh(v @ B.T / 5)  # noqa: E731
    J = idf.finite_difference_jacobian(f, rng.normal(size=(2, 23)), np.ones(23), rel_step=1e-5)
    sv, ranks, shares = idf.local_identifiability(idf.scaled_jacobian(J, np.ones(23), np.ones(16)), rtol=1e-6)
    # 23 parameters, 16 outputs: null space of dimension 7, parameter 7 entirely in it
    assert (ranks == 16).all()
    np.testing.assert_allclose(shares.sum(axis=1), 1.0)
    np.testing.assert_allclose(shares[:, 7], 1 / 7, rtol=1e-6)


def test_cvsim6_jacobian_at_default():
    """Hr is copied to the output and SVR = R_a * 1333.3: exact sensitivities."""
    lo, hi = priors.prior_bounds(priors.PAPER_PRIORS["structural"])
    w = hi - lo
    p = registry.default_parameters()
    J = idf.finite_difference_jacobian(idf.simulator_outputs(), p, w, rel_step=1e-3)[0]
    I, O = registry.PARAMETER_INDEX, registry.OUTPUT_INDEX
    assert J[O["Hr"], I["Hr"]] == pytest.approx(1.0, rel=1e-9)
    assert J[O["SVR"], I["R_a"]] == pytest.approx(1000 / 60 * 80, rel=1e-9)
    assert J[O["SVR"], np.arange(23) != I["R_a"]] == pytest.approx(0, abs=1e-6)
    sv, ranks, shares = idf.local_identifiability(idf.scaled_jacobian(J[None], w), rtol=1e-3)
    assert 8 <= ranks[0] <= 16
    assert shares[0, I["Hr"]] < 1e-6  # heart rate is observed directly


def test_unstressed_volumes_enter_only_through_their_sum():
    """Outside the left ventricle (whose volume is an output), the unstressed volumes set
    the stressed blood volume only through their sum (pressures are (V - V0) / C and the
    total volume is fixed): 4 exact null directions of the Jacobian at any point. The
    local-identifiability machinery must find them, with the share each parameter has in
    that subspace, 1 - w_j^2 / sum_i w_i^2 in prior-width units."""
    lo, hi = priors.prior_bounds(priors.PAPER_PRIORS["structural"])
    w = hi - lo
    p = registry.default_parameters()
    J = idf.finite_difference_jacobian(idf.simulator_outputs(), p, w, rel_step=1e-3)[0]
    I = registry.PARAMETER_INDEX
    names = ["V0_a", "V0_v", "V0_r", "V0_pa", "V0_pv"]
    cols = [I[n] for n in names]
    # d output / d V0 (per mL) is the same for the five
    np.testing.assert_allclose(J[:, cols], np.repeat(J[:, cols[:1]], 5, axis=1), rtol=1e-5, atol=1e-9)
    _, ranks, shares = idf.local_identifiability(idf.scaled_jacobian(J[None], w), rtol=1e-3)
    ww = w[cols] ** 2
    expected = 1 - ww / ww.sum()
    in_null = shares[0, cols] * (23 - ranks[0])  # shares are ||P_null e_j||^2 / dim(null)
    assert np.all(in_null >= expected - 1e-3), (in_null, expected)

import itertools

import numpy as np
import pytest

from engine import make_inverse, method_names
from engine.inverses import METHODS


def _random_J(rng, rank=6, n=6):
    U, _ = np.linalg.qr(rng.normal(size=(6, 6)))
    V, _ = np.linalg.qr(rng.normal(size=(n, n)))
    s = np.sort(rng.uniform(0.2, 2.0, min(6, n)))[::-1]
    s[rank:] = 0.0
    S = np.zeros((6, n))
    S[: len(s), : len(s)] = np.diag(s)
    return U @ S @ V.T


def test_dls_tends_to_the_inverse(rng):
    J = _random_J(rng)
    x = rng.normal(size=6)
    exact = np.linalg.solve(J, x)
    errors = [np.linalg.norm(make_inverse("dls", **{"lambda": lam}).solve(J, x).qd - exact) for lam in (1e-1, 1e-2, 1e-3, 1e-4)]
    assert errors[-1] < 1e-6 * np.linalg.norm(exact)
    assert all(a > b for a, b in itertools.pairwise(errors))


def test_dls_matches_eq6_and_is_bounded(rng):
    for rank in (6, 5, 3):
        J = _random_J(rng, rank)
        x = rng.normal(size=6)
        for lam in (0.01, 0.1, 0.5):
            qd = make_inverse("dls", **{"lambda": lam}).solve(J, x).qd
            eq6 = J.T @ np.linalg.solve(J @ J.T + lam**2 * np.eye(6), x)
            np.testing.assert_allclose(qd, eq6, atol=1e-10)
            assert np.linalg.norm(qd) <= np.linalg.norm(x) / (2 * lam) * (1 + 1e-12)


def test_plain_inverse_solves_and_pseudo_inverts(rng):
    J = _random_J(rng)
    x = rng.normal(size=6)
    np.testing.assert_allclose(J @ make_inverse("inverse").solve(J, x).qd, x, atol=1e-12)
    Jr = _random_J(rng, n=4)
    np.testing.assert_allclose(make_inverse("inverse").solve(Jr, x).qd, np.linalg.pinv(Jr) @ x, atol=1e-12)


def test_adaptive_is_plain_inverse_above_epsilon(rng):
    J = _random_J(rng)  # all singular values >= 0.2
    x = rng.normal(size=6)
    step = make_inverse("adaptive", lambda_max=0.5, epsilon=0.19).solve(J, x)
    np.testing.assert_allclose(step.qd, np.linalg.solve(J, x), atol=1e-10)
    assert np.all(step.damping == 0.0)


def test_adaptive_damping_follows_eq16_and_is_continuous():
    inv = make_inverse("adaptive", lambda_max=0.06, epsilon=0.1)
    x = np.ones(6)
    for sigma, expected in ((0.0, 0.06), (0.05, 0.03), (0.1 - 1e-9, 0.0), (0.1, 0.0), (0.3, 0.0)):
        J = np.diag([1.0, 0.9, 0.8, 0.7, 0.6, sigma])
        np.testing.assert_allclose(inv.solve(J, x).damping[-1], expected, atol=1e-7)
    below = inv.solve(np.diag([1, 1, 1, 1, 1, 0.1 - 1e-9]), x).qd
    above = inv.solve(np.diag([1, 1, 1, 1, 1, 0.1 + 1e-9]), x).qd
    np.testing.assert_allclose(below, above, atol=1e-6)


def test_all_methods_bounded_at_a_singularity(rng):
    J = _random_J(rng, rank=5)
    x = rng.normal(size=6)
    for name in method_names():
        if name == "inverse":
            continue
        qd = make_inverse(name).solve(J, x).qd
        assert np.all(np.isfinite(qd)) and np.linalg.norm(qd) < 1e3, name


def test_sdls_respects_gamma_max(rng):
    for _ in range(20):
        J = _random_J(rng, rank=int(rng.integers(3, 7)))
        x = rng.normal(size=6) * 10
        qd = make_inverse("sdls", gamma_max=0.3).solve(J, x).qd
        assert np.max(np.abs(qd)) <= 0.3 + 1e-12


def test_svf_filtered_singular_values_are_bounded(rng):
    J = _random_J(rng, rank=4)
    x = rng.normal(size=6)
    qd = make_inverse("svf", sigma0=0.05, nu=10.0).solve(J, x).qd
    assert np.linalg.norm(qd) <= np.linalg.norm(x) / 0.05


def test_wdls_equals_dls_with_its_damping(rng):
    J = _random_J(rng)
    J[:, -1] *= 1e-3
    x = rng.normal(size=6)
    step = make_inverse("wdls", lambda_max=0.1, epsilon=0.5).solve(J, x)
    lam = step.damping[0]
    assert 0 < lam <= 0.1
    np.testing.assert_allclose(step.qd, make_inverse("dls", **{"lambda": lam}).solve(J, x).qd, atol=1e-12)


def test_batched_parameters_equal_a_loop(rng):
    J = np.stack([_random_J(rng, rank=5) for _ in range(4)])
    x = rng.normal(size=(4, 6))
    lam = np.array([0.01, 0.05, 0.1, 0.2])
    eps = np.array([0.05, 0.1, 0.2, 0.3])
    for name, params in (("dls", {"lambda": lam}), ("adaptive", {"lambda_max": lam, "epsilon": eps})):
        batched = make_inverse(name, **params).solve(J, x).qd
        for i in range(4):
            single = make_inverse(name, **{k: float(v[i]) for k, v in params.items()}).solve(J[i], x[i]).qd
            np.testing.assert_allclose(batched[i], single, atol=1e-13)


def test_make_inverse_errors():
    with pytest.raises(ValueError, match="valid methods: inverse, dls, adaptive, wdls, sdls, svf, bounded"):
        make_inverse("magic")
    with pytest.raises(ValueError, match="unknown parameter"):
        make_inverse("dls", lam=0.1)
    with pytest.raises(ValueError, match="epsilon"):
        make_inverse("adaptive", epsilon=0.0)
    with pytest.raises(ValueError, match="lambda"):
        make_inverse("dls", **{"lambda": float("nan")})
    assert set(METHODS) == {"inverse", "dls", "adaptive", "wdls", "sdls", "svf", "bounded"}


def test_docstrings_cite_sources():
    for name, spec in METHODS.items():
        assert spec.doc and any(ch.isdigit() for ch in spec.doc), name

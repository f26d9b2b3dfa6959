"""The likelihood's Kalman filter computes its gains once for each run of batch members
that share the noise (the whole batch when the noise is fixed by repeats), and runs a
batch that shares one noise side by side: the result is bit for bit what each member
alone gives, and it is the dense Gaussian's."""

from __future__ import annotations

import numpy as np
from test_likelihood import brute_force

from pmabayes.inference.likelihood import _kalman_loglik, _noise_loglik


def _members_alone(y, x, scale, sigma, rho, white):
    return np.concatenate([
        _kalman_loglik(y, x[b:b + 1] if x.shape[0] > 1 else x, scale, sigma[b:b + 1],
                       rho[b:b + 1], white[b:b + 1]) for b in range(sigma.size)])


def test_shared_gains_are_bit_for_bit_each_members_own():
    rng = np.random.default_rng(5)
    n = 400
    y = 1e-5 * rng.standard_normal((3, n))
    # runs of equal noise, a change, a return to an earlier value, and a NaN member
    sigma = np.array([7e-6, 7e-6, 7e-6, 9e-6, 9e-6, 7e-6, 7e-6, 7e-6])
    rho = np.array([0.3, 0.3, 0.3, 0.3, 0.3, 0.9, 0.3, np.nan])
    white = np.array([1e-6, 1e-6, 1e-6, 1e-6, 0.0, 0.0, 1e-6, 1e-6])
    for x in (1e-5 * rng.standard_normal((8, n)), 1e-5 * rng.standard_normal((1, n))):
        batched = _kalman_loglik(y, x, 1.5, sigma, rho, white)
        alone = _members_alone(y, x, 1.5, sigma, rho, white)
        assert np.array_equal(batched, alone, equal_nan=True)
        assert np.isnan(batched[-1]).all() and np.isfinite(batched[:-1]).all()
        # members with different data but the same noise do not get the same answer
        assert len(set(batched[:3, 0])) == (3 if x.shape[0] > 1 else 1)


def test_a_fixed_noise_batch_matches_the_dense_gaussian():
    rng = np.random.default_rng(6)
    n = 150
    y = 1e-5 * rng.standard_normal((2, n))
    x = 1e-5 * rng.standard_normal((4, n))
    sigma, rho, white = np.full(4, 8e-6), np.full(4, 0.95), np.full(4, 2e-6)
    got = _kalman_loglik(y, x, 1.0, sigma, rho, white)
    expected = [[brute_force(y[m], x[b], 8e-6, 0.95, 2e-6) for m in range(2)]
                for b in range(4)]
    assert np.allclose(got, expected, rtol=1e-10, atol=1e-6)


def test_every_route_of_the_likelihood_gives_the_same_bits():
    """Fixed noise (side by side, from a row-major or the simulator's transposed
    layout), a shared model output (once, repeated), and sampled noise (member by
    member) all equal the general filter."""
    rng = np.random.default_rng(7)
    n, batch = 300, 6
    y = 1e-5 * rng.standard_normal((4, n))
    x = 1e-5 * rng.standard_normal((batch, n))
    fixed = (np.full(batch, 8e-6), np.full(batch, 0.7), np.full(batch, 1e-6))
    sampled = (np.linspace(6e-6, 9e-6, batch), np.full(batch, 0.7), np.full(batch, 1e-6))
    for noise in (fixed, sampled):
        general = _kalman_loglik(y, x, 2.0, *noise)
        assert np.array_equal(_noise_loglik(y, x, 2.0, *noise), general)
        assert np.array_equal(_noise_loglik(y, np.ascontiguousarray(x.T).T, 2.0, *noise),
                              general)
        one = x[:1]
        assert np.array_equal(_noise_loglik(y, one, 2.0, *noise),
                              _kalman_loglik(y, one, 2.0, *noise))
    assert not np.array_equal(_noise_loglik(y, x, 2.0, *fixed),
                              _noise_loglik(y, x, 2.0, *sampled))


def test_the_gains_copied_at_the_recursions_cycle_are_the_ones_computed():
    """The Riccati recursion's steps are copied once it repeats itself (a fixed point or a
    cycle of two, met to the bit): every gain, variance and the log sum are the bits of
    the recursion computed at every sample, with gaps."""
    import math

    import numba

    from pmabayes.inference.noise.ar1 import _kalman_gains, _masked_gains

    @numba.njit(error_model="numpy")
    def every_step(sigma, rho, white, seen, gains, variances):  # the recursion, computed
        s2 = sigma * sigma
        q = s2 * (1.0 - rho * rho)
        r = white * white
        p = s2
        const = 0.0
        count = 0
        for k in range(seen.shape[0]):
            if seen[k]:
                s_k = p + r
                gain = p / s_k
                const += math.log(s_k)
                count += 1
                variances[k] = s_k
                gains[k] = gain
                p = rho * rho * (1.0 - gain) * p + q
            else:
                p = rho * rho * p + q
        return const, count

    rng = np.random.default_rng(11)
    n = 3000
    cases = [(1e-4, 0.9, 1e-5), (1e-4, 0.99, 1e-5), (2e-6, 0.5, 1e-6), (1e-5, 0.0, 1e-6),
             (1e-5, 0.999999, 1e-7), (1e-5, -0.7, 1e-6), (1e-5, 0.6, 0.0), (0.0, 0.5, 1e-6),
             (1e-5, np.nan, 1e-6)]
    cases += [(10 ** rng.uniform(-7, -3), rng.uniform(-1, 1), 10 ** rng.uniform(-8, -3))
              for _ in range(200)]
    masks = [np.ones(n, bool), rng.random(n) > 0.3]
    gap = np.ones(n, bool)
    gap[500:900] = False
    gap[2000] = False
    masks.append(gap)
    for sigma, rho, white in cases:
        for seen in masks:
            want_g, want_v = np.full(n, -1.0), np.full(n, -1.0)
            got_g, got_v = np.full(n, -1.0), np.full(n, -1.0)
            want = every_step(sigma, rho, white, seen, want_g, want_v)
            got = _masked_gains(sigma, rho, white, seen, got_g, got_v)
            assert want[1] == got[1]
            assert np.array_equal([want[0]], [got[0]], equal_nan=True), (sigma, rho, white)
            assert np.array_equal(got_g, want_g, equal_nan=True), (sigma, rho, white)
            assert np.array_equal(got_v, want_v, equal_nan=True), (sigma, rho, white)
        g, v = np.empty(n), np.empty(n)
        full = every_step(sigma, rho, white, masks[0], np.empty(n), np.empty(n))[0]
        assert np.array_equal([_kalman_gains(sigma, rho, white, g, v)], [full], equal_nan=True)

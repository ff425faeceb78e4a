"""The guard against the linearisation: its invariants, its bounds against sampled margins,
and its place in the certificates (a person's are guarded, the paper's are not)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.core.certificate import certify_batch
from legws_daemon.core.commit import commit_batch
from legws_daemon.core.guard import guarded, spread_trace
from legws_daemon.core.operator import OperatorModel, UserMotion
from legws_daemon.core.params import Params

BETA = 5.0


def _margin(x: np.ndarray, g_i: np.ndarray, g_j: np.ndarray, scale: float) -> np.ndarray:
    """``beta (|x - g_j| - |x - g_i|) / S``: the margin's random part (dragan form)."""
    return BETA * (np.linalg.norm(x - g_j, axis=-1) - np.linalg.norm(x - g_i, axis=-1)) / scale


@settings(max_examples=200, deadline=None)
@given(
    r_i=st.floats(0.0, 0.5),
    r_j=st.floats(1e-3, 0.8),
    d_i=st.floats(0.05, 0.8),
    pos_sd=st.floats(1e-5, 0.1),
    sd=st.floats(0.0, 1.0),
)
def test_the_guard_only_lowers_the_mean_and_widens_the_spread_up_to_the_largest_gradient(
    r_i: float, r_j: float, d_i: float, pos_sd: float, sd: float
) -> None:
    inv_s = 1.0 / 0.4
    wid, trace = 0.4, 0.4**2 + 2 * 0.3**2
    cap = BETA * pos_sd * wid * 2 * inv_s
    sd = min(sd, cap)  # a linearised sd never exceeds the largest gradient's
    m, s = guarded(1.0, sd, r_i, r_j, d_i, inv_s, inv_s, pos_sd**2, wid, trace, BETA)
    assert float(m) <= 1.0
    assert sd - 1e-12 <= float(s) <= cap * (1 + 1e-12)


def test_the_guard_vanishes_as_the_spread_shrinks() -> None:
    """Far from the goals against the spread, the certificate is the linearised one to
    first order: the corrections fall with the variance."""
    drops, extras = [], []
    for pos_sd in (1e-2, 1e-3, 1e-4):
        m, s = guarded(1.0, 0.1, 0.2, 0.3, 0.4, 2.5, 2.5, pos_sd**2, 0.4, 0.3, BETA)
        drops.append(1.0 - float(m))
        extras.append(float(s) - 0.1)
    assert drops[1] / drops[0] == pytest.approx(1e-2, rel=0.05)  # ~ the variance
    assert extras[2] < extras[1] < extras[0]
    assert drops[2] < 1e-7 and extras[2] < 1e-9


@pytest.mark.parametrize("r_i", [0.003, 0.02, 0.08, 0.2])
def test_the_bounds_hold_for_sampled_positions_however_wide_the_spread(r_i: float) -> None:
    """Against Gaussian positions around the nominal (the bridge's share 1: ``d_i = r_i``),
    the guard's mean is at or below the sampled margin's mean and its standard deviation at
    or above the sampled one, where the linearised ones fail: near the goal with a spread
    of centimetres (the mean at least)."""
    rng = np.random.default_rng(int(r_i * 1e4))
    pbar = np.zeros(3)
    g_i = np.array([r_i, 0.0, 0.0])
    g_j = np.array([r_i, 0.12, 0.02])
    scale = 0.4
    pos_sd = 0.06  # m per axis: rho 0.95 over a reach
    x = pbar + pos_sd * rng.standard_normal((200_000, 3))
    f = _margin(x, g_i, g_j, scale)
    r_j = float(np.linalg.norm(pbar - g_j))
    a = (pbar - g_j) / r_j / scale - (pbar - g_i) / r_i / scale
    lin_m = float(_margin(pbar[None], g_i, g_j, scale)[0])
    lin_sd = BETA * pos_sd * float(np.linalg.norm(a))
    m, s = guarded(lin_m, lin_sd, r_i, r_j, r_i, 1 / scale, 1 / scale, pos_sd**2, 1.0, 3.0, BETA)
    se = f.std() / np.sqrt(f.size)
    assert float(m) <= f.mean() + 4 * se
    assert float(s) >= f.std() * 0.999
    if r_i <= 0.02:  # the linearisation's own mean is off there
        assert lin_m > f.mean() + 10 * se


def test_the_trace_of_each_steps_spread() -> None:
    assert spread_trace(UserMotion(1.0, 0.5, 0.5), True) == pytest.approx(0.75)
    assert spread_trace(UserMotion(1.0, 0.3, 0.4), True) == pytest.approx(0.09 + 0.32)
    assert spread_trace(UserMotion(1.0, 0.3, 0.4), False) == pytest.approx(0.48)


def _layouts(m: int, b: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pos = np.empty((b, m, 3))
    pos[..., 0] = rng.uniform(0.45, 0.85, (b, m))
    pos[..., 1] = rng.uniform(-0.35, 0.35, (b, m))
    pos[..., 2] = 0.05
    return pos


def test_a_persons_certificates_are_guarded_and_the_papers_are_not(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """With the robot's clip the guard lowers slacks (most for the correlated operator) and
    withdraws commit certificates, never adds one; the model as written (the golden
    numbers' branch) is not guarded at all."""
    import legws_daemon.core.certificate as cert_mod
    import legws_daemon.core.commit as commit_mod

    params = Params()
    pos = _layouts(3, 40, 4)
    rot = np.broadcast_to(np.eye(3), (*pos.shape[:2], 3, 3))
    p0, r0 = np.array([0.55, 0.0, 0.35]), np.eye(3)
    ops = (OperatorModel(), OperatorModel(rho=0.8), OperatorModel(0.6, 0.03, 0.95, 20.0))

    def run() -> list[tuple[np.ndarray, np.ndarray]]:
        out = []
        for op, clip in [*((op, True) for op in ops), (OperatorModel(rho=0.8), False)]:
            user = op.motion(params, clip=clip)
            j = certify_batch(p0, r0, pos, rot, np.ones(3), params, op, user)
            k = commit_batch(p0, r0, pos, rot, np.ones(3), params, user, "sum", op)
            out.append((j.slack, k.certified))
        return out

    guarded_ = run()
    identity = lambda margin, sd, *rest: (np.asarray(margin), np.asarray(sd))  # noqa: E731
    monkeypatch.setattr(cert_mod, "guarded", identity)
    monkeypatch.setattr(commit_mod, "guarded", identity)
    linear = run()
    lowered = []
    for (js, kc), (jl, kl) in zip(guarded_[:3], linear[:3], strict=True):
        finite = np.isfinite(js)
        assert np.all(js[finite] <= jl[finite] + 1e-12)
        assert not np.any(kc & ~kl)
        lowered.append(float(np.median(jl[finite] - js[finite])))
    assert 0.0 < lowered[0] < lowered[1] < lowered[2]
    # the operator's model as written: untouched by the guard
    np.testing.assert_array_equal(guarded_[3][0], linear[3][0])
    np.testing.assert_array_equal(guarded_[3][1], linear[3][1])

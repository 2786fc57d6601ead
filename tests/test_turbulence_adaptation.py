"""The turbulence scale learnt from the innovations (immukf_sitl.service.turbulence).

Checked against a system whose consistent noise level is known exactly: six independent random
walks observed in white noise, filtered by the textbook scalar Kalman filter with the adapter's
process noise. When its noise equals the truth's the filter is optimal and its innovations are
white with variance ``S``, so covariance matching must settle at the true scale; with noise
everywhere else it must not.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from immukf_sitl.estimation import ProcessModel
from immukf_sitl.service.turbulence import TurbulenceAdapter, TurbulenceEstimate

REPO = Path(__file__).resolve().parents[1]
DT_S = 0.01
R = 0.0245**2  # the accelerometer's white noise (m/s^2)^2
Q_DESIGN = 1e-4  # random-walk variance per step at the design air


def _adapter(**changes) -> TurbulenceAdapter:
    nx = 6
    process = ProcessModel(
        f=lambda t, x, u, v: x,
        nx=nx,
        noise_cov=np.eye(1),
        state_noise_cov=np.diag(np.full(nx, Q_DESIGN)),
    )
    settings = {"averaging_s": 10.0, "floor": 0.05} | changes
    return TurbulenceAdapter(process, range(nx), np.full(6, R), DT_S, **settings)


def _fly(
    adapter: TurbulenceAdapter, q_true: np.ndarray, seconds: float, seed: int,
    dead: int | None = None, trusted: np.ndarray | None = None,
    unmodelled_var: np.ndarray | None = None, p0: float = 1.0,
) -> TurbulenceEstimate:  # fmt: skip
    """Six scalar random walks, each filtered with the adapter's noise at its current scale."""
    rng = np.random.default_rng(seed)
    trusted = np.ones(6, dtype=bool) if trusted is None else trusted
    x = np.zeros(6)
    x_hat = np.zeros(6)
    p = np.full(6, p0)
    est = TurbulenceEstimate()
    for _ in range(round(seconds / DT_S)):
        q = np.diagonal(adapter.process_at(est.scale).state_noise_cov)
        x = x + rng.normal(0.0, np.sqrt(q_true))
        z = x + rng.normal(0.0, np.sqrt(R), 6)
        if unmodelled_var is not None:  # noise the filter's R does not hold
            z = z + rng.normal(0.0, np.sqrt(unmodelled_var))
        if dead is not None:
            z[dead] = rng.normal(0.0, np.sqrt(R))  # zeroed: the healthy model cannot explain it
        p_pred = p + q
        s = p_pred + R
        nu = z - x_hat
        gain = p_pred / s
        x_hat = x_hat + gain * nu
        p = (1.0 - gain) * p_pred
        est = adapter.update(est, nu, s, trusted)
    return est


@pytest.mark.parametrize("k_true", [0.3, 0.6, 1.3])
def test_scale_settles_where_the_filter_is_consistent(k_true: float) -> None:
    """Air calmer than the design's, and rougher (up to the ceiling), is learnt."""
    est = _fly(_adapter(ceiling=2.0), np.full(6, k_true**2 * Q_DESIGN), 150.0, seed=11)
    assert est.scale == pytest.approx(k_true, rel=0.2)


def test_still_air_goes_to_the_floor_and_rough_air_to_the_ceiling() -> None:
    adapter = _adapter(floor=0.2, ceiling=1.5)
    assert _fly(adapter, np.zeros(6), 120.0, seed=12).scale == pytest.approx(0.2)
    assert _fly(adapter, np.full(6, 9.0 * Q_DESIGN), 60.0, seed=13).scale == 1.5
    assert _fly(_adapter(), np.full(6, 4.0 * Q_DESIGN), 60.0, seed=13).scale == 1.0


def test_a_dead_channel_moves_the_scale_by_one_rank_only() -> None:
    """A zeroed channel's innovations, fed as if healthy, leave the median near the truth."""
    k_true = 0.4
    est = _fly(_adapter(), np.full(6, k_true**2 * Q_DESIGN), 150.0, seed=14, dead=2)
    assert est.scale == pytest.approx(k_true, rel=0.3)


def test_unexplained_variance_is_the_noise_the_filter_does_not_model() -> None:
    """A channel reading white noise beyond its R shows that variance, and only that one."""
    unmodelled = np.array([0.0, 0.0, 3.0 * R, 0.0, 0.0, 0.0])
    est = _fly(_adapter(), np.full(6, 0.25 * Q_DESIGN), 120.0, seed=16, unmodelled_var=unmodelled)
    beyond = est.unexplained_var()
    assert beyond[2] == pytest.approx(3.0 * R, rel=0.25)
    assert np.all(beyond[[0, 1, 3, 4, 5]] < 0.3 * R)
    assert np.all(TurbulenceEstimate().unexplained_var() == 0.0)  # nothing seen: nothing added
    forgotten = est.forget_unexplained(np.arange(6) == 2).unexplained_var()
    assert forgotten[2] == 0.0 and np.all(forgotten[[0, 1, 3, 4, 5]] == beyond[[0, 1, 3, 4, 5]])


def test_a_start_up_transient_does_not_hide_the_unexplained_variance() -> None:
    """The filter starts 10^5 R uncertain (an alignment's): its first innovations have
    ``S >> nu^2``. Each sample weighs by what it tells of the variance (1 / (S + q)^2), so 30 s
    in, half the 60 s time constant, the 3 R the filter does not model is already shown, as it
    is after a start-up 10^5 times less uncertain (an unweighted average of ``nu^2 - S`` is
    negative, so 0, for over a minute). The scale is held at the truth's (floor = ceiling = 1),
    so every other channel is consistent."""
    unmodelled = np.array([0.0, 0.0, 3.0 * R, 0.0, 0.0, 0.0])
    truth = np.full(6, Q_DESIGN)
    pinned = _adapter(floor=1.0, ceiling=1.0)
    est = _fly(pinned, truth, 30.0, seed=17, unmodelled_var=unmodelled, p0=1e5 * R)
    beyond = est.unexplained_var()
    assert beyond[2] == pytest.approx(3.0 * R, rel=0.25)
    assert np.all(beyond[[0, 1, 3, 4, 5]] < 0.3 * R)
    settled = _fly(pinned, truth, 30.0, seed=17, unmodelled_var=unmodelled, p0=R)
    assert beyond[2] == pytest.approx(settled.unexplained_var()[2], rel=0.05)


def test_the_fixes_unexplained_variance_is_their_spread_beyond_s() -> None:
    """GPS fixes whose innovations are normal with variance 4 S show 3 S beyond S (a
    statistical consistency check over 10 min of 1 Hz fixes, with a 60 s time constant); a
    fix beyond 5 sigmas counts as 5; nothing before the first fix."""
    adapter = _adapter()
    rng = np.random.default_rng(21)
    s = np.array([4.0, 4.0, 9.0, 0.01, 0.0004])  # position, speed and course variances
    est = TurbulenceEstimate()
    assert np.all(est.gps_unexplained_var(5) == 0.0)
    excess = []
    for k in range(600):
        est = adapter.update_gps(est, 1.0 + k, rng.normal(0.0, 2.0 * np.sqrt(s)), s)
        if k >= 300:
            excess.append(est.gps_unexplained_var(5) / s)
    assert np.mean(excess, axis=0) == pytest.approx(np.full(5, 3.0), rel=0.15)
    one = adapter.update_gps(TurbulenceEstimate(), 1.0, 100.0 * np.sqrt(s), s)
    np.testing.assert_allclose(one.gps_unexplained_var(5), 24.0 * s)  # clipped: 25 S - S
    assert np.all(one.gps_unexplained_var(3) == 0.0)  # another receiver's channels: unknown


def test_untrusted_channels_say_nothing() -> None:
    trusted = np.array([True, True, False, True, True, True])
    est = _fly(_adapter(), np.full(6, 0.09 * Q_DESIGN), 60.0, seed=15, dead=2, trusted=trusted)
    assert est.weight[2] == 0.0 and est.excess[2] == 0.0 and est.predicted[2] == 0.0
    assert est.weight[0] > 0.99


def test_process_at_scales_only_the_turbulence_states() -> None:
    nx = 4
    state = np.diag([1.0, 2.0, 3.0, 4.0])
    process = ProcessModel(
        f=lambda t, x, u, v: x, nx=nx, noise_cov=np.eye(1), additive_noise_cov=2.0 * state,
        state_noise_cov=state,
    )  # fmt: skip
    adapter = TurbulenceAdapter(process, (1, 3), np.full(6, R), DT_S)
    assert adapter.process_at(1.0) is process
    half = adapter.process_at(0.5)
    np.testing.assert_array_equal(np.diagonal(half.state_noise_cov), [1.0, 0.5, 3.0, 1.0])
    np.testing.assert_array_equal(np.diagonal(half.additive_noise_cov), [2.0, 1.0, 6.0, 2.0])
    assert adapter.process_at(0.5) is half  # built once per scale


def test_process_at_scales_only_the_turbulences_share() -> None:
    """A state whose driving variance is 3/4 turbulence: at half the air, 3/4 / 4 + 1/4."""
    state = np.diag([1.0, 2.0, 3.0, 4.0])
    process = ProcessModel(
        f=lambda t, x, u, v: x, nx=4, noise_cov=np.eye(1), additive_noise_cov=state,
        state_noise_cov=state,
    )  # fmt: skip
    adapter = TurbulenceAdapter(process, (1, 3), np.full(6, R), DT_S, turbulence_share=(1.0, 0.75))
    half = adapter.process_at(0.5)
    np.testing.assert_allclose(np.diagonal(half.state_noise_cov), [1.0, 0.5, 3.0, 4.0 * 0.4375])
    with pytest.raises(ValueError, match="turbulence_share"):
        TurbulenceAdapter(process, (1, 3), np.full(6, R), DT_S, turbulence_share=(1.0, 1.5))


def test_bad_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="floor"):
        _adapter(floor=0.0)
    with pytest.raises(ValueError, match="ceiling"):
        _adapter(ceiling=0.9)
    with pytest.raises(ValueError, match="period_s"):
        _adapter(averaging_s=0.1)


def _scale_after(air: dict, seconds: float) -> float:
    from immukf_sitl.experiments.inprocess import run_inprocess
    from immukf_sitl.scenario import load_scenario
    from immukf_sitl.service.filter_models import RealAirModel
    from immukf_sitl.service.pipeline import PipelineConfig

    scenario = load_scenario(REPO / "scenarios" / "fault_free_windy.yaml")
    scenario = dataclasses.replace(scenario, wind=dataclasses.replace(scenario.wind, **air))
    config = PipelineConfig(
        variant="ukf2", sensors=scenario.sensors.spec_sheet(), filter_model=RealAirModel()
    )
    run = run_inprocess(scenario, config, duration_s=seconds)
    return run.pipeline.estimate.turbulence.scale


@pytest.mark.slow
def test_the_filter_learns_calm_air_from_rough() -> None:
    """The real-air filter over JSBSim on a drawn airframe: in still air its turbulence noise
    falls well below the design's; in the design's moderate turbulence it stays near it."""
    calm = _scale_after({"speed_mps": 0.0, "turbulence": "none"}, 45.0)
    rough = _scale_after({"speed_mps": 10.0, "turbulence": "moderate"}, 45.0)
    assert calm < 0.3
    assert rough > 0.7

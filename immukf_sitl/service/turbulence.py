"""How rough the air is, learnt in flight from the filter's own innovations.

The real-air model drives its wind and rotational-gust states as hard as its design air
(:class:`~immukf_sitl.service.filter_models.RealAirModel`, moderate turbulence: by default the
roughest it is meant to hold in). In calmer air that design trusts the model's prediction of the IMU
far less than the air allows (in calm air the healthy filter's accelerometer innovations have about
half the standard deviation it predicts), and the wind and gust states explain away a dead channel's
small change of reading before its mode can win. A design for calm air fails the other way, in rough
air. So the intensity is estimated, not assumed.

MIL-F-8785C scales every gust intensity (``sigma_u``, ``sigma_v``, ``sigma_w`` and the
rotational gusts) with one number, W20. So one scale ``k = sigma_flown / sigma_design``
(``floor <= k <= ceiling``) multiplies the standard deviations of the turbulence states' driving
noise, and of the part of the model-error corrections' driving noise that the gusts make.
It is learnt by innovation-based covariance matching (Mehra, IEEE TAC 15(2), 1970; Mohamed &
Schwarz, J. Geodesy 73, 1999). On each IMU channel the leading mode trusts, the
innovation variance beyond the sensor noise, ``<nu^2 - R>``, is compared with what the filter
predicted beyond it, ``<S - R>``; both are exponential averages over ``averaging_s``. The
median of the channels' ratios moves ``k^2`` geometrically toward consistency, with gain
``period / averaging_s`` per update. The median means a dead channel, whose innovation the
healthy mode cannot explain, moves the estimate by one rank at most.

The floor keeps the wind learnable. With no driving noise at all (``k = 0``, a design for
still air), the filter lost the wind and its position in calm air within 10 s. The ceiling is
the roughest air the filter is built for over the design's (by default the design itself, 1:
the real-air model's ``roughest_turbulence``; docs/design/real-air-model.md shows the flights
that kept it).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numba
import numpy as np

from immukf_sitl.estimation import ProcessModel

__all__ = ["TurbulenceAdapter", "TurbulenceEstimate"]

#: an innovation beyond this many sigmas counts as this many (one outlier is not the air)
_CLIP_SIGMAS = 5.0


@numba.njit(cache=True)
def _information(s: float, q: float) -> float:
    """What one innovation of variance ``s + q`` tells of ``q``: ``1 / (s + q)^2`` (Fisher's, x2).

    ``nu ~ N(0, S + q)`` gives ``q`` the information ``1 / (2 (S + q)^2)``, so the maximum-
    likelihood ``q`` of many samples is their average of ``nu^2 - S`` weighted by it. A sample
    whose ``S`` is the filter's start-up uncertainty (``S`` 10^3 times the air's) weighs 10^-6 of
    one in steady flight, where an unweighted average carried its ``nu^2 - S`` (large and
    negative) for a minute and hid the spread the filter does not explain.
    """
    return 1.0 / max(s + q, 1e-300) ** 2


@numba.njit(cache=True)
def _fold(
    excess: np.ndarray, predicted: np.ndarray, weight: np.ndarray, beyond: np.ndarray,
    beyond_weight: np.ndarray, nu: np.ndarray, s: np.ndarray, r: np.ndarray,
    trusted: np.ndarray, nu_base: np.ndarray, s_base: np.ndarray, trusted_base: np.ndarray,
    alpha: float, alpha_beyond: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:  # fmt: skip
    """One step into the averages of ``nu^2 - R``, ``S - R``, ``nu^2 - S`` and their weights.

    The first two are the leading mode's, the third the base mode's, each sample of the third
    weighted by what it tells of the variance (:func:`_information`, at the estimate so far).
    """
    n = excess.shape[0]
    for i in range(n):
        if not (math.isfinite(nu[i]) and math.isfinite(s[i])):
            return None
        if not (math.isfinite(nu_base[i]) and math.isfinite(s_base[i])):
            return None
    new_excess = np.empty(n)
    new_predicted = np.empty(n)
    new_weight = np.empty(n)
    new_beyond = np.empty(n)
    new_beyond_weight = np.empty(n)
    for i in range(n):
        g = alpha * trusted[i]
        nu2 = min(nu[i] * nu[i], _CLIP_SIGMAS * _CLIP_SIGMAS * s[i])
        new_excess[i] = excess[i] + g * (nu2 - r[i] - excess[i])
        new_predicted[i] = predicted[i] + g * (s[i] - r[i] - predicted[i])
        new_weight[i] = weight[i] + g * (1.0 - weight[i])
        h = alpha_beyond * trusted_base[i]
        nu2_base = min(nu_base[i] * nu_base[i], _CLIP_SIGMAS * _CLIP_SIGMAS * s_base[i])
        q = 0.0
        if beyond_weight[i] > 0.0:
            q = max(beyond[i], 0.0) / beyond_weight[i]
        info = _information(s_base[i], q)
        new_beyond[i] = (1.0 - h) * beyond[i] + h * info * (nu2_base - s_base[i])
        new_beyond_weight[i] = (1.0 - h) * beyond_weight[i] + h * info
    return new_excess, new_predicted, new_weight, new_beyond, new_beyond_weight


@dataclass(frozen=True)
class TurbulenceEstimate:
    """The adapter's state at one step (immutable; carried by the estimate).

    Attributes
    ----------
    scale : float
        ``k``: the flown turbulence intensity over the design's (standard deviations).
    excess : ndarray, shape (6,)
        Average ``nu^2 - R`` per IMU channel (unit^2).
    predicted : ndarray, shape (6,)
        Average ``S - R`` per IMU channel (unit^2).
    weight : ndarray, shape (6,)
        Total weight of the averages per channel (1 once ``averaging_s`` of data is in).
    beyond : ndarray, shape (6,)
        Exponential sum over ``unexplained_averaging_s`` of ``(nu^2 - S) / (S + q)^2`` per IMU
        channel, ``q`` the average so far (:func:`_information`; unit^-2).
    beyond_weight : ndarray, shape (6,)
        The same sum of ``1 / (S + q)^2``: ``beyond / beyond_weight`` is the average.
    steps : int
        Steps since the last change of ``scale``.
    gps_beyond, gps_beyond_weight : ndarray, shape (n,)
        Average ``nu^2 - S`` of the base mode's GPS channels over ``unexplained_averaging_s``
        and its weight, unweighted (empty before the first fix; :meth:`TurbulenceAdapter.
        update_gps`).
    gps_t_s : float
        Time of the last fix folded in (NaN: none yet).
    """

    scale: float = 1.0
    excess: np.ndarray = field(default_factory=lambda: np.zeros(6))
    predicted: np.ndarray = field(default_factory=lambda: np.zeros(6))
    weight: np.ndarray = field(default_factory=lambda: np.zeros(6))
    beyond: np.ndarray = field(default_factory=lambda: np.zeros(6))
    beyond_weight: np.ndarray = field(default_factory=lambda: np.zeros(6))
    steps: int = 0
    gps_beyond: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gps_beyond_weight: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gps_t_s: float = math.nan

    def forget_unexplained(self, channels: np.ndarray) -> TurbulenceEstimate:
        """The estimate with the average of ``nu^2 - S`` of ``channels`` (a mask) emptied.

        A channel declared or released: its innovations since the failure measured the
        failure, not the air, and the slot that trusts it again must not borrow their spread.
        """
        keep = ~np.asarray(channels, dtype=bool)
        return dataclasses.replace(
            self, beyond=self.beyond * keep, beyond_weight=self.beyond_weight * keep
        )

    def unexplained_var(self) -> np.ndarray:
        """``(6,)``: the variance ``q`` the innovations show beyond ``S``, per channel (unit^2).

        What the innovations show that the filter's covariance does not (at least 0): the
        maximum-likelihood ``q`` of ``nu ~ N(0, S + q)``, one scoring step a sample, over what
        has been seen, so from the first steps (0 on a channel not seen yet). The scale ``k``
        is one number for every channel; this is what each channel keeps beyond it.
        """
        return _average(self.beyond, self.beyond_weight)

    def gps_unexplained_var(self, n: int) -> np.ndarray:
        """``(n,)``: :meth:`unexplained_var` of the ``n`` GPS channels (0 before any fix).

        A fault mode that leaves a channel out predicts the fix more loosely than the base,
        so it gains on every fix the base is overconfident on, whatever the channel did:
        scored against the spread the base's fixes show, it gains only on what that spread
        does not explain.
        """
        if self.gps_beyond.shape != (n,):
            return np.zeros(n)
        return _average(self.gps_beyond, self.gps_beyond_weight)


def _average(total: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """``max(total, 0) / weight`` where some weight is in, else 0."""
    ready = weight > 0.0
    out = np.zeros(total.shape)
    out[ready] = np.maximum(total[ready], 0.0) / weight[ready]
    return out


@dataclass(frozen=True, eq=False)
class TurbulenceAdapter:
    """Learns the turbulence scale and gives the process model that scale implies.

    Parameters
    ----------
    process : ProcessModel
        The filter's process model at the design air (scale 1).
    turbulence_idx : sequence of int
        States whose driving noise is the turbulence's (the wind and the rotational gusts), or
        partly so (the model-error corrections).
    noise_var : ndarray, shape (6,)
        ``R`` of the six IMU channels.
    dt_s : float
        Filter step (s).
    averaging_s : float
        Time constant of the innovation averages (s).
    unexplained_averaging_s : float
        Time constant of the average of ``nu^2 - S`` (s): long against the second or so a
        failing sensor takes to be declared, so that its innovations barely enter it.
    period_s : float
        Time between updates of the scale (s).
    floor : float
        Smallest scale.
    ceiling : float
        Largest scale.
    turbulence_share : sequence of float, optional
        The part of each of those states' driving variance that is the turbulence's (default
        all of it); the rest stays at the design's.
    """

    process: ProcessModel
    turbulence_idx: Sequence[int]
    noise_var: np.ndarray
    dt_s: float
    averaging_s: float = 10.0
    unexplained_averaging_s: float = 60.0
    period_s: float = 0.5
    floor: float = 0.1
    ceiling: float = 1.0
    turbulence_share: Sequence[float] | None = None
    _cache: dict[float, ProcessModel] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        if not 0.0 < self.floor <= 1.0 <= self.ceiling:
            raise ValueError(
                "turbulence scale: expected 0 < floor <= 1 <= ceiling, got "
                f"{self.floor} and {self.ceiling}"
            )
        if not 0.0 < self.dt_s <= min(self.period_s, self.unexplained_averaging_s):
            raise ValueError(
                "turbulence adapter: expected 0 < dt_s <= period_s and unexplained_averaging_s"
            )
        if not 0.0 < self.dt_s <= self.period_s <= self.averaging_s:
            raise ValueError(
                "turbulence adapter: expected 0 < dt_s <= period_s <= averaging_s, got "
                f"{self.dt_s}, {self.period_s}, {self.averaging_s}"
            )
        object.__setattr__(self, "turbulence_idx", tuple(int(i) for i in self.turbulence_idx))
        share = self.turbulence_share
        share = np.ones(len(self.turbulence_idx)) if share is None else np.asarray(share, float)
        if share.shape != (len(self.turbulence_idx),) or np.any((share < 0.0) | (share > 1.0)):
            raise ValueError("turbulence_share: expected one value in [0, 1] per turbulence state")
        object.__setattr__(self, "turbulence_share", share)
        object.__setattr__(self, "noise_var", np.asarray(self.noise_var, dtype=float))

    @cached_property
    def _alpha(self) -> float:
        """Weight of one step in the exponential averages."""
        return -math.expm1(-self.dt_s / self.averaging_s)

    @cached_property
    def _alpha_beyond(self) -> float:
        """Weight of one step in the average of what the covariance does not explain."""
        return -math.expm1(-self.dt_s / self.unexplained_averaging_s)

    @cached_property
    def _period_steps(self) -> int:
        return max(1, round(self.period_s / self.dt_s))

    def update(
        self,
        estimate: TurbulenceEstimate,
        innovation: np.ndarray,
        innovation_var: np.ndarray,
        trusted: np.ndarray,
        base: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> TurbulenceEstimate:
        """Fold one step's IMU innovations in; every ``period_s`` move the scale.

        Parameters
        ----------
        estimate : TurbulenceEstimate
            The state before this step.
        innovation, innovation_var : ndarray, shape (6,)
            The leading mode's IMU innovations and their variances (diagonal of ``S``).
        trusted : ndarray, shape (6,)
            1 (or True) on the channels that mode takes as healthy, 0 on its failed ones (a
            failed channel's ``S`` is ``R``: it says nothing of the air).
        base : (ndarray, ndarray, ndarray), optional
            The innovations, variances and trusted channels of the mode the spread beyond
            ``S`` is learnt on: the base mode, the one it is added to when the modes are
            scored (default: the leading mode's above). A fault mode that leads on the spread
            the base does not explain would otherwise stop that spread being learnt.
        """
        nu_base, s_base, trusted_base = (
            (innovation, innovation_var, trusted) if base is None else base
        )
        averages = _fold(
            estimate.excess, estimate.predicted, estimate.weight, estimate.beyond,
            estimate.beyond_weight, np.asarray(innovation, dtype=float),
            np.asarray(innovation_var, dtype=float), self.noise_var,
            np.asarray(trusted, dtype=float), np.asarray(nu_base, dtype=float),
            np.asarray(s_base, dtype=float), np.asarray(trusted_base, dtype=float),
            self._alpha, self._alpha_beyond,
        )  # fmt: skip
        if averages is None:
            return estimate  # a filter reset this step: nothing to learn from
        excess, predicted, weight, beyond, beyond_weight = averages
        steps = estimate.steps + 1
        scale = estimate.scale
        if steps >= self._period_steps:
            steps = 0
            scale = self._rescaled(scale, excess, predicted, weight)
        return dataclasses.replace(
            estimate, scale=scale, excess=excess, predicted=predicted, weight=weight,
            beyond=beyond, beyond_weight=beyond_weight, steps=steps,
        )  # fmt: skip

    def update_gps(
        self,
        estimate: TurbulenceEstimate,
        t_s: float,
        innovation: np.ndarray,
        innovation_var: np.ndarray,
    ) -> TurbulenceEstimate:
        """Fold one fix's innovations of the base mode into the average of ``nu^2 - S``.

        Each fix weighs by the time since the previous one (``unexplained_averaging_s`` time
        constant), and counts at most :data:`_CLIP_SIGMAS` sigmas, as the IMU channels do.
        Not weighted by what it tells of the variance, as the IMU channels are: so weighted,
        the fixes' spread was learnt in the first minute too, the slow test (which scores the
        fault modes at the fixes) declared a roll-gyro drift 2.9 s sooner on the light-air test
        flight, named it spikes, and the roll was up to 21 deg off over the next 4 s
        (docs/design/real-air-model.md).
        """
        nu = np.asarray(innovation, dtype=float)
        s = np.asarray(innovation_var, dtype=float)
        if not (np.all(np.isfinite(nu)) and np.all(np.isfinite(s))):
            return estimate
        n = nu.shape[0]
        beyond, weight = estimate.gps_beyond, estimate.gps_beyond_weight
        if beyond.shape != (n,):
            beyond, weight = np.zeros(n), np.zeros(n)
        elapsed = t_s - estimate.gps_t_s if math.isfinite(estimate.gps_t_s) else self.dt_s
        g = -math.expm1(-max(elapsed, 0.0) / self.unexplained_averaging_s)
        nu2 = np.minimum(nu * nu, _CLIP_SIGMAS * _CLIP_SIGMAS * s)
        return dataclasses.replace(
            estimate,
            gps_beyond=beyond + g * (nu2 - s - beyond),
            gps_beyond_weight=weight + g * (1.0 - weight),
            gps_t_s=float(t_s),
        )

    def _rescaled(
        self, scale: float, excess: np.ndarray, predicted: np.ndarray, weight: np.ndarray
    ) -> float:
        """The scale moved toward consistency by the median channel's excess ratio."""
        ready = (weight > 1.0 - 1.0 / math.e) & (predicted > 0.0)
        if not np.any(ready):
            return scale
        ratio = float(np.median(np.maximum(excess[ready], 0.0) / predicted[ready]))
        ratio = min(max(ratio, math.exp(-4.0)), math.exp(4.0))
        scale2 = scale * scale * ratio ** (self.period_s / self.averaging_s)
        return min(max(math.sqrt(scale2), self.floor), self.ceiling)

    def process_at(self, scale: float) -> ProcessModel:
        """The process model with the turbulence's driving noise at ``scale`` (sigmas)."""
        if scale == 1.0:
            return self.process
        cached = self._cache.get(scale)
        if cached is not None:
            return cached
        idx = self.turbulence_idx
        share = np.asarray(self.turbulence_share)
        factor = 1.0 - share + share * scale * scale
        changes: dict[str, np.ndarray] = {}
        for name in ("state_noise_cov", "additive_noise_cov"):
            base = getattr(self.process, name)
            if base is not None:
                scaled = base.copy()
                scaled[idx, idx] *= factor
                changes[name] = scaled
        model = dataclasses.replace(self.process, **changes)
        self._cache.clear()  # one scale at a time: it moves every period_s
        self._cache[scale] = model
        return model

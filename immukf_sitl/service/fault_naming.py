"""Naming a declared failure: which way the channel failed (the fault kind) and by how much.

Once an untrusted mode is declared its filter no longer uses the failed channel, so its
prediction of that channel ``h`` (from the other sensors, variance ``s2`` with the sensor
noise) is an independent estimate of what the channel should read. The readings ``z`` of the
:data:`NAMING_WINDOW_S` after the declaration are then explained by each kind of
:mod:`immukf_sitl.fault_kinds` in turn, and the kind that explains them best names the failure:

- ``stuck``: the readings do not move (their spread below a tenth of the sensor's noise sigma,
  which a live sensor shows one window in never); size: the held value;
- ``zero``: ``sum z^2 / R`` within the chi-square quantile :data:`ZERO_QUANTILE`; size: none;
- otherwise the best by the Bayesian information criterion of the residual ``e = z - h``
  with ``e ~ N(m, v)``: ``bias`` (``m = b``), ``drift`` (``m = a + c t``), ``scale``
  (``m = (g - 1) h``), ``noise`` (``m = 0``, ``v = s2 + (k^2 - 1) R``) and ``spikes``, a
  contaminated normal (``N(0, s2)``, or with odds ``w`` a spike ``N(0, s2 + A^2)``); sizes
  ``b`` (in the channel's unit), ``c`` (per second), ``g``, ``k`` and ``A``. The spikes' heavy
  tail is what tells them from noise, whose every sample is wider: a 2 Hz train puts two
  spikes in the window, too few for a rule on outliers to weigh against the rest.

That list is the namer's without a record of the channel before its failure. With one (the
service keeps the last :data:`BASELINE_S` of readings, :meth:`FaultNamer.record`), the readings'
own texture names a noise and spikes before the residual is looked at, because the residual
carries the base's error of the channel, often wider and heavier-tailed than ``s2`` says (the
re-based prediction's settling, turbulence), and named noises spike trains and spike trains
noises. The second differences ``z(k) - 2 z(k-1) + z(k-2)`` cancel a true
value that moves smoothly over 20 ms; their robust sigma (the median absolute value over
0.6745, :class:`Roughness`) is the sensor's noise ``sqrt(6 R)`` plus what the air adds. Against
the same sigma over the channel's healthy seconds before the declaration (up to
:data:`BASELINE_GUARD_S` before it), a bias, a drift and a spike train keep it, a gain ``g``
scales it by ``|g|`` and a noise widens it:

- ``spikes``: more second differences beyond :data:`SPIKE_SIGMAS` robust sigmas than the
  healthy channel's own rate of them makes likely (a Poisson count at the zero test's quantile);
  a spike of size ``A`` puts ``A, -2A, A`` there, so the size is half the median peak;
- ``noise``: the ratio of the two sigmas beyond its sampling spread at that quantile (the
  median absolute deviation's, about ``sqrt(1.36 / n)`` in ``ln`` for ``n`` independent
  samples, ``n`` reduced by 36/70 for the second differences' correlation); its factor is the
  one that widens the healthy roughness by that ratio; unless a gain above 1, which roughens
  the readings too, explains the residual better (``(g - 1) h`` in it, which a noise leaves
  out);
- otherwise bias, drift and gain by the residual's information criterion as above, each also
  scored on the ratio it predicts (1 for a bias or a drift, ``|g|`` for a gain, its sigma as
  above), which tells a gain from a bias where the channel holds still and the residual
  cannot. The residual is then read through the prediction's own error over the window
  (:class:`_LoosePrediction`): the re-based prediction settles off by an offset and follows
  the channel's fluctuation with a response of its own, each within its variance ``s2 - R``,
  so neither names a gain or a bias by itself (on the tuning draw a bias of -1.66 m/s^2 on z
  in moderate air had the residual slope on ``h`` of a gain of 1.17, and a p gain of 0.45 the
  slope of one of 0.81).

Without a record, a noise's factor is read from the readings' second differences alone, white
noise of variance ``6 k^2 R`` (in turbulence the air's own roughness reads as a larger factor,
which the record takes out); the residual's width would overstate it by the base's own error
of the declared channel (on the held-out draw a gyro's factor of 4.4 was named 40). One second
of readings gives the factor to about 10 %, and the second after a declaration is often
rougher than the noise (the autopilot answers the re-based estimate), so the factor is read
again over :data:`SECOND_LOOK_S`.

A drift is named only when its ramp moves the channel by more than :data:`DRIFT_SIGMAS` sigmas
of the prediction (``sqrt(s2 - R)``) over the window. The mode declared has not read the channel
for a while (a fault mode keeps its own history), and once it is the base its prediction settles
by a sigma or two in the first few tenths of a second: without the rule, 8 of 17 biases of the
tuning draw were named drifts of the settling's slope. The cost: a drift too slow to show
beyond that in one second is named a bias (its size the window's mean).

The window stays one second. Over longer ones the base filter's prediction of the declared
channel moves toward its reading (on the tuning draw, 10 s after an x-accelerometer gain of
0.57 was declared, the prediction read what the faulty channel did), so the residual grows a
slope that is not the fault's, and gains and biases were named drifts.

A failure named a bias, a drift or a gain is looked at again :data:`SECOND_LOOK_S` after its
declaration (:func:`second_look`): a drift slow enough to pass for a bias in the first second
has moved its channel further by then, its rate is read over seconds rather than through the
re-based prediction's settling, a gain has seen its channel's true value move, and a spike
train quiet in its first second (which a gain of nearly 1 explained) has spiked. The pull of
the prediction toward the reading only ever shrinks the residual, so a residual that keeps
growing away from zero, by more than the drift rule's sigmas, is the fault's own ramp. The
failure is named again where the whole window names it otherwise, or a drift at another
rate. A bias or a drift the second look names is looked at a last time, :data:`LAST_LOOK_S`
after the declaration, over the whole window: a bias is named anew if that finds a drift or a
gain, a drift gets the rate of those seconds. The re-based prediction wanders off the truth
by about its own sigma for seconds at a time, and over five seconds that wander's slope can
be as large as the drift's (a pitch-gyro drift of -0.015 rad/s^2 in light air read -0.030);
a line's slope through a wander shorter than the window errs as its length to the power
-1.5, five times less over fifteen seconds (that drift then read -0.021). A drift's ramp
goes on, so the line through the whole window moves the channel further than the second
look's did (three times as far at a steady rate); a settling prediction's does not (for an
exponential settling of time constant 1.5 s, 0.48 of its size over fifteen seconds against
0.82 over five). A drift whose ramp the whole window does not carry on is named by what that
window shows: a pitch-gyro bias of 0.036 rad/s in moderate air read as a drift of 0.019
rad/s^2 over five seconds and as a bias of 0.036 over fifteen.

A name whose fitted deviation from the healthy reading stays inside the band a healthy sensor
reads off the truth (``bands``: 5 sigmas of noise and turn-on bias, the band that defines a
detectable fault) shows no failure: the first second of a spike train that has not spiked
again, a gain while its channel holds still. It is not published (:data:`UNSEEN`), and the
failure is named by every kind over the second look's seconds.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.stats import chi2, norm, poisson

from immukf_sitl.models.sensors import MIN_NOISE_FACTOR

__all__ = [
    "NAMING_WINDOW_S",
    "SECOND_LOOK_S",
    "UNSEEN",
    "FailureName",
    "FaultNamer",
    "Roughness",
    "classify_failure",
    "roughness",
    "second_look",
]

#: how long after a declaration the readings are gathered before the failure is named (s)
NAMING_WINDOW_S = 1.0
#: the zero test's quantile (as the detector's)
ZERO_QUANTILE = 0.999
#: readings whose spread is below this many noise sigmas are not a live sensor's
STUCK_SPREAD_SIGMAS = 0.1
#: a drift moves its channel by more than this many sigmas of the prediction over the window
DRIFT_SIGMAS = 3.0
#: how long after a declaration a failure named a bias, a drift, a gain or a noise is looked at
#: again (s)
SECOND_LOOK_S = 5.0
#: how long after a declaration a failure its second look names a bias or a drift is looked at
#: a last time (s): a slow drift moves its channel by its prediction's sigmas only over seconds,
#: and a drift's rate read over them errs less than over the second look's
LAST_LOOK_S = 15.0
#: the name of a window whose best explanation stays within what a healthy sensor reads (the
#: first second of a spike train that has not spiked again, a gain on a channel holding still):
#: never published; the failure is named over the seconds of the second look instead
UNSEEN = "unseen"
#: expectation-maximisation steps of the spike mixture's fit (it settles in a few dozen)
_SPIKE_EM_STEPS = 60
#: how long before a declaration a channel's readings are kept for its healthy roughness (s)
BASELINE_S = 10.0
#: the seconds just before a declaration left out of that: the failure may already act in them
#: (a jump is declared within the 0.2 s dwell, a noise within a second in most runs)
BASELINE_GUARD_S = 1.0
#: the variance of ln(MAD sigma) of n normal samples is about this over n (Hampel 1974: the
#: median absolute deviation's asymptotic efficiency of 37 %)
_MAD_LOG_VARIANCE = 1.36
#: a second difference beyond this many robust sigmas of the readings' roughness is a spike's
#: (the detectable band's 5)
SPIKE_SIGMAS = 5.0
#: second differences of white noise are correlated (lags 1 and 2: -4/6 and 1/6), so n of them
#: weigh as n * 36 / 70 independent ones in a sum of squares
_SECOND_DIFFERENCE_DOF = 36.0 / 70.0


@dataclass(frozen=True)
class FailureName:
    """A failure's kind and size (None where the kind has no size)."""

    kind: str
    size: float | None


def classify_failure(
    t_s: np.ndarray,
    z: np.ndarray,
    h: np.ndarray,
    s2: np.ndarray,
    noise_sigma: float,
    band: float | None = None,
    baseline: Roughness | None = None,
) -> FailureName:
    """The kind and size of a failed channel from its readings and the healthy prediction.

    Parameters
    ----------
    t_s : ndarray, shape (n,)
        Sample times (s).
    z : ndarray, shape (n,)
        The channel's readings.
    h : ndarray, shape (n,)
        The declared mode's prediction of the channel from the other sensors.
    s2 : ndarray, shape (n,)
        Variance of ``z - h`` for a healthy channel (prediction and sensor noise).
    noise_sigma : float
        The sensor's white-noise sigma.
    band : float, optional
        Half-width of what a healthy channel may read off the truth (its noise and turn-on
        bias); a bias, drift, gain or spike train that keeps the residual's fitted deviation
        within it shows no failure, and is named :data:`UNSEEN`. None: always a kind.
    baseline : Roughness, optional
        The channel's roughness before the failure (:func:`roughness`). The readings' own
        texture then names spikes and a noise first (their outliers, their widening of it:
        the factor is the one that widening says), and a gain ``g`` also explains the
        roughness it scales by ``|g|``, which a bias or a drift leaves. None: the residual
        alone names the failure.
    """
    t, z, h, s2 = (np.asarray(a, dtype=float) for a in (t_s, z, h, s2))
    n = z.size
    if n < 3:
        raise ValueError(f"classify_failure: expected at least 3 samples, got {n}")
    r = noise_sigma**2
    if np.std(z) < STUCK_SPREAD_SIGMAS * noise_sigma:
        return FailureName("stuck", float(np.mean(z)))
    if np.sum(z * z) / r <= chi2.ppf(ZERO_QUANTILE, n):
        return FailureName("zero", None)
    e = z - h
    texture = None if baseline is None else _texture(t, z, baseline)
    if texture is None:
        candidates = [
            _bias(e, s2), _drift(t, e, s2), _scale(e, h, s2), _noise(e, s2, r), _spikes(e, s2)
        ]  # fmt: skip
    elif texture.spike_size is not None:
        return FailureName("spikes", texture.spike_size)
    elif _rougher(texture, baseline, r):  # a noise, or a gain above 1, which roughens too
        return _noise_or_gain(e, h, s2, r, texture, baseline)
    else:  # the residual names an offset or a gain; the roughness weighs a gain against them
        loose = _LoosePrediction(h, s2, r)
        candidates = [
            _unscaled(loose.bias(e), texture),
            _unscaled(loose.drift(t, e)[0], texture),
            _scale_of_roughness(e, h, texture, loose),
        ]
    # a ramp the prediction's own error could make is no drift: h's error (variance s2 - R)
    # settles over the window after a declaration, by up to a few of its sigmas
    prediction_sigma = math.sqrt(max(float(np.mean(s2)) - r, 0.0))
    drift = candidates[1]
    if abs(drift[3]) * float(t[-1] - t[0]) <= DRIFT_SIGMAS * prediction_sigma:
        candidates.remove(drift)
    best = max(candidates, key=lambda c: c[0] - 0.5 * c[1] * math.log(n))
    if band is not None and best[2] != "noise" and _deviation(t, e, h, s2, best) <= band:
        return FailureName(UNSEEN, None)
    if best[2] == "noise":
        factor = _roughness_factor(t, z, r)
        return FailureName("noise", best[3] if factor is None else factor)
    return FailureName(best[2], best[3])


def _rougher(texture: _Texture, baseline: Roughness, r: float) -> bool:
    """Whether the readings are rougher than a healthy channel's by a detectable noise's worth.

    A widening that a noise of at most :data:`MIN_NOISE_FACTOR` would explain is one no sample
    shows (the smallest detectable noise): it names no noise, and a bias, a drift or a gain is
    weighed with the roughness instead. On the tuning draw a calm x accelerometer's 1.9 m/s^2
    bias roughened its readings by ``e^0.31`` against a baseline below the sensor's own noise
    (``sqrt(6 R)``), a noise of 1.19 by the ratio, and the second look named it that.
    """
    return texture.rough and baseline.factor(texture.log_ratio, r) > MIN_NOISE_FACTOR


def _noise_or_gain(
    e: np.ndarray, h: np.ndarray, s2: np.ndarray, r: float, texture: _Texture,
    baseline: Roughness,
) -> FailureName:  # fmt: skip
    """Readings rougher than the channel's own: a noise, or a gain above 1.

    A noise widens the roughness by the factor that widening says; a gain above 1 scales it by
    ``g`` and puts ``(g - 1) h`` in the residual (a range set wrong reads twice the truth).

    Both are scored on the residual read through the prediction's own error
    (:class:`_LoosePrediction`): the noise's with the sensor's variance widened by its factor
    (the prediction's budget ``s2 - R`` kept), the gain's with the roughness it explains.
    """
    factor = baseline.factor(texture.log_ratio, r)
    noisy = _LoosePrediction(h, s2 + (factor**2 - 1.0) * r, factor**2 * r)
    gain = _scale_of_roughness(e, h, texture, _LoosePrediction(h, s2, r))
    if gain[0] > noisy.log_likelihood(e):  # one parameter each
        return FailureName("scale", gain[3])
    return FailureName("noise", factor)


def _deviation(
    t: np.ndarray, e: np.ndarray, h: np.ndarray, s2: np.ndarray,
    fit: tuple[float, int, str, float],
) -> float:  # fmt: skip
    """The largest deviation from the healthy reading that a fitted kind puts on the window."""
    kind, size = fit[2], fit[3]
    if kind == "bias":
        return abs(size)
    if kind == "drift":
        return float(np.max(np.abs(_line(t, e, s2)[0])))
    if kind == "scale":
        return float(np.max(np.abs((size - 1.0) * h)))
    return size  # spikes: their rms


def _roughness_factor(t: np.ndarray, z: np.ndarray, r: float) -> float | None:
    """The noise factor ``k`` from the readings' second differences (None: under 3 of them)."""
    second = _second_differences(t, z)
    if second.size < 3:
        return None
    return math.sqrt(max(float(np.mean(second**2)) / (6.0 * r), 1.0))


@dataclass(frozen=True)
class Roughness:
    """How rough a channel's readings are: the robust sigma of their second differences.

    ``sigma`` is the median absolute second difference over 0.6745 (the normal's), in the
    channel's unit, read from ``count`` second differences, of which ``outliers`` lie beyond
    :data:`SPIKE_SIGMAS` of it. A healthy sensor's is its noise's ``sqrt(6 R)`` plus what the
    air adds (on z in moderate turbulence about ten times that); a bias, a drift or a spike
    train keeps it (a median ignores a few spikes), a gain scales it and a noise widens it.

    ``spread``, on a channel's roughness before its failure, is how far the healthy channels'
    roughness moved over the seconds being named, against theirs over the same seconds before
    (the rms of their ``ln`` ratios; :meth:`FaultNamer.flight_spread`): the flight's own
    change, which the sampling spread of a ratio leaves out. 0: not known.
    """

    sigma: float
    count: int
    outliers: int
    spread: float = 0.0

    def factor(self, log_ratio: float, r: float) -> float:
        """The noise factor that widens this roughness by ``exp(log_ratio)`` (at least 1).

        A noise of factor ``k`` adds ``6 (k^2 - 1) R`` to the second differences' variance.
        """
        added = self.sigma**2 * (math.exp(2.0 * log_ratio) - 1.0)
        return math.sqrt(max(1.0 + added / (6.0 * r), 1.0))


@dataclass(frozen=True)
class _Texture:
    """Readings' roughness against the channel's before the failure.

    ``log_ratio`` is ``ln`` of their robust sigmas' ratio and ``sigma`` its sampling sigma;
    ``rough``: the ratio beyond what that spread explains at :data:`ZERO_QUANTILE`;
    ``spike_size``: the spikes' size where more second differences lie beyond
    :data:`SPIKE_SIGMAS` than the healthy channel's rate of them explains (None: no spikes).
    """

    log_ratio: float
    sigma: float
    rough: bool
    spike_size: float | None


def _second_differences(t: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``z(k) - 2 z(k-1) + z(k-2)`` over evenly spaced triplets (a sample left out breaks one)."""
    dt = np.diff(t)
    even = np.isclose(dt[1:], dt[:-1], rtol=1e-3)
    return (z[2:] - 2.0 * z[1:-1] + z[:-2])[even]


def roughness(t_s: np.ndarray, z: np.ndarray) -> Roughness | None:
    """The readings' :class:`Roughness` (None: under 3 second differences, or no spread)."""
    t, z = np.asarray(t_s, dtype=float), np.asarray(z, dtype=float)
    second = _second_differences(t, z) if t.size >= 5 else np.empty(0)
    if second.size < 3:
        return None
    sigma = float(np.median(np.abs(second))) / 0.6745
    if sigma <= 0.0:
        return None
    return Roughness(sigma, int(second.size), int(np.sum(np.abs(second) > SPIKE_SIGMAS * sigma)))


def _texture(t: np.ndarray, z: np.ndarray, baseline: Roughness) -> _Texture | None:
    """The readings' :class:`_Texture` against ``baseline`` (None: they have no roughness).

    The ratio's sigma is the two robust sigmas' sampling spread (:data:`_MAD_LOG_VARIANCE`
    over the effective count of each), or the baseline's ``spread`` where the healthy channels'
    own ratios spread wider over the same seconds: after a declaration the autopilot flies on
    a new estimate and the air changes (over the 15 s after an x-accelerometer declaration in
    the tuning draw's moderate air a healthy roll gyro's roughness moved by ``e^-0.25``, four
    sampling sigmas). A spike of size ``A`` puts ``A, -2A, A`` in the second differences;
    the count beyond :data:`SPIKE_SIGMAS` is tested against a Poisson count at the healthy
    channel's rate (half an outlier added, so that a baseline without one does
    not call every outlier a spike), and the spikes' size is half the median peak.
    """
    now = roughness(t, z)
    if now is None:
        return None
    log_ratio = math.log(now.sigma / baseline.sigma)
    sampling = math.sqrt(
        _MAD_LOG_VARIANCE / _SECOND_DIFFERENCE_DOF * (1.0 / now.count + 1.0 / baseline.count)
    )
    sigma = max(sampling, baseline.spread)
    second = _second_differences(t, z)
    threshold = SPIKE_SIGMAS * max(now.sigma, baseline.sigma)
    beyond = np.abs(second) > threshold
    expected = (baseline.outliers + 0.5) * second.size / baseline.count
    spike_size = None
    count = int(np.sum(beyond))
    if count and poisson.sf(count - 1, expected) < 1.0 - ZERO_QUANTILE:
        runs = np.split(np.abs(second), np.flatnonzero(np.diff(beyond)) + 1)
        spike_size = 0.5 * float(np.median([np.max(run) for run in runs if run[0] > threshold]))
    rough = log_ratio > norm.ppf(ZERO_QUANTILE) * sigma
    return _Texture(log_ratio, sigma, rough, spike_size)


def _unscaled(
    fit: tuple[float, int, str, float], texture: _Texture
) -> tuple[float, int, str, float]:
    """A bias's or a drift's fit with the log-likelihood of the roughness it keeps (ratio 1)."""
    return fit[0] - 0.5 * (texture.log_ratio / texture.sigma) ** 2, fit[1], fit[2], fit[3]


def _scale_of_roughness(
    e: np.ndarray, h: np.ndarray, texture: _Texture, loose: _LoosePrediction
) -> tuple[float, int, str, float]:
    """A gain fitted to the residual ``(g - 1) h`` and to the roughness ratio ``|g|`` at once.

    Where the channel holds still the residual cannot tell a gain from a bias, and its
    roughness, scaled by ``|g|``, still can. The residual is read with the prediction's own
    error over the window (:class:`_LoosePrediction`): its offset and its slope on ``h`` say
    ``g`` only beyond what that error allows.
    """

    def log_likelihood(g: float) -> float:
        rough = -0.5 * ((texture.log_ratio - math.log(max(abs(g), 1e-3))) / texture.sigma) ** 2
        return loose.log_likelihood(e - (g - 1.0) * h) + rough

    residual_only = 1.0 + float(loose.fit(e, h[:, None])[1][0])
    fit = minimize_scalar(lambda g: -log_likelihood(g), bounds=(1e-3, 10.0), method="bounded")
    gain = max((residual_only, float(fit.x)), key=log_likelihood)
    return log_likelihood(gain), 1, "scale", gain


def _noise_factor(
    t: np.ndarray, z: np.ndarray, r: float, baseline: Roughness | None
) -> float | None:
    """A noise's factor from the readings' roughness: against ``baseline`` where there is one."""
    if baseline is None:
        return _roughness_factor(t, z, r)
    texture = _texture(t, z, baseline)
    return None if texture is None else baseline.factor(texture.log_ratio, r)


def _gaussian(e: np.ndarray, mean: np.ndarray | float, var: np.ndarray) -> float:
    return float(-0.5 * np.sum((e - mean) ** 2 / var + np.log(2.0 * np.pi * var)))


def _bias(e: np.ndarray, s2: np.ndarray) -> tuple[float, int, str, float]:
    w = 1.0 / s2
    b = float(np.sum(w * e) / np.sum(w))
    return _gaussian(e, b, s2), 1, "bias", b


def _line(t: np.ndarray, e: np.ndarray, s2: np.ndarray) -> tuple[np.ndarray, float, float]:
    """The weighted straight line through ``e``: its values, its value at the mean time, slope."""
    w = 1.0 / s2
    basis = np.column_stack([np.ones_like(t), t - t.mean()])
    coef = np.linalg.lstsq(basis * np.sqrt(w)[:, None], e * np.sqrt(w), rcond=None)[0]
    return basis @ coef, float(coef[0]), float(coef[1])


def _drift(t: np.ndarray, e: np.ndarray, s2: np.ndarray) -> tuple[float, int, str, float]:
    fitted, _, slope = _line(t, e, s2)
    return _gaussian(e, fitted, s2), 2, "drift", slope


class _LoosePrediction:
    """The residual's likelihood with the re-based prediction's own error over the window.

    The prediction ``h`` of a declared channel has an error of variance ``s2 - R`` by its own
    account, and over a window that error is partly shared by its samples: an offset (the
    re-based filter settling) and a response of its own to the true value's fluctuation (a
    slope on ``f = h - mean(h)``; z in turbulence follows its channel loosely). Either, drawn
    from that budget (``a ~ N(0, s2 - R)``, ``c ~ N(0, (s2 - R) / var(h))``) and integrated
    out, gives the residual the covariance ``S + U D U'`` (``U = [1, f]``), whose inverse and
    determinant the push-through identity gives from 2 x 2 matrices. An offset or a slope
    within that budget is then no evidence of a bias against a gain: the offset the gain makes
    through the mean of ``h`` and the roughness tell them apart, and a slope beyond the budget
    (a gyro's gain in still air, closely predicted) still names a gain.
    """

    def __init__(self, h: np.ndarray, s2: np.ndarray, r: float) -> None:
        self._w = 1.0 / np.sqrt(s2)
        budget = max(float(np.mean(s2)) - r, 0.0)
        spread = float(np.var(h))
        self._d = np.array([budget, budget / spread if spread > 0.0 else 0.0])
        self._u = np.column_stack([np.ones_like(h), h - float(np.mean(h))]) * self._w[:, None]
        inner = np.eye(2) + self._d[:, None] * (self._u.T @ self._u)  # I + D U'U
        # push-through: (I + U D U')^-1 = I - U (I + D U'U)^-1 D U'; det = det(I + D U'U)
        self._m = np.linalg.inv(inner)
        self._constant = math.log(np.linalg.det(inner)) + float(np.sum(np.log(2.0 * np.pi * s2)))

    def _inverse(self, v: np.ndarray) -> np.ndarray:
        """``(I + U D U')^-1 v`` for whitened ``v`` (a vector or the columns of a matrix)."""
        projected = self._u.T @ v
        scaled = self._d.reshape((2,) + (1,) * (projected.ndim - 1)) * projected  # D U' v
        return v - self._u @ (self._m @ scaled)

    def log_likelihood(self, residual: np.ndarray) -> float:
        """``ln N(residual; 0, S + U D U')``."""
        y = residual * self._w
        return -0.5 * (float(y @ self._inverse(y)) + self._constant)

    def fit(self, e: np.ndarray, columns: np.ndarray) -> tuple[float, np.ndarray]:
        """The mean ``columns @ beta`` fitted to ``e`` under that covariance, its likelihood."""
        x, y = columns * self._w[:, None], e * self._w
        ix = self._inverse(x)
        beta = np.linalg.lstsq(x.T @ ix, ix.T @ y, rcond=None)[0]
        return self.log_likelihood(e - columns @ beta), beta

    def bias(self, e: np.ndarray) -> tuple[float, int, str, float]:
        """A bias's fit."""
        log_likelihood, beta = self.fit(e, np.ones((e.size, 1)))
        return log_likelihood, 1, "bias", float(beta[0])

    def drift(self, t: np.ndarray, e: np.ndarray) -> tuple[tuple[float, int, str, float], float]:
        """A drift's fit, and its line's value at the mean time."""
        log_likelihood, beta = self.fit(e, np.column_stack([np.ones_like(t), t - t.mean()]))
        return (log_likelihood, 2, "drift", float(beta[1])), float(beta[0])


def second_look(
    t_s: np.ndarray,
    z: np.ndarray,
    h: np.ndarray,
    s2: np.ndarray,
    noise_sigma: float,
    band: float | None = None,
    baseline: Roughness | None = None,
) -> FailureName:
    """A bias, a gain or a drift: what the readings since a declaration show over seconds.

    The arguments are :func:`classify_failure`'s, over the :data:`SECOND_LOOK_S` after the
    declaration of a failure its first second named a bias or a drift. The residual
    ``e = z - h`` is explained by a bias, a gain (``e = (g - 1) h``, which the first second
    cannot tell from a bias while the true value holds still) and a drift, and the best by the
    Bayesian information criterion names the failure. The straight line of a drift must move
    the channel by more than :data:`DRIFT_SIGMAS` prediction sigmas, away from zero (the slope
    has the sign of the line's mean: the prediction's pull toward the reading only shrinks the
    residual); its slope over seconds is the drift's rate, where the first second's also
    holds the re-based prediction's settling. Where the best of the three stays within
    ``band`` (:func:`classify_failure`'s) the seconds show no bias, gain or drift, and every
    kind is weighed again (a spike train whose first second had no spike). With the channel's
    roughness before the failure (``baseline``), seconds that show spikes or a noise in the
    readings themselves are named by :func:`classify_failure`, and a gain also explains the
    roughness it scales.
    """
    t, z, h, s2 = (np.asarray(a, dtype=float) for a in (t_s, z, h, s2))
    n = z.size
    if n < 3:
        raise ValueError(f"second_look: expected at least 3 samples, got {n}")
    e = z - h
    texture = None if baseline is None else _texture(t, z, baseline)
    if texture is not None and (
        _rougher(texture, baseline, noise_sigma**2) or texture.spike_size is not None
    ):
        return classify_failure(t, z, h, s2, noise_sigma, baseline=baseline)
    prediction_sigma = math.sqrt(max(float(np.mean(s2)) - noise_sigma**2, 0.0))
    if texture is None:
        candidates = [_bias(e, s2), _scale(e, h, s2)]
        fitted, mean, slope = _line(t, e, s2)
        drift = (_gaussian(e, fitted, s2), 2, "drift", slope)
    else:
        loose_prediction = _LoosePrediction(h, s2, noise_sigma**2)
        candidates = [
            _unscaled(loose_prediction.bias(e), texture),
            _scale_of_roughness(e, h, texture, loose_prediction),
        ]
        loose, mean = loose_prediction.drift(t, e)
        drift, slope = _unscaled(loose, texture), loose[3]
    if abs(slope) * float(t[-1] - t[0]) > DRIFT_SIGMAS * prediction_sigma and mean * slope > 0.0:
        candidates.append(drift)
    best = max(candidates, key=lambda c: c[0] - 0.5 * c[1] * math.log(n))
    if band is not None and _deviation(t, e, h, s2, best) <= band:
        return classify_failure(t, z, h, s2, noise_sigma, baseline=baseline)
    return FailureName(best[2], best[3])


def _ramp_goes_on(t: np.ndarray, e: np.ndarray, s2: np.ndarray, ramp: float) -> bool:
    """Whether the line through the residual ``e`` moves it further than ``ramp``, its way.

    ``ramp``: how far a drift's line moved the channel over its second look. A drift's goes on
    (over three times the seconds, three times as far); the ramp of a prediction settling
    after the re-base stops.
    """
    slope = _line(t, e, s2)[2]
    return slope * ramp > 0.0 and abs(slope) * float(t[-1] - t[0]) > abs(ramp)


def _scale(e: np.ndarray, h: np.ndarray, s2: np.ndarray) -> tuple[float, int, str, float]:
    w = 1.0 / s2
    denominator = float(np.sum(w * h * h))
    gain_minus_1 = float(np.sum(w * e * h) / denominator) if denominator > 0.0 else 0.0
    return _gaussian(e, gain_minus_1 * h, s2), 1, "scale", 1.0 + gain_minus_1


def _noise(e: np.ndarray, s2: np.ndarray, r: float) -> tuple[float, int, str, float]:
    def cost(log_k2: float) -> float:
        return -_gaussian(e, 0.0, s2 + (math.exp(log_k2) - 1.0) * r)

    fit = minimize_scalar(cost, bounds=(0.0, math.log(1e6)), method="bounded")
    return -float(fit.fun), 1, "noise", math.sqrt(math.exp(float(fit.x)))


def _spikes(e: np.ndarray, s2: np.ndarray) -> tuple[float, int, str, float]:
    """The contaminated normal's fit by expectation-maximisation; size: the spikes' rms ``A``.

    The variance's M-step ``A^2 = sum g (e^2 - s2) / sum g`` is exact for a constant ``s2``
    and a fixed point of the likelihood near it otherwise; the likelihood is evaluated exactly.
    """
    n = e.size
    e2 = e * e
    a2 = max(float(np.max(e2 - s2)), float(np.min(s2)))  # the largest excess: the first spike
    odds = 1.0 / n
    for _ in range(_SPIKE_EM_STEPS):
        clean = math.log1p(-odds) - 0.5 * (e2 / s2 + np.log(2.0 * np.pi * s2))
        spiked = math.log(odds) - 0.5 * (e2 / (s2 + a2) + np.log(2.0 * np.pi * (s2 + a2)))
        g = np.exp(spiked - np.logaddexp(clean, spiked))  # each sample's odds of a spike
        weight = float(np.sum(g))
        odds = min(max(weight / n, 0.5 / n), 1.0 - 0.5 / n)
        a2 = max(float(np.sum(g * (e2 - s2))) / max(weight, 1e-300), float(np.min(s2)) * 1e-6)
    clean = math.log1p(-odds) - 0.5 * (e2 / s2 + np.log(2.0 * np.pi * s2))
    spiked = math.log(odds) - 0.5 * (e2 / (s2 + a2) + np.log(2.0 * np.pi * (s2 + a2)))
    return float(np.sum(np.logaddexp(clean, spiked))), 2, "spikes", math.sqrt(a2)


class FaultNamer:
    """Gathers each step's readings and predictions; names each declaration once its window is in.

    Every declared channel is named on its own (a second failure declared within the first's
    window does not lose the first's name). A failure named a bias, a drift or a gain keeps
    being gathered until ``second_look_s`` after its declaration, and is named again where
    :func:`second_look` names it otherwise (a drift: again, with the rate of the seconds); a
    noise is named again with its factor over those seconds. A bias or a drift is then looked
    at a last time at ``last_look_s``: a bias renamed where that finds a drift or a gain, a
    drift given the rate of those seconds, or named by them where its ramp did not go on.

    Parameters
    ----------
    noise_sigmas : ndarray, shape (6,)
        The IMU channels' white-noise sigmas.
    window_s : float
        How long after a declaration to gather (:data:`NAMING_WINDOW_S`).
    second_look_s : float
        When a bias, a drift, a gain or a noise is looked at again (:data:`SECOND_LOOK_S`); at most
        ``window_s``: never.
    bands : ndarray, shape (6,), optional
        What a healthy channel may read off the truth (``DETECTABLE_SIGMAS`` band sigmas of
        the spec sheet). A first second whose best name stays within it is named over the
        second look's seconds instead (None: always named at the first second).
    last_look_s : float
        When a failure its second look names a bias or a drift is looked at a last time
        (:data:`LAST_LOOK_S`); at most ``second_look_s``: never.
    """

    def __init__(
        self,
        noise_sigmas: np.ndarray,
        window_s: float = NAMING_WINDOW_S,
        second_look_s: float = SECOND_LOOK_S,
        bands: np.ndarray | None = None,
        last_look_s: float = LAST_LOOK_S,
    ) -> None:
        self.noise_sigmas = np.asarray(noise_sigmas, dtype=float)
        self.bands = None if bands is None else np.asarray(bands, dtype=float)
        self.window_s = window_s
        self.second_look_s = second_look_s
        self.last_look_s = last_look_s
        self._pending: dict[int, tuple[int, float]] = {}  # channel -> mode slot, declared at
        # (t, readings) of the BASELINE_S before a declaration and the seconds of its looks
        self._recent: deque[tuple[float, np.ndarray]] = deque()
        self._baselines: dict[int, Roughness | None] = {}  # channel -> roughness before it
        # channel -> every channel's roughness over the seconds of its baseline
        self._flight_baselines: dict[int, list[Roughness | None]] = {}
        self._failed: set[int] = set()  # channels declared and not released
        self._samples: dict[int, list[tuple[float, float, float, float]]] = {}
        self._first: dict[int, FailureName] = {}  # channel -> first name, waiting for a second look
        # channel -> the bias or drift its last look re-reads, and a drift's ramp at the second
        self._last: dict[int, tuple[str, float]] = {}

    @property
    def pending(self) -> bool:
        """Whether a declaration waits to be named (else :meth:`observe` has nothing to do)."""
        return bool(self._pending)

    def record(self, t_s: float, imu: np.ndarray) -> None:
        """Keep this step's readings for the roughness of a channel declared later.

        They are kept over the seconds of a last look too, for :meth:`flight_spread`.
        """
        self._recent.append((t_s, np.array(imu, dtype=float)))
        keep_s = BASELINE_S + BASELINE_GUARD_S + max(self.last_look_s, self.second_look_s)
        while self._recent and t_s - self._recent[0][0] > keep_s:
            self._recent.popleft()

    def declared(self, mode_index: int, channel: int, t_s: float) -> None:
        """Start gathering for mode ``mode_index``'s failed ``channel``, declared at ``t_s``.

        The channel's roughness before the failure is read from the readings :meth:`record`
        kept, up to :data:`BASELINE_GUARD_S` before the declaration.
        """
        self._pending[channel] = (mode_index, t_s)
        self._samples[channel] = []
        self._failed.add(channel)
        before = [
            (t, v) for t, v in self._recent
            if t <= t_s - BASELINE_GUARD_S and t_s - t <= BASELINE_S + BASELINE_GUARD_S
        ]  # fmt: skip
        if before:
            times = np.array([t for t, _ in before])
            readings = np.array([v for _, v in before])
            self._flight_baselines[channel] = [roughness(times, c) for c in readings.T]
        else:
            self._flight_baselines[channel] = [None] * len(self.noise_sigmas)
        self._baselines[channel] = self._flight_baselines[channel][channel]

    def released(self, channel: int) -> None:
        """The detector released ``channel``: forget its naming; its roughness is healthy again."""
        self.cancel(channel)
        self._failed.discard(channel)

    def flight_spread(self, channel: int, since_s: float, t_s: float) -> float:
        """How far healthy channels' roughness moved over ``(since_s, t_s]`` (rms ``ln`` ratio).

        Each channel neither ``channel`` nor declared is read over those seconds against its
        roughness over the seconds of ``channel``'s baseline: the flight's own change of
        roughness, beside which a failed channel's ratio says a gain or a noise. 0: none known.
        """
        bases = self._flight_baselines.get(channel)
        window = [(t, v) for t, v in self._recent if since_s < t <= t_s + 1e-9]
        if bases is None or len(window) < 5:
            return 0.0
        times = np.array([t for t, _ in window])
        readings = np.array([v for _, v in window])
        ratios = []
        for j, base in enumerate(bases):
            if j == channel or j in self._failed or base is None:
                continue
            now = roughness(times, readings[:, j])
            if now is not None:
                ratios.append(math.log(now.sigma / base.sigma))
        return math.sqrt(float(np.mean(np.square(ratios)))) if ratios else 0.0

    def looking(self, channel: int) -> bool:
        """Whether ``channel``'s failure waits to be named, or to be looked at again.

        A bias or a drift waiting for its last look is not: a bias's name is final unless that
        look finds a drift or a gain, which it then names anew, and a drift's is final but for
        its rate, read again over the look's seconds, unless its ramp stopped.
        """
        return channel in self._pending and channel not in self._last

    def cancel(self, channel: int | None = None) -> None:
        """Forget a pending declaration (``channel``; None: all of them)."""
        for c in list(self._pending) if channel is None else [channel]:
            self._pending.pop(c, None)
            self._samples.pop(c, None)
            self._first.pop(c, None)
            self._last.pop(c, None)
            self._baselines.pop(c, None)
            self._flight_baselines.pop(c, None)

    def observe(
        self, t_s: float, imu: np.ndarray, innovations: np.ndarray, variances: np.ndarray
    ) -> list[tuple[int, FailureName]]:
        """Feed one step; returns ``(channel, name)`` of each failure whose window is full.

        A failure its second look names otherwise is returned again, renamed. A sample
        whose reading, prediction or variance is not a finite number (a variance not positive)
        says nothing of the failure and is left out.
        """
        out = []
        for i, (j, since) in list(self._pending.items()):
            z = float(imu[i])
            h = z - float(innovations[j, i])
            s2 = float(variances[j, i])
            if not (math.isfinite(h) and math.isfinite(s2) and s2 > 0.0):
                continue
            samples = self._samples[i]
            samples.append((t_s, z, h, s2))
            looking_again, looking_last = i in self._first, i in self._last
            due = (
                self.last_look_s if looking_last
                else self.second_look_s if looking_again else self.window_s
            )  # fmt: skip
            if t_s - since < due - 1e-9 or len(samples) < 3:
                continue
            t, zs, hs, s2 = (np.array(c) for c in zip(*samples, strict=True))
            sigma = float(self.noise_sigmas[i])
            baseline = self._baselines.get(i)
            if baseline is not None:
                baseline = dataclasses.replace(baseline, spread=self.flight_spread(i, since, t_s))
            band = None if self.bands is None else float(self.bands[i])
            if looking_last:
                named, ramp = self._last[i]
                self.cancel(i)
                last = second_look(t, zs, hs, s2, sigma, band, baseline)
                # a bias is named anew by a drift or a gain; a drift keeps its name, not its
                # rate, while its ramp goes on
                stopped = named == "drift" and not _ramp_goes_on(t, zs - hs, s2, ramp)
                if last.kind == "drift" or last.kind != named and (named == "bias" or stopped):
                    out.append((i, last))
                continue
            if looking_again:
                first = self._first.pop(i)
                if first.kind in (UNSEEN, "noise"):
                    self.cancel(i)
                if first.kind == UNSEEN:  # named now, by the seconds, whatever they show
                    out.append((i, classify_failure(t, zs, hs, s2, sigma, baseline=baseline)))
                    continue
                if first.kind == "noise":  # its factor over seconds, not one second's
                    factor = _noise_factor(t, zs, sigma**2, baseline)
                    if factor is not None:
                        out.append((i, FailureName("noise", factor)))
                    continue
                again = second_look(t, zs, hs, s2, sigma, band, baseline)
                if again.kind != first.kind or again.kind == "drift":
                    out.append((i, again))
                if again.kind in ("bias", "drift") and self.last_look_s > self.second_look_s:
                    ramp = again.size * float(t[-1] - t[0]) if again.kind == "drift" else 0.0
                    self._last[i] = (again.kind, ramp)
                else:
                    self.cancel(i)
                continue
            looks_again = self.second_look_s > self.window_s
            band = float(self.bands[i]) if looks_again and self.bands is not None else None
            name = classify_failure(t, zs, hs, s2, sigma, band, baseline)
            if name.kind != UNSEEN:
                out.append((i, name))
            if name.kind in ("bias", "drift", "scale", "noise", UNSEEN) and looks_again:
                self._first[i] = name
            else:
                self.cancel(i)
        return out

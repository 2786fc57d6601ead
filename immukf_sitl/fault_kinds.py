"""How an IMU channel fails: the fault kinds a scenario injects, their parameters and their law.

Real MEMS sensors rarely fail by reading exactly zero. Each kind below is one way they do, with
the one parameter (``value``) that sizes it; the fault proxy applies it to a healthy reading
``y = s + n`` (true value ``s``, the sensor's white noise ``n`` of sigma ``sigma``) from the
fault's ``t_s`` until its ``end_t_s``:

=========  ================================  ===============================================
kind       reads                             ``value``
=========  ================================  ===============================================
zero       ``n``                             none (a dead sensor that still reports; the
                                             paper's fault)
stuck      ``y(t_s)``, held, no noise        none (a hung bus, a stale register)
bias       ``y + value``                     the offset, m/s^2 or rad/s, non-zero (a shock,
                                             a solder crack)
drift      ``y + value (t - t_s)``           the rate, m/s^2/s or rad/s/s, non-zero
                                             (temperature)
scale      ``value * y``                     the gain, finite and not 1 (saturation, a
                                             partial failure; -1 is a reversed axis)
noise      ``y + sqrt(value^2 - 1) sigma e``  the factor on the noise sigma, > 1 (vibration,
                                             a loose mount)
spikes     ``y + value`` on a random sign    the spike size, non-zero, at ``rate_hz``
           at Poisson times                  (> 0, at most the IMU rate) (bus glitches)
=========  ================================  ===============================================

The spike times are a Poisson process of rate ``rate_hz`` from ``t_s``, with random signs,
drawn from a generator seeded by the fault's own parameters (:func:`spike_schedule`): the
proxy, a replay of its tlog and the truth tools all see the same spikes from the fault record
alone.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "FAULT_KINDS",
    "KIND_VALUES",
    "MAX_SPIKE_RATE_HZ",
    "SPIKE_CHUNK_S",
    "check_fault_parameters",
    "spike_schedule",
]

#: what ``value`` means for each kind (None: the kind takes no value)
KIND_VALUES: dict[str, str | None] = {
    "zero": None,
    "stuck": None,
    "bias": "the offset (m/s^2 or rad/s), non-zero",
    "drift": "the rate (m/s^2/s or rad/s/s), non-zero",
    "scale": "the gain, finite and not 1",
    "noise": "the factor on the noise sigma, > 1",
    "spikes": "the spike size (m/s^2 or rad/s), non-zero",
}
FAULT_KINDS: tuple[str, ...] = tuple(KIND_VALUES)
#: spikes come at most once per IMU sample (100 Hz)
MAX_SPIKE_RATE_HZ = 100.0
#: the spike schedule is drawn this many seconds at a time
SPIKE_CHUNK_S = 10.0


def check_fault_parameters(kind: str, value: float | None, rate_hz: float | None) -> str | None:
    """What is wrong with a fault's parameters, in a phrase (None: nothing).

    ``value`` and ``rate_hz`` are None where the scenario does not give them.
    """
    if kind not in KIND_VALUES:
        return f"kind: expected one of {', '.join(FAULT_KINDS)}, got {kind!r}"
    meaning = KIND_VALUES[kind]
    if meaning is None:
        if value is not None:
            return f"value: kind {kind} takes none, got {value!r}"
    elif value is None:
        return f"value: kind {kind} needs one ({meaning})"
    elif not math.isfinite(value) or _out_of_range(kind, value):
        return f"value: expected {meaning} for kind {kind}, got {value!r}"
    if kind != "spikes":
        if rate_hz is not None:
            return f"rate_hz: only kind spikes takes one, got {rate_hz!r} for kind {kind}"
    elif rate_hz is None or not 0.0 < rate_hz <= MAX_SPIKE_RATE_HZ:
        return f"rate_hz: expected spikes per second in (0, {MAX_SPIKE_RATE_HZ:g}], got {rate_hz!r}"
    return None


def _out_of_range(kind: str, value: float) -> bool:
    if kind == "scale":
        return value == 1.0
    if kind == "noise":
        return value <= 1.0
    return value == 0.0


def spike_schedule(
    t_s: float, value: float, rate_hz: float, from_s: float, until_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """The spikes of a ``spikes`` fault starting at ``t_s`` that fall in ``[from_s, until_s)``.

    A Poisson process of ``rate_hz`` from ``t_s``, each spike ``+value`` or ``-value`` with equal
    odds, drawn :data:`SPIKE_CHUNK_S` at a time from a generator seeded by ``(t_s, value,
    rate_hz)`` to the microsecond and the chunk's index: the same fault always spikes the same
    way, and any window of it is drawn without the ones before. Returns the times (s) and the
    signed sizes.
    """
    key = [round(t_s * 1e6), round(abs(value) * 1e6), round(rate_hz * 1e6)]
    lo = max(from_s, t_s)
    times: list[np.ndarray] = []
    sizes: list[np.ndarray] = []
    if not until_s > lo:
        return np.zeros(0), np.zeros(0)
    for chunk in range(int((lo - t_s) // SPIKE_CHUNK_S), int((until_s - t_s) // SPIKE_CHUNK_S) + 1):
        rng = np.random.default_rng(np.random.SeedSequence([abs(k) for k in key] + [chunk]))
        count = int(rng.poisson(rate_hz * SPIKE_CHUNK_S))
        at = t_s + SPIKE_CHUNK_S * (chunk + np.sort(rng.random(count)))  # uniform given the count
        signs = np.where(rng.random(count) < 0.5, -1.0, 1.0)
        keep = (at >= lo) & (at < until_s)
        times.append(at[keep])
        sizes.append(signs[keep] * value)
    return np.concatenate(times), np.concatenate(sizes)

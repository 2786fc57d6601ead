"""Runs of exactly repeated IMU readings: a held register, told from chance.

A sensor whose bus hangs or whose register goes stale repeats its last reading exactly, sample
after sample. A healthy sensor repeats one only by chance: never for a noisy float stream,
now and then for a quantised one (an autopilot's integer RAW_IMU). So the run of exact repeats
is evidence of a stuck channel by itself, whatever the model predicts: in turbulence the
prediction is loose, and a held value can sit within a few sigmas of it for seconds while the
channel shows nothing of the aircraft's motion.

:class:`RepeatRuns` counts, per channel, the current run and how often the channel has repeated
its previous reading at all. A run is *beyond chance* once a healthy channel repeating
independently at its own observed rate ``p`` would give it with probability ``p^n`` below
:data:`HELD_CHANCE`. ``p`` is the posterior mean under a uniform prior, ``(repeats + 1) /
(pairs + 2)``: a half at start-up (30 samples needed), a thousandth after ten seconds of a float
stream (3 samples), and the channel's own rate for a quantised one. A reading at or beyond
its range is the rail, which a healthy sensor holds exactly as long as the motion lasts: it
neither counts nor continues a run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: the chance of a run beyond which it is called held: at 100 Hz on six channels a healthy IMU
#: gives one such run in about 460 hours (1e-9 x 2.16e6 samples an hour), and a run only lets
#: the stuck part of a mode be scored; the mode still has to win on it (docs/design).
HELD_CHANCE = 1e-9

_LOG_HELD_CHANCE = math.log(HELD_CHANCE)


@dataclass(frozen=True)
class RepeatRuns:
    """Per channel: the last finite reading, the current run of exact repeats and their rate.

    Attributes
    ----------
    last : ndarray, shape (6,)
        The last finite reading of each channel (NaN: none yet, or the rail).
    run : ndarray of int, shape (6,)
        How many samples in a row have repeated the one before exactly.
    repeats, pairs : ndarray of int, shape (6,)
        How many consecutive pairs of readings were equal, of how many compared.
    """

    last: np.ndarray
    run: np.ndarray
    repeats: np.ndarray
    pairs: np.ndarray

    @classmethod
    def start(cls, channels: int = 6) -> RepeatRuns:
        """Nothing read yet."""
        zeros = np.zeros(channels, dtype=np.int64)
        return cls(np.full(channels, np.nan), zeros, zeros, zeros)

    def after(self, reading: np.ndarray, ranges: np.ndarray) -> RepeatRuns:
        """The runs once ``reading`` (``(6,)``, NaN where missing) has arrived.

        A missing channel (a gap, or a predict-only step up to a slower stream's next sample)
        leaves its run as it was: the next reading is compared with the last one read.
        """
        reading = np.asarray(reading, dtype=float)
        finite = np.isfinite(reading)
        on_rail = finite & (np.abs(reading) >= ranges)
        compared = finite & ~on_rail & np.isfinite(self.last)
        same = compared & (reading == self.last)
        run = np.where(same, self.run + 1, np.where(finite, 0, self.run))
        last = np.where(finite, np.where(on_rail, np.nan, reading), self.last)
        return RepeatRuns(last, run, self.repeats + same, self.pairs + compared)

    def beyond_chance(self) -> np.ndarray:
        """``(6,)``: 1.0 where the current run is longer than a healthy channel gives by chance."""
        if not self.run.any():  # the common case at 100 Hz: no channel repeats at all
            return np.zeros(self.run.shape)
        rate = (self.repeats + 1.0) / (self.pairs + 2.0)
        return np.where(self.run * np.log(rate) < _LOG_HELD_CHANCE, 1.0, 0.0)

"""Which raw readings are new measurements: held values from slow drivers, repeated values from
quantised encoders (docs/method.md §13).

A value exactly equal to the previous sample's is one of two things:

* a reading **held** by a slow driver or logger (wheel speeds and currents refreshed at 0.5-5 Hz,
  the logger repeating the last value in between): no new measurement, the observer predicts;
* a **new reading of the same value** from a stream read at the sample rate: an encoder's count
  difference is quantised (2 pi / cpr / dt, 0.038 rad/s at 16384 counts and 100 Hz), so at a
  steady speed it repeats for several samples.  Treating those as held lets the observer run open
  loop on the torques for a tenth of a second or more: a simulated 12-s sweep's front slip read
  0.14 for a true 0.02 that way, and K moved with it.

The stream tells which it is: a stream read at the sample rate changes value at consecutive
samples whenever the signal moves (63-100 % of its changes in the simulated drives), a held one
never does (0 % of the Warthog's held wheel speeds, 0 % at 5 Hz).  So each channel keeps a
running share of its value changes that came one sample after the previous change; above
``full_rate_share`` its repeats are readings, for at most ``repeat_window`` s (a driver that
froze repeats forever: after that the value is held, as from a slow stream).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: weight of one value change in the running share of consecutive changes (~10 changes of memory)
SHARE_WEIGHT = 0.1


class Readings(NamedTuple):
    """One step's verdict on readings (k, c)."""

    fresh: np.ndarray  #: a new measurement: a changed value, or a full-rate stream's repeat
    changed: np.ndarray  #: the value itself changed (or everything is new: a first sample, a restart)
    prev: np.ndarray  #: the previous sample's readings
    changed_before: np.ndarray  #: when the value last changed before this sample (the interval of a count difference)
    age: np.ndarray  #: s since the channel's last new measurement (0 when fresh)
    full_rate: np.ndarray  #: the stream is read at the sample rate (its running share of consecutive changes)


class ReadingClock:
    """Per (vehicle, channel): the last value, when it last changed, when the channel last gave a
    new reading, and the running share of value changes at consecutive samples.  Arrays (n, c)."""

    def __init__(self, n_vehicles: int, n_channels: int, full_rate_share: float, repeat_window: float):
        self.full_rate_share, self.repeat_window = full_rate_share, repeat_window
        self.prev = np.full((n_vehicles, n_channels), np.nan)
        self.fresh_at = np.full((n_vehicles, n_channels), np.nan)  # last new reading (changed or a full-rate repeat)
        self.value_at = np.full((n_vehicles, n_channels), np.nan)  # last change of the value itself
        self.share = np.zeros((n_vehicles, n_channels))

    def step(self, sel, stamp: np.ndarray, last_stamp: np.ndarray, raw: np.ndarray,
             restart: np.ndarray) -> Readings:
        """Readings ``raw`` (k, c) of the vehicles ``sel`` at ``stamp`` (k,), whose previous sample
        was at ``last_stamp`` (k,; NaN at a first); ``restart`` (k,): a first sample or a stamp that
        went backwards (everything is new then)."""
        # copies: ``sel`` may be a slice, and the state is overwritten below
        prev, fresh_before, value_before = self.prev[sel].copy(), self.fresh_at[sel].copy(), self.value_at[sel].copy()
        share = self.share[sel]
        changed = (raw != prev) | restart[:, None]
        # a missing reading (NaN: a dropout) and the first one after it change nothing about the
        # stream's rate: counted, a dropout would make a held 10 Hz stream look full-rate
        counted = changed & ~restart[:, None] & np.isfinite(raw) & np.isfinite(prev)
        # the previous sample brought a new value too: the stream is read at the sample rate
        consecutive = value_before == last_stamp[:, None]
        share = np.where(counted, share + SHARE_WEIGHT * (consecutive - share), share)
        with np.errstate(invalid="ignore"):
            repeat = (~changed & (share > self.full_rate_share) & (stamp - last_stamp > 0)[:, None]
                      & (stamp[:, None] - value_before <= self.repeat_window))
        fresh = changed | repeat
        fresh_at = np.where(fresh, stamp[:, None], fresh_before)
        self.prev[sel] = raw
        self.fresh_at[sel] = fresh_at
        self.value_at[sel] = np.where(changed, stamp[:, None], value_before)
        self.share[sel] = share
        return Readings(fresh, changed, prev, value_before, stamp[:, None] - fresh_at, share > self.full_rate_share)

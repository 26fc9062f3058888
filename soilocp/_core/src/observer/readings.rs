//! Which raw readings are new measurements (docs/method.md §13): a value equal to the previous
//! sample's is a reading **held** by a slow driver (no measurement, the observer predicts) or a
//! **new reading of the same value** from a stream read at the sample rate (a quantised encoder's
//! count difference at a steady speed).  Each channel keeps a running share of its value changes
//! that came one sample after the previous change; above `full_rate_share` its repeats are
//! readings, for at most `repeat_window` s (a driver that froze repeats forever).

/// Weight of one value change in the running share of consecutive changes (~10 changes of memory).
pub const SHARE_WEIGHT: f64 = 0.1;

/// Channels per vehicle: wheel speeds 1-4, ground speed, torques 1-4.
pub const CHANNELS: usize = 9;

/// One step's verdict on one vehicle's readings.
#[derive(Clone, Copy, Debug)]
pub struct Readings {
    /// a new measurement: a changed value, or a full-rate stream's repeat
    pub fresh: [bool; CHANNELS],
    /// the value itself changed (or everything is new: a first sample, a restart)
    pub changed: [bool; CHANNELS],
    /// the previous sample's readings
    pub prev: [f64; CHANNELS],
    /// when the value last changed before this sample (the interval of a count difference)
    pub changed_before: [f64; CHANNELS],
    /// s since the channel's last new measurement (0 when fresh)
    pub age: [f64; CHANNELS],
    /// the stream is read at the sample rate (its running share of consecutive changes)
    pub full_rate: [bool; CHANNELS],
}

/// Per (vehicle, channel): the last value, when it last changed, when it last gave a new reading,
/// and the running share of value changes at consecutive samples.
pub struct ReadingClock {
    pub full_rate_share: f64,
    pub repeat_window: f64,
    prev: Vec<[f64; CHANNELS]>,
    fresh_at: Vec<[f64; CHANNELS]>,
    value_at: Vec<[f64; CHANNELS]>,
    pub share: Vec<[f64; CHANNELS]>,
}

impl ReadingClock {
    pub fn new(n_vehicles: usize, full_rate_share: f64, repeat_window: f64) -> ReadingClock {
        ReadingClock {
            full_rate_share,
            repeat_window,
            prev: vec![[f64::NAN; CHANNELS]; n_vehicles],
            fresh_at: vec![[f64::NAN; CHANNELS]; n_vehicles],
            value_at: vec![[f64::NAN; CHANNELS]; n_vehicles],
            share: vec![[0.0; CHANNELS]; n_vehicles],
        }
    }

    /// Vehicle `g`'s readings `raw` at `stamp`, its previous sample at `last_stamp` (NaN at a
    /// first); `restart`: a first sample or a stamp that went backwards (everything is new then).
    /// A missing reading (NaN) and the first one after it are no evidence of the stream's rate:
    /// counted, a dropout would make a held 10 Hz stream look full-rate.
    pub fn step(&mut self, g: usize, stamp: f64, last_stamp: f64, raw: &[f64; CHANNELS], restart: bool) -> Readings {
        let (prev, fresh_before, value_before) = (self.prev[g], self.fresh_at[g], self.value_at[g]);
        let share = &mut self.share[g];
        let mut out = Readings {
            fresh: [false; CHANNELS],
            changed: [false; CHANNELS],
            prev,
            changed_before: value_before,
            age: [0.0; CHANNELS],
            full_rate: [false; CHANNELS],
        };
        let forward = stamp - last_stamp > 0.0;
        for c in 0..CHANNELS {
            // NaN != NaN: a missing reading counts as changed, as in numpy
            let changed = raw[c] != prev[c] || restart;
            let counted = changed && !restart && raw[c].is_finite() && prev[c].is_finite();
            // the previous sample brought a new value too: the stream is read at the sample rate
            let consecutive = if value_before[c] == last_stamp { 1.0 } else { 0.0 };
            if counted {
                share[c] += SHARE_WEIGHT * (consecutive - share[c]);
            }
            let full = share[c] > self.full_rate_share;
            let repeat = !changed && full && forward && stamp - value_before[c] <= self.repeat_window;
            let fresh = changed || repeat;
            let fresh_at = if fresh { stamp } else { fresh_before[c] };
            self.fresh_at[g][c] = fresh_at;
            self.value_at[g][c] = if changed { stamp } else { value_before[c] };
            out.fresh[c] = fresh;
            out.changed[c] = changed;
            out.age[c] = stamp - fresh_at;
            out.full_rate[c] = full;
        }
        self.prev[g] = *raw;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(clock: &mut ReadingClock, t: f64, last: f64, v: f64, restart: bool) -> (bool, f64) {
        let r = clock.step(0, t, last, &[v; CHANNELS], restart);
        (r.fresh[0], r.age[0])
    }

    /// Samples `steps` of a 100 Hz log (stamp i / 100 s), every channel at `value(i)` and sample 0 a
    /// restart; `last`: the previous sample's stamp, moved on.  (fresh, age) of each.
    fn run(
        clock: &mut ReadingClock,
        steps: std::ops::Range<usize>,
        last: &mut f64,
        value: impl Fn(usize) -> f64,
    ) -> Vec<(bool, f64)> {
        steps
            .map(|i| {
                let t = i as f64 * 0.01;
                let out = one(clock, t, *last, value(i), i == 0);
                *last = t;
                out
            })
            .collect()
    }

    #[test]
    fn a_held_slow_stream_is_no_reading_until_it_changes() {
        // a 5 Hz driver held by a 100 Hz logger: 20 samples of one value, then the next
        let mut clock = ReadingClock::new(1, 0.5, 0.5);
        let mut last = f64::NAN;
        let out = run(&mut clock, 0..100, &mut last, |i| (i / 20) as f64);
        for (i, &(fresh, age)) in out.iter().enumerate() {
            assert_eq!(fresh, i % 20 == 0, "{i}");
            assert!((age - (i % 20) as f64 * 0.01).abs() < 1e-12);
        }
    }

    #[test]
    fn a_full_rate_streams_repeat_is_a_reading_within_the_window() {
        let mut clock = ReadingClock::new(1, 0.5, 0.5);
        let mut last = f64::NAN;
        run(&mut clock, 0..40, &mut last, |i| i as f64);
        // repeats: readings for 0.5 s after the last change, then a frozen driver
        let fresh: Vec<bool> = run(&mut clock, 40..120, &mut last, |_| 39.0)
            .iter()
            .map(|r| r.0)
            .collect();
        assert!(fresh[..49].iter().all(|&f| f) && fresh[52..].iter().all(|&f| !f));
        // a repeated stamp is no new reading
        assert!(!one(&mut clock, last, last, 39.0, false).0);
    }
}

//! Whether a server keeps the frame rate its `WELCOME` announced
//! (spec/session.md section 6, "Rate"): sans-IO, fed the time of each
//! tick, it says when a `NOTICE` with code 4 is due and what rate to put
//! in it.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Seconds of ticks a rate is measured over.
pub const RATE_WINDOW: Duration = Duration::from_secs(2);

/// Share of the announced rate below which the server tells its clients.
pub const RATE_SHARE: f64 = 0.9;

/// Least time between two rate notices.
pub const NOTICE_EVERY: Duration = Duration::from_secs(10);

/// Counts a server's ticks against its announced rate.
#[derive(Clone, Debug)]
pub struct RateWatch {
    rate: u16,
    /// When the watch started: no verdict before a whole window.
    start: Option<Instant>,
    /// Tick times within the last window.
    ticks: VecDeque<Instant>,
    last_notice: Option<Instant>,
}

impl RateWatch {
    /// A watch for a server announcing `rate` Hz (at least 1).
    pub fn new(rate: u16) -> RateWatch {
        RateWatch {
            rate: rate.max(1),
            start: None,
            ticks: VecDeque::with_capacity(2 * rate.max(1) as usize + 1),
            last_notice: None,
        }
    }

    /// Records a tick at `now` (times must not go back). Returns the rate
    /// measured over the last [`RATE_WINDOW`], in Hz, when a notice is due:
    /// the window is whole, holds fewer than [`RATE_SHARE`] of the ticks
    /// the announced rate gives it, and this watch returned no rate in the
    /// last [`NOTICE_EVERY`].
    pub fn tick(&mut self, now: Instant) -> Option<f64> {
        let start = *self.start.get_or_insert(now);
        self.ticks.push_back(now);
        while let Some(&t) = self.ticks.front() {
            if now.duration_since(t) >= RATE_WINDOW {
                self.ticks.pop_front();
            } else {
                break;
            }
        }
        if now.duration_since(start) < RATE_WINDOW {
            return None;
        }
        let window = RATE_WINDOW.as_secs_f64();
        let measured = self.ticks.len() as f64 / window;
        if measured >= RATE_SHARE * self.rate as f64 {
            return None;
        }
        if self
            .last_notice
            .is_some_and(|t| now.duration_since(t) < NOTICE_EVERY)
        {
            return None;
        }
        self.last_notice = Some(now);
        Some(measured)
    }

    /// The announced rate, Hz.
    pub fn rate(&self) -> u16 {
        self.rate
    }
}

/// The text of a rate notice: `41.5 of 60 Hz`.
pub fn rate_text(measured: f64, rate: u16) -> String {
    format!("{measured:.1} of {rate} Hz")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Ticks every `period_ms` from `t0` for `seconds`; the times a notice
    /// was due (ms after `t0`) and the rates it gave.
    fn run(rate: u16, period_ms: u64, seconds: u64) -> Vec<(u64, f64)> {
        let t0 = Instant::now();
        let mut w = RateWatch::new(rate);
        let mut out = Vec::new();
        let mut t = 0;
        while t <= seconds * 1000 {
            if let Some(hz) = w.tick(t0 + Duration::from_millis(t)) {
                out.push((t, hz));
            }
            t += period_ms;
        }
        out
    }

    #[test]
    fn a_server_on_time_is_never_noticed() {
        assert!(run(60, 16, 30).is_empty());
        assert!(run(10, 100, 30).is_empty());
        // One tick in twenty lost stays above 90%.
        assert!(run(10, 105, 30).is_empty());
    }

    #[test]
    fn a_slow_server_is_noticed_once_every_ten_seconds_with_its_rate() {
        // 25 Hz against 60 announced.
        let n = run(60, 40, 25);
        let times: Vec<u64> = n.iter().map(|x| x.0).collect();
        assert_eq!(times, vec![2000, 12000, 22000]);
        assert!(n.iter().all(|&(_, hz)| (hz - 25.0).abs() < 0.6), "{n:?}");
        assert_eq!(rate_text(n[0].1, 60), "25.0 of 60 Hz");
    }

    #[test]
    fn no_verdict_before_a_whole_window() {
        let t0 = Instant::now();
        let mut w = RateWatch::new(60);
        // One tick a second: far too slow, but the first window is not
        // whole until 2 s have passed.
        assert_eq!(w.tick(t0), None);
        assert_eq!(w.tick(t0 + Duration::from_secs(1)), None);
        assert!(w.tick(t0 + Duration::from_secs(2)).is_some());
    }
}

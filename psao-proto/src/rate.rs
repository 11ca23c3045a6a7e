//! Whether a server keeps the frame rate its `WELCOME` announced
//! (spec/session.md section 6, "Rate"), sans-IO, fed the time of each
//! tick: [`RateWatch`] says when a `NOTICE` with code 4 is due and what
//! rate to put in it, and [`TickSchedule`] says when the next tick is due.

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

/// How far behind its schedule a server may fall and still catch up (or
/// one period, if that is longer: [`catch_up_limit`]); further behind, it
/// gives the missed ticks up and starts a new schedule.
pub const CATCH_UP: Duration = Duration::from_millis(250);

/// The period of `rate` ticks a second (at least 1).
fn period_of(rate: u16) -> Duration {
    Duration::from_secs_f64(1.0 / f64::from(rate.max(1)))
}

/// How far behind its schedule a server of `rate` ticks a second may fall
/// and still catch up: [`CATCH_UP`], or one period if that is longer.
pub fn catch_up_limit(rate: u16) -> Duration {
    CATCH_UP.max(period_of(rate))
}

/// When a server's ticks are due: one period apart from the first, so
/// that a tick that ran late is made up by the ticks after it (they start
/// at once until the schedule is met again) rather than lost. Only a
/// server more than [`catch_up_limit`] behind gives ticks up: it starts a
/// new schedule from now, and counts the ticks it gave up.
#[derive(Clone, Debug)]
pub struct TickSchedule {
    period: Duration,
    catch_up: Duration,
    /// When the next tick is due.
    next: Instant,
    behind_ticks: u64,
    lost: u64,
    most_behind: Duration,
}

impl TickSchedule {
    /// A schedule of `rate` ticks a second (at least 1) whose first tick
    /// starts at `now`.
    pub fn new(rate: u16, now: Instant) -> TickSchedule {
        let period = period_of(rate);
        TickSchedule {
            period,
            catch_up: catch_up_limit(rate),
            next: now + period,
            behind_ticks: 0,
            lost: 0,
            most_behind: Duration::ZERO,
        }
    }

    /// Called when a tick ended at `now` (times must not go back): when
    /// the next tick starts, `now` or earlier when it is due already (then
    /// it starts at once).
    pub fn after_tick(&mut self, now: Instant) -> Instant {
        let due = self.next;
        if due >= now {
            self.next += self.period;
            return due;
        }
        let behind = now - due;
        self.most_behind = self.most_behind.max(behind);
        self.behind_ticks += 1;
        if behind <= self.catch_up {
            // Behind: start at once, and keep the schedule.
            self.next += self.period;
        } else {
            // Too far behind to catch up without playing the scene fast
            // for long: give the missed ticks up.
            let periods = behind.as_nanos() / self.period.as_nanos().max(1);
            self.lost = self
                .lost
                .saturating_add(u64::try_from(periods).unwrap_or(u64::MAX));
            self.next = now + self.period;
        }
        now
    }

    /// Ticks that started at once, behind their schedule: the tick before
    /// ended after they were due. Those within [`catch_up_limit`] kept the
    /// schedule; a server always behind counts every tick here.
    pub fn behind_ticks(&self) -> u64 {
        self.behind_ticks
    }

    /// Ticks given up because the server fell more than
    /// [`catch_up_limit`] behind.
    pub fn lost_ticks(&self) -> u64 {
        self.lost
    }

    /// The furthest behind its schedule the server has been when a tick
    /// ended.
    pub fn most_behind(&self) -> Duration {
        self.most_behind
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

    /// Steps of the given lengths (µs) on a schedule of `rate` Hz from
    /// `t0`: when each tick started (µs after `t0`), and the schedule.
    fn schedule_us(rate: u16, steps_us: &[u64]) -> (Vec<u64>, TickSchedule) {
        let t0 = Instant::now();
        let mut s = TickSchedule::new(rate, t0);
        let mut now = t0;
        let mut starts = Vec::new();
        for &us in steps_us {
            starts.push((now - t0).as_micros() as u64);
            now += Duration::from_micros(us);
            now = s.after_tick(now).max(now);
        }
        (starts, s)
    }

    /// The same at 60 Hz in whole milliseconds.
    fn schedule(steps_ms: &[u64]) -> (Vec<u64>, TickSchedule) {
        let steps: Vec<u64> = steps_ms.iter().map(|ms| ms * 1000).collect();
        let (starts, s) = schedule_us(60, &steps);
        (starts.iter().map(|us| us / 1000).collect(), s)
    }

    #[test]
    fn ticks_on_time_start_a_period_apart() {
        let (starts, s) = schedule(&[5, 10, 16, 1]);
        // 16.67 ms apart, truncated to whole milliseconds.
        assert_eq!(starts, vec![0, 16, 33, 50]);
        assert_eq!((s.behind_ticks(), s.lost_ticks()), (0, 0));
    }

    #[test]
    fn a_tick_that_ends_when_the_next_is_due_is_not_behind() {
        let t0 = Instant::now();
        let mut s = TickSchedule::new(10, t0);
        let due = t0 + Duration::from_millis(100);
        assert_eq!(s.after_tick(due), due);
        assert_eq!(s.after_tick(due), due + Duration::from_millis(100));
        assert_eq!((s.behind_ticks(), s.most_behind()), (0, Duration::ZERO));
    }

    #[test]
    fn a_slow_tick_is_made_up_by_the_next_ones() {
        // A 45 ms step (nearly three periods) among 10 ms ones: the ticks
        // after it start at once until the schedule is met, and none is
        // lost.
        let mut steps = vec![10, 45];
        steps.extend([10; 10]);
        let (starts, s) = schedule(&steps);
        assert_eq!(&starts[..8], &[0, 16, 61, 71, 81, 91, 101, 116]);
        // Back on the schedule: tick 11 starts at 11 periods (183.3 ms).
        assert_eq!(starts[11], 183);
        assert_eq!(s.lost_ticks(), 0);
        // Ticks 2 to 6 started behind, the first by 28.3 ms.
        assert_eq!(s.behind_ticks(), 5);
        assert_eq!(s.most_behind().as_micros() / 100, 283);
    }

    #[test]
    fn a_server_exactly_at_the_limit_still_catches_up() {
        let t0 = Instant::now();
        let mut s = TickSchedule::new(60, t0);
        let period = Duration::from_secs_f64(1.0 / 60.0);
        // The first tick ends CATCH_UP after the second was due.
        let end = t0 + period + CATCH_UP;
        assert_eq!(s.after_tick(end), end);
        assert_eq!((s.lost_ticks(), s.behind_ticks()), (0, 1));
        assert_eq!(s.most_behind(), CATCH_UP);
        // A nanosecond more would have given ticks up: the 15 due by
        // then but the one that starts now.
        let mut u = TickSchedule::new(60, t0);
        u.after_tick(end + Duration::from_nanos(1));
        assert_eq!(u.lost_ticks(), 14);
    }

    #[test]
    fn a_server_far_behind_gives_ticks_up_and_starts_again() {
        // A 390 ms step: more than CATCH_UP behind. The next tick starts
        // at once, on a new schedule, and the 22 other ticks due by then
        // are lost.
        let (starts, s) = schedule(&[10, 390, 10, 10]);
        assert_eq!(starts, vec![0, 16, 406, 423]);
        assert_eq!(s.lost_ticks(), 22);
        assert_eq!(s.behind_ticks(), 1);
    }

    #[test]
    fn a_server_always_behind_steps_every_tick_and_counts_what_it_gave_up() {
        // Steps of two periods at 60 Hz (33,334 µs) for 600 ticks: each
        // ends after the next was due, and ticks run plus ticks given up
        // cover the time, to within one schedule's worth.
        let (starts, s) = schedule_us(60, &[33_334; 600]);
        let elapsed = *starts.last().unwrap() + 33_334;
        let scheduled = elapsed / 16_667;
        assert_eq!(s.behind_ticks(), 600);
        assert!(s.most_behind() <= catch_up_limit(60) + Duration::from_micros(33_334));
        let covered = 600 + s.lost_ticks();
        assert!(
            covered <= scheduled && covered + 16 >= scheduled,
            "{covered} of {scheduled}"
        );
    }

    #[test]
    fn a_slow_rate_catches_up_within_one_period() {
        // At 1 Hz one period (1 s) is longer than CATCH_UP.
        assert_eq!(catch_up_limit(1), Duration::from_secs(1));
        assert_eq!(catch_up_limit(60), CATCH_UP);
        let t0 = Instant::now();
        let mut s = TickSchedule::new(1, t0);
        let end = t0 + Duration::from_millis(1500);
        assert_eq!(s.after_tick(end), end);
        assert_eq!(
            s.after_tick(t0 + Duration::from_millis(1600)),
            t0 + Duration::from_secs(2)
        );
        assert_eq!((s.behind_ticks(), s.lost_ticks()), (1, 0));
        // Over a period behind, it gives up.
        let mut u = TickSchedule::new(1, t0);
        u.after_tick(t0 + Duration::from_millis(2500));
        assert_eq!(u.lost_ticks(), 1);
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

//! Each point's trend, for the ray budget's priority (see `budget`): how
//! far its last trace left it from what clients hold, and how fast its AO
//! moved between its last two traces. From these a point's *urgency*
//! follows: how near the send threshold its AO probably is now.

/// A point's trend: whether it has been traced, its last trace quantized,
/// that trace's distance from what clients hold in 1/255 steps (0 when it
/// went out), the step it was traced in, and the pace its AO moved at
/// between its last two traces (steps of 1/255 per pipeline step).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct Trend {
    traced: bool,
    last: u8,
    gap: u8,
    at: u32,
    pace: f32,
}

impl Trend {
    /// The trend of a point whose trace at step `at` gave `q`, what
    /// clients hold (setup's first trace): no gap, no pace yet.
    pub fn seeded(q: u8, at: u32) -> Trend {
        Trend {
            traced: true,
            last: q,
            gap: 0,
            at,
            pace: 0.0,
        }
    }

    /// Notes a trace at step `now` that gave `q` (quantized), clients
    /// holding `held` (`None`: nothing); `sent`: the trace went out, so
    /// clients hold it now and no gap is left.
    pub fn note(&mut self, q: u8, held: Option<u8>, now: u32, sent: bool) {
        let gap = match (sent, held) {
            (false, Some(h)) => h.abs_diff(q),
            _ => 0,
        };
        let pace = if self.traced {
            self.last.abs_diff(q) as f32 / now.wrapping_sub(self.at).max(1) as f32
        } else {
            0.0
        };
        *self = Trend {
            traced: true,
            last: q,
            gap,
            at: now,
            pace,
        };
    }

    /// How far from what clients hold the point's AO probably is once it
    /// has waited `age` steps as a candidate (0: reached this step), as a
    /// share of `threshold`: the gap its last trace left plus its pace
    /// times `age + 1`, the steps in which motion could have changed it
    /// (a point motion did not reach kept its AO); 0 before any trace.
    pub fn urgency(&self, age: u32, threshold: u8) -> f32 {
        if !self.traced {
            return 0.0;
        }
        (self.gap as f32 + self.pace * (age as f32 + 1.0)) / threshold.max(1) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_is_urgent_by_its_gap_and_its_pace_over_the_steps_it_waited() {
        let mut t = Trend::default();
        assert_eq!(t.urgency(3, 8), 0.0, "no trace yet");
        // First trace at step 10: 2 steps from what clients hold, no pace.
        t.note(200, Some(202), 10, false);
        assert_eq!(t.urgency(0, 8), 2.0 / 8.0);
        assert_eq!(t.urgency(4, 8), 2.0 / 8.0, "no pace known yet");
        // Traced again 2 steps later, 4 steps further: a pace of 2 a step.
        t.note(196, Some(202), 12, false);
        assert_eq!(t.urgency(0, 8), (6.0 + 2.0) / 8.0);
        assert_eq!(t.urgency(2, 8), (6.0 + 6.0) / 8.0);
    }

    #[test]
    fn a_trace_that_went_out_leaves_no_gap_whatever_its_distance() {
        let mut t = Trend::default();
        t.note(100, Some(120), 1, true);
        assert_eq!(t.urgency(0, 8), 0.0, "sent: clients now hold it");
        // At the threshold and not sent (the send rule is strict): the
        // whole gap stays.
        let mut u = Trend::default();
        u.note(100, Some(108), 1, false);
        assert_eq!(u.urgency(0, 8), 1.0);
        let mut v = Trend::default();
        v.note(100, None, 1, false);
        assert_eq!(v.urgency(0, 8), 0.0, "nothing held: no gap");
        // The pace still counts after a send.
        t.note(104, Some(100), 2, false);
        assert_eq!(t.urgency(0, 8), (4.0 + 4.0) / 8.0);
    }

    #[test]
    fn a_fully_open_point_is_a_traced_one() {
        // AO 1 quantizes to 255: a point recovering to open has a trend.
        let mut t = Trend::default();
        t.note(255, Some(250), 5, false);
        assert_eq!(t.urgency(0, 8), 5.0 / 8.0);
        t.note(250, Some(250), 6, false);
        assert_eq!(t.urgency(0, 8), 5.0 / 8.0, "a pace of 5, no gap");
        let s = Trend::seeded(255, 0);
        assert_eq!(s.urgency(0, 8), 0.0);
        let mut s2 = s;
        s2.note(251, Some(255), 2, false);
        assert_eq!(
            s2.urgency(0, 8),
            (4.0 + 2.0) / 8.0,
            "seeded: the pace counts"
        );
    }

    #[test]
    fn steps_wrap_around() {
        let mut t = Trend::default();
        t.note(50, Some(50), u32::MAX, false);
        t.note(52, Some(50), 1, false);
        // Two steps apart across the wrap: a pace of 1 a step.
        assert_eq!(t.urgency(0, 8), (2.0 + 1.0) / 8.0);
    }
}

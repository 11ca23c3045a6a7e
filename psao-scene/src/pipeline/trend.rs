//! Each point's trend, for the ray budget's priority (see `budget`): how
//! far its last trace left it from what clients hold, and how fast its AO
//! moved between its last two traces. From these a point's *urgency*
//! follows: how near the send threshold its AO probably is now.

/// A point's trend: its last trace quantized (`u8::MAX` before any), that
/// trace's distance from what clients held in 1/255 steps (0 when it went
/// out), the step it was traced in, and the pace its AO moved at between
/// its last two traces (steps of 1/255 per pipeline step).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Trend {
    last: u8,
    gap: u8,
    at: u32,
    pace: f32,
}

impl Default for Trend {
    fn default() -> Self {
        Trend {
            last: u8::MAX,
            gap: 0,
            at: 0,
            pace: 0.0,
        }
    }
}

impl Trend {
    /// Notes a trace at step `now` that gave `q` (quantized), clients
    /// holding `held` (`None`: nothing); `threshold`: the send threshold
    /// in steps (a trace that far from `held` goes out, leaving no gap).
    pub fn note(&mut self, q: u8, held: Option<u8>, now: u32, threshold: u8) {
        let gap = held.map_or(0, |h| h.abs_diff(q));
        let pace = if self.last == u8::MAX {
            0.0
        } else {
            self.last.abs_diff(q) as f32 / now.wrapping_sub(self.at).max(1) as f32
        };
        *self = Trend {
            last: q,
            gap: if gap >= threshold { 0 } else { gap },
            at: now,
            pace,
        };
    }

    /// How far from what clients hold the point's AO probably is at step
    /// `now`, as a share of `threshold`: the gap its last trace left plus
    /// its pace times the steps since (0 before any trace).
    pub fn urgency(&self, now: u32, threshold: u8) -> f32 {
        if self.last == u8::MAX {
            return 0.0;
        }
        let since = now.wrapping_sub(self.at) as f32;
        (self.gap as f32 + self.pace * since) / threshold.max(1) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_is_urgent_by_its_gap_and_its_pace_since_its_last_trace() {
        let mut t = Trend::default();
        assert_eq!(t.urgency(10, 8), 0.0, "no trace yet");
        // First trace at step 10: 2 steps from what clients hold, no pace.
        t.note(200, Some(202), 10, 8);
        assert_eq!(t.urgency(10, 8), 2.0 / 8.0);
        assert_eq!(t.urgency(14, 8), 2.0 / 8.0, "no pace known yet");
        // Traced again 2 steps later, 4 steps further: a pace of 2 a step.
        t.note(196, Some(202), 12, 8);
        assert_eq!(t.urgency(12, 8), 6.0 / 8.0);
        assert_eq!(t.urgency(13, 8), 8.0 / 8.0);
        assert_eq!(t.urgency(15, 8), 12.0 / 8.0);
    }

    #[test]
    fn a_trace_that_goes_out_leaves_no_gap_and_nothing_held_is_no_gap() {
        let mut t = Trend::default();
        t.note(100, Some(120), 1, 8);
        assert_eq!(t.urgency(1, 8), 0.0, "sent: clients now hold it");
        let mut u = Trend::default();
        u.note(100, None, 1, 8);
        assert_eq!(u.urgency(1, 8), 0.0);
        // The pace still counts after a send.
        t.note(104, Some(100), 2, 8);
        assert_eq!(t.urgency(3, 8), (4.0 + 4.0) / 8.0);
    }

    #[test]
    fn steps_wrap_around() {
        let mut t = Trend::default();
        t.note(50, Some(50), u32::MAX, 8);
        t.note(52, Some(50), 1, 8);
        // Two steps apart across the wrap: a pace of 1 a step.
        assert_eq!(t.urgency(3, 8), (2.0 + 2.0) / 8.0);
    }
}

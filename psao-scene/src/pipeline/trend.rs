//! Each point's trend, for the ray budget's priority (see `budget`): how
//! far its last trace left it from what clients hold, and how fast its AO
//! moved between its last two traces. From these a point's *urgency*
//! follows: how near the send threshold its AO probably is now.
//!
//! A point's own trend knows nothing of a change that has not reached it
//! yet: the rim of a box sweeping down a bar that slides out of it turns
//! each point of the bar from dark to open in turn, and a point's last
//! two traces (both inside) say it holds still. Its neighbours know:
//! [`Heat`] keeps, per cell of an instance's space, the fastest pace its
//! points moved at lately, and the point of a rigid part that can move,
//! traced in full, is at least as urgent as that pace makes it.

use glam::{Affine3A, IVec3, Vec3};
use rustc_hash::FxHashMap;

use crate::model::mesh::box_corners;

/// A point's trend: whether it has been traced, its last trace quantized,
/// what clients hold (so the trace's distance from it in 1/255 steps, its
/// gap: 0 when it went out), the step it was traced in, and the pace its
/// AO moved at between its last two traces (steps of 1/255 per pipeline
/// step).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct Trend {
    traced: bool,
    last: u8,
    /// What clients hold since its last trace (`None`: nothing).
    held: Option<u8>,
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
            held: Some(q),
            at,
            pace: 0.0,
        }
    }

    /// Notes a trace at step `now` that gave `q` (quantized), clients
    /// holding `held` (`None`: nothing); `sent`: the trace went out, so
    /// clients hold it now and no gap is left.
    /// Returns the pace noted.
    pub fn note(&mut self, q: u8, held: Option<u8>, now: u32, sent: bool) -> f32 {
        let pace = if self.traced {
            self.last.abs_diff(q) as f32 / now.wrapping_sub(self.at).max(1) as f32
        } else {
            0.0
        };
        *self = Trend {
            traced: true,
            last: q,
            held: if sent { Some(q) } else { held },
            at: now,
            pace,
        };
        pace
    }

    /// What clients hold of the point after its last trace (`None`
    /// before any, or where they hold nothing).
    pub fn held(&self) -> Option<u8> {
        self.held.filter(|_| self.traced)
    }

    /// Notes what clients hold of the point now, where that changed
    /// without a trace of it (settled to its last trace, or dropped by the
    /// table): `None`, nothing.
    pub fn set_held(&mut self, held: Option<u8>) {
        self.held = held;
    }

    /// How far its last trace lies from what clients hold, in 1/255 steps
    /// (0 where it went out, or where they hold nothing).
    fn gap(&self) -> u8 {
        self.held.map_or(0, |h| h.abs_diff(self.last))
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
        (self.gap() as f32 + self.pace * (age as f32 + 1.0)) / threshold.max(1) as f32
    }
}

/// How much a rigid part's own AO depends on its pose, for
/// [`MoversWhole::Auto`](super::config::MoversWhole::Auto): of its points
/// traced lately (not stopped early), how many went out (their AO moved
/// past the send threshold, or settled). Counts halve past
/// [`PoseDependence::MEMORY`] traced points, so the recent ones weigh most.
/// And whether it turns in place lately (a wheel on its axle), which
/// `Auto` does not hold: see [`PoseDependence::turns_in_place`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct PoseDependence {
    traced: f32,
    sent: f32,
    /// How far its bounds' centre travelled lately, and the farthest
    /// corner of its bounds (each step's distance, the sums decaying by
    /// [`PoseDependence::TRAVEL_DECAY`] a step).
    centre: f32,
    corner: f32,
}

impl PoseDependence {
    /// Traced points past which the counts halve.
    const MEMORY: f32 = 4096.0;
    /// Traced points below which nothing is known yet.
    const LEAST: f32 = 64.0;
    /// What the travelled distances keep of their sums each step.
    const TRAVEL_DECAY: f32 = 0.9;
    /// The share of its farthest corner's travel under which a part's
    /// centre stays put: it turns in place.
    const IN_PLACE: f32 = 0.25;

    /// Notes a step's move of the part from `before` to `after`, its
    /// local bounds `bounds`.
    pub fn note_move(&mut self, before: &Affine3A, after: &Affine3A, bounds: (Vec3, Vec3)) {
        let at = |m: &Affine3A, p: Vec3| m.transform_point3(p);
        let travel = |p: Vec3| at(after, p).distance(at(before, p));
        let centre = travel((bounds.0 + bounds.1) * 0.5);
        let corner = box_corners(bounds)
            .into_iter()
            .map(travel)
            .fold(0.0, f32::max);
        if centre.is_finite() && corner.is_finite() {
            self.centre = self.centre * Self::TRAVEL_DECAY + centre;
            self.corner = self.corner * Self::TRAVEL_DECAY + corner;
        }
    }

    /// Whether it turns in place lately: its bounds' centre travelled
    /// under [`PoseDependence::IN_PLACE`] of what their farthest corner
    /// did (a wheel spinning on its axle, not a box tumbling along).
    pub fn turns_in_place(&self) -> bool {
        self.corner > 0.0 && self.centre < Self::IN_PLACE * self.corner
    }

    /// Notes a step's trace of `traced` of the part's points, `sent` of
    /// which went out.
    pub fn note(&mut self, traced: u32, sent: u32) {
        self.traced += traced as f32;
        self.sent += sent.min(traced) as f32;
        while self.traced > Self::MEMORY {
            self.traced *= 0.5;
            self.sent *= 0.5;
        }
    }

    /// The share of its traced points that went out (`None` before
    /// [`PoseDependence::LEAST`] were traced).
    pub fn share(&self) -> Option<f32> {
        (self.traced >= Self::LEAST).then(|| self.sent / self.traced)
    }

    /// Whether its AO depends on its pose: a known share of at least
    /// [`POSE_DEPENDENT_SHARE`](super::config::POSE_DEPENDENT_SHARE).
    pub fn depends(&self) -> bool {
        self.share()
            .is_some_and(|s| s >= super::config::POSE_DEPENDENT_SHARE)
    }
}

/// Steps a cell stays hot after a point in it moved at its pace.
pub(super) const HEAT_STEPS: u32 = 8;

/// The fastest pace the points of each cell of one instance moved at
/// lately (see the module): cubes of a side of the AO radius in the
/// instance's local space (`PointSet::positions`; only rigid instances
/// that can move keep heat, so their points never move there).
#[derive(Debug)]
pub(super) struct Heat {
    /// The cells' side.
    cell: f32,
    /// Per cell, the step the pace was noted in and the pace.
    cells: FxHashMap<IVec3, (u32, f32)>,
    /// The step cold cells were last forgotten in.
    cooled: u32,
}

impl Heat {
    /// No cell hot yet; cells of side `cell` (a positive length; any
    /// other keeps no heat).
    pub fn new(cell: f32) -> Heat {
        Heat {
            cell: if cell.is_finite() && cell > 0.0 {
                cell
            } else {
                0.0
            },
            cells: FxHashMap::default(),
            cooled: 0,
        }
    }

    /// The cell holding `p` (`None`: no cells, or `p` not finite).
    fn cell_of(&self, p: Vec3) -> Option<IVec3> {
        (self.cell > 0.0 && p.is_finite()).then(|| (p / self.cell).floor().as_ivec3())
    }

    /// Notes a point at `p` whose AO moved at `pace` (1/255 steps a
    /// step), traced at step `now`: its cell keeps the fastest pace noted
    /// since it was last cold, and goes cold [`HEAT_STEPS`] steps after
    /// that pace was noted (a slower pace noted meanwhile is not kept).
    pub fn note(&mut self, p: Vec3, pace: f32, now: u32) {
        if pace <= 0.0 {
            return;
        }
        let Some(c) = self.cell_of(p) else { return };
        let e = self.cells.entry(c).or_insert((now, 0.0));
        if now.wrapping_sub(e.0) > HEAT_STEPS || pace >= e.1 {
            *e = (now, pace);
        }
    }

    /// The pace the cell of `p` keeps (see [`Heat::note`]) at step `now`
    /// (0: the cell is cold).
    pub fn pace(&self, p: Vec3, now: u32) -> f32 {
        self.cell_of(p)
            .and_then(|c| self.cells.get(&c))
            .filter(|e| now.wrapping_sub(e.0) <= HEAT_STEPS)
            .map_or(0.0, |e| e.1)
    }

    /// Forgets the cold cells at step `now`, once every [`HEAT_STEPS`]
    /// steps: the map holds only cells noted in the last
    /// `2 * HEAT_STEPS` steps.
    pub fn cool(&mut self, now: u32) {
        if now.wrapping_sub(self.cooled) < HEAT_STEPS {
            return;
        }
        self.cooled = now;
        self.cells
            .retain(|_, e| now.wrapping_sub(e.0) <= HEAT_STEPS);
    }

    /// Bytes held (capacity).
    pub fn memory_bytes(&self) -> u64 {
        self.cells.capacity() as u64 * (std::mem::size_of::<(IVec3, (u32, f32))>() as u64 + 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_dependence_is_known_after_enough_points_and_follows_the_recent_ones() {
        let mut d = PoseDependence::default();
        d.note(40, 40);
        assert_eq!((d.share(), d.depends()), (None, false), "40 points");
        d.note(40, 0);
        assert_eq!(d.share(), Some(0.5));
        assert!(d.depends());
        // A part sliding over an even floor: 2% went out, for long enough
        // that the first steps weigh little.
        for _ in 0..100 {
            d.note(200, 4);
        }
        let share = d.share().unwrap();
        assert!((0.02..0.03).contains(&share), "{share}");
        assert!(!d.depends());
        // More sent than traced counts as all of them.
        let mut e = PoseDependence::default();
        e.note(100, 500);
        assert_eq!(e.share(), Some(1.0));
    }

    #[test]
    fn a_part_whose_centre_stays_while_its_corners_travel_turns_in_place() {
        let bounds = (Vec3::splat(-1.0), Vec3::splat(1.0));
        let turn = |deg: f32| Affine3A::from_rotation_y(deg.to_radians());
        let slide = |x: f32| Affine3A::from_translation(Vec3::new(x, 0.0, 0.0));
        // Steps from pose `at(k)` to `at(k + 1)` for k in `ks`.
        let moved =
            |d: &mut PoseDependence, ks: std::ops::Range<u32>, at: &dyn Fn(f32) -> Affine3A| {
                for k in ks {
                    d.note_move(&at(k as f32), &at(k as f32 + 1.0), bounds);
                }
            };
        // Nothing known: it does not.
        assert!(!PoseDependence::default().turns_in_place());
        let mut wheel = PoseDependence::default();
        moved(&mut wheel, 0..10, &|a| turn(a * 10.0));
        assert!(wheel.turns_in_place());
        let mut slider = PoseDependence::default();
        moved(&mut slider, 0..10, &|a| slide(a * 0.1));
        assert!(!slider.turns_in_place());
        // Tumbling along (turning as it travels, as BoxAnimated's box).
        let mut tumbler = PoseDependence::default();
        moved(&mut tumbler, 0..10, &|a| slide(a * 0.3) * turn(a * 10.0));
        assert!(!tumbler.turns_in_place());
        // What it did lately counts: a part that slid and now turns in
        // place turns in place after some steps.
        moved(&mut slider, 0..40, &|a| turn(a * 10.0));
        assert!(slider.turns_in_place());
        // Non-finite moves are not noted.
        let mut odd = PoseDependence::default();
        odd.note_move(&slide(0.0), &slide(f32::NAN), bounds);
        assert!(!odd.turns_in_place());
    }

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
        // What clients hold after each trace: the trace where it went out,
        // what they held where not, nothing where they held nothing.
        assert_eq!(Trend::default().held(), None);
        assert_eq!(Trend::seeded(77, 0).held(), Some(77));
        assert_eq!(t.held(), Some(100));
        t.note(200, Some(100), 3, true);
        assert_eq!(t.held(), Some(200));
        assert_eq!(u.held(), Some(108));
        assert_eq!(v.held(), None);
        u.set_held(Some(100));
        assert_eq!(u.held(), Some(100));
        // Settled to its last trace: no gap is left.
        assert_eq!(u.urgency(0, 8), 0.0);
        u.set_held(None);
        assert_eq!(u.held(), None);
        // Before any trace nothing is known, whatever was set.
        let mut w = Trend::default();
        w.set_held(Some(3));
        assert_eq!(w.held(), None);
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
    fn a_cell_keeps_its_fastest_pace_for_heat_steps_then_cools() {
        let mut h = Heat::new(0.5);
        let (a, b, far) = (
            Vec3::new(0.1, 0.1, 0.1),
            Vec3::new(0.4, 0.2, 0.3),
            Vec3::new(0.6, 0.1, 0.1),
        );
        h.note(a, 3.0, 10);
        h.note(b, 1.0, 11);
        assert_eq!(h.pace(b, 11), 3.0, "the same cell: the fastest pace");
        assert_eq!(h.pace(far, 11), 0.0, "another cell");
        assert_eq!(h.pace(a, 10 + HEAT_STEPS), 3.0);
        assert_eq!(h.pace(a, 11 + HEAT_STEPS), 0.0, "cooled");
        // Once cooled, a slower pace takes the cell.
        h.note(b, 1.0, 11 + HEAT_STEPS);
        assert_eq!(h.pace(a, 11 + HEAT_STEPS), 1.0);
        // A point that held still heats nothing.
        h.note(far, 0.0, 20);
        assert_eq!(h.pace(far, 20), 0.0);
        h.cool(40);
        assert!(h.cells.is_empty(), "cool forgets cold cells");
        // A hot cell stays.
        h.note(a, 2.0, 41);
        h.cool(41 + HEAT_STEPS);
        assert_eq!(h.pace(a, 41 + HEAT_STEPS), 2.0);
        assert_eq!(h.cells.len(), 1);
    }

    #[test]
    fn heat_ignores_what_has_no_cell() {
        let mut h = Heat::new(0.5);
        h.note(Vec3::NAN, 5.0, 1);
        h.note(Vec3::splat(f32::INFINITY), 5.0, 1);
        assert!(h.cells.is_empty());
        assert_eq!(h.pace(Vec3::NAN, 1), 0.0);
        // No cell size: no heat kept.
        for bad in [0.0, -1.0, f32::NAN] {
            let mut h = Heat::new(bad);
            h.note(Vec3::ZERO, 5.0, 1);
            assert_eq!(h.pace(Vec3::ZERO, 1), 0.0);
        }
        // A far point's cell saturates instead of wrapping.
        let mut h = Heat::new(1e-3);
        h.note(Vec3::splat(1e30), 2.0, 1);
        assert_eq!(h.pace(Vec3::splat(1e30), 1), 2.0);
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

//! What each chosen point casts ([`Pipeline::trace_planned`]): a
//! [`PointWork`] says which of its rays to cast next and takes their
//! scores, so that the CPU tracer casts a point's rays at once and a
//! backend ([`AoBackend::cast_rays`]) casts every point's next rays
//! together, a round at a time, with the same outcome from the same
//! scores: the same rules (ray reuse, early decisions) on both.
//!
//! [`Pipeline::trace_planned`]: super::Pipeline
//! [`AoBackend::cast_rays`]: super::backend::AoBackend::cast_rays

use std::borrow::Cow;

use glam::Vec3;
use psao_codec::SentPoint;
use psao_codec::Thresholds;
use psao_codec::wire::point::dequantize_ao;

use super::early::{EarlyDecisions, EarlyRun, Kept, changed_rays};
use super::reach::RayMask;
use crate::trace::ao::ao_of_scores;

/// How a moving instance's point is traced with early decisions.
#[derive(Clone, Copy)]
pub(super) struct Moving<'a> {
    /// The early decisions' settings.
    pub test: &'a EarlyDecisions,
    /// The rays' spread order (`early::ray_order`).
    pub order: &'a [u32],
    /// Where this step's rotation of the order starts.
    pub rot: usize,
    /// The send threshold of AO, as a fraction.
    pub tolerance: f32,
    /// The send thresholds.
    pub th: &'a Thresholds,
}

/// One point's work.
enum How {
    /// A moving point that may stop early, over its kept scores.
    Early {
        run: EarlyRun,
        kept: Kept,
        held: f32,
    },
    /// A moving point traced in full, its scores kept for next time
    /// (`old`: those kept before, to mark the rays that changed).
    Moving { old: Option<Kept>, normal: Vec3 },
    /// A static point whose scores are kept (ray reuse).
    Kept,
    /// A point traced in full, nothing kept.
    Plain,
}

/// One chosen point's rays: which to cast next, and what came of them
/// (`'a`: the list of every ray, shared).
pub(super) struct PointWork<'a> {
    /// Its index in the batch.
    pub b: usize,
    how: How,
    /// Every ray's score (not early): kept ones, cast ones written over.
    scores: Vec<f32>,
    /// The rays to cast (not early), in ray order; empty once cast.
    rays: Cow<'a, [u32]>,
    /// Its rays are known to score 1 ([`Plan::Open`](super::plan::Plan)):
    /// they are taken as such, none cast.
    open: bool,
    /// Rays taken.
    taken: u64,
}

/// One point as [`PointWork::finish`] leaves it.
pub(super) struct Traced {
    /// Its index in the batch.
    pub b: usize,
    /// Its AO (what clients hold, for a point that stopped early).
    pub value: f32,
    /// Rays cast.
    pub cast: u64,
    /// A static point's scores, to keep.
    pub scores: Option<Vec<f32>>,
    /// A moving point's kept scores, to put back (early decisions).
    pub kept: Option<Kept>,
    /// Whether it stopped early.
    pub stopped: bool,
    /// Rays it would have cast had it not been known open (`cast`
    /// otherwise): what the budget prices a moving point at.
    pub priced: u64,
}

impl<'a> PointWork<'a> {
    /// A moving instance's point `b` with early decisions (`how`): over
    /// its `kept` scores when it has them, has rays (`has_rays`), has not
    /// stopped [`max_stops`](EarlyDecisions::max_stops) times in a row,
    /// and could go unsent (clients hold a word for it, `sent`, that its
    /// position and normal alone would not send again); in full
    /// otherwise, keeping the scores for the next time. `normal`: its
    /// world normal now; `all`: every ray, in order.
    pub fn moving(
        b: usize,
        kept: Option<Kept>,
        sent: &SentPoint,
        normal: Vec3,
        (all, has_rays, open): (&'a [u32], bool, bool),
        how: &Moving,
    ) -> PointWork<'a> {
        let held = dequantize_ao(sent.word.fields().ao);
        let could_stay = sent.word.is_allocated() && !sent.changed(held, how.th);
        let kind = match kept {
            Some(mut kept) if has_rays && could_stay && kept.stops < how.test.max_stops => {
                // Rays that turned with the point since its scores were
                // kept change more, and more at once, than rays that held
                // still.
                let mut test = *how.test;
                if kept.normal != normal {
                    test.sd_floor = test.sd_floor.max(test.sd_floor_turning);
                }
                kept.normal = normal;
                let run = EarlyRun::new(how.order, how.rot, &kept, held, how.tolerance, &test);
                How::Early { run, kept, held }
            }
            old => How::Moving { old, normal },
        };
        match kind {
            How::Early { .. } => PointWork::new(b, kind, Vec::new(), &[], open),
            _ => PointWork::new(b, kind, vec![1.0; all.len()], all, open),
        }
    }

    /// A static point `b` whose scores are kept: `scores` those kept,
    /// with the rays `need` to cast over them (every ray, `all`, with
    /// nothing kept: `scores` then all 1).
    pub fn kept(
        b: usize,
        scores: Vec<f32>,
        (all, need): (&'a [u32], Option<&RayMask>),
        open: bool,
    ) -> PointWork<'a> {
        match need {
            Some(need) => {
                let rays: Vec<u32> = all.iter().copied().filter(|&k| need.has(k)).collect();
                PointWork::new(b, How::Kept, scores, rays, open)
            }
            None => PointWork::new(b, How::Kept, scores, all, open),
        }
    }

    /// A point `b` traced in full (`all`: every ray) with nothing kept.
    pub fn plain(b: usize, all: &'a [u32], open: bool) -> PointWork<'a> {
        PointWork::new(b, How::Plain, vec![1.0; all.len()], all, open)
    }

    fn new(
        b: usize,
        how: How,
        scores: Vec<f32>,
        rays: impl Into<Cow<'a, [u32]>>,
        open: bool,
    ) -> PointWork<'a> {
        let mut w = PointWork {
            b,
            how,
            scores,
            rays: rays.into(),
            open,
            taken: 0,
        };
        // A point known open decides as its rays would: each scores 1.
        while open && !w.wants().is_empty() {
            w.take_each(|_| 1.0);
        }
        w
    }

    /// Whether its rays' scores come from the ray cache's kept rays (a
    /// static point casting some of them over kept scores).
    pub fn over_kept(&self) -> bool {
        matches!(self.how, How::Kept) && self.rays.len() < self.scores.len()
    }

    /// The rays to cast next, in order (none once done).
    pub fn wants(&self) -> &[u32] {
        match &self.how {
            How::Early { run, .. } => run.wants(),
            _ => &self.rays,
        }
    }

    /// Takes the scores of the rays [`wants`](Self::wants) gave, in its
    /// order.
    pub fn take(&mut self, scores: &[f32]) {
        let mut scores = scores.iter();
        self.take_each(|_| scores.next().copied().unwrap_or(1.0));
    }

    /// As [`take`](Self::take), with `score(k)` giving ray `k`'s score,
    /// called for each ray [`wants`](Self::wants) gave, in its order.
    pub fn take_each(&mut self, mut score: impl FnMut(u32) -> f32) {
        self.taken += self.wants().len() as u64;
        match &mut self.how {
            How::Early { run, kept, .. } => run.take_each(kept, score),
            _ => {
                for &k in self.rays.iter() {
                    self.scores[k as usize] = score(k);
                }
                self.rays = Cow::Borrowed(&[]);
            }
        }
    }

    /// What came of it (call once [`wants`](Self::wants) is empty).
    pub fn finish(self) -> Traced {
        let cast = if self.open { 0 } else { self.taken };
        let (b, priced) = (self.b, self.taken);
        let traced = |value, scores, kept, stopped| Traced {
            b,
            value,
            cast,
            scores,
            kept,
            stopped,
            priced,
        };
        match self.how {
            How::Early {
                run,
                mut kept,
                held,
            } => {
                let out = run.finish(&mut kept);
                kept.stops = if out.value.is_some() {
                    0
                } else {
                    kept.stops.saturating_add(1)
                };
                let stopped = out.value.is_none();
                traced(out.value.unwrap_or(held), None, Some(kept), stopped)
            }
            How::Moving { old, normal } => {
                // The rays that changed since the kept scores (all of
                // them with nothing kept).
                let rays = self.scores.len() as u32;
                let changed = match &old {
                    Some(o) if o.scores.len() == self.scores.len() => {
                        changed_rays(&o.scores, &self.scores)
                    }
                    _ => RayMask::all(rays),
                };
                let value = ao_of_scores(&self.scores);
                let kept = Kept {
                    normal,
                    changed,
                    scores: self.scores.into(),
                    stops: 0,
                };
                traced(value, None, Some(kept), false)
            }
            How::Kept => {
                let value = ao_of_scores(&self.scores);
                traced(value, Some(self.scores), None, false)
            }
            How::Plain => traced(ao_of_scores(&self.scores), None, None, false),
        }
    }
}

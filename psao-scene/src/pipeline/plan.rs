//! How each point a step's motion may reach is traced ([`Plan`]): in
//! full, only the rays motion reached over the scores kept from its last
//! trace, or not at all; and what planning learns of a static point's
//! rays against the envelope of what moves, so that later steps test
//! only those.

use glam::{Vec3, Vec4};
use rayon::prelude::*;

use super::Pipeline;
use super::budget::RayBudget;
use super::dirty::{Batch, StepMotion};
use super::ray_cache::key;
use super::reach::{Among, RayMask, ReachQuery, reached_rays};
use crate::trace::ao::PointRays;

/// How one point is traced this step.
#[derive(Clone, Debug)]
pub(super) enum Plan {
    /// Motion reaches none of its rays and nothing waits: not traced.
    Skip,
    /// Every ray; `reached` counts those motion reached (all of a moving
    /// instance's), which ranks it under a budget.
    Full { reached: u32 },
    /// In full, but no triangle lies where its rays can hit
    /// ([`PointRays::surely_open`]): every ray scores 1, known without
    /// casting one. Found for chosen points only, after choosing
    /// ([`Pipeline::known_open`](super::Pipeline::known_open)).
    Open,
    /// Only `need` (motion's `reached` ones and those it reached while
    /// the point waited), the others' scores kept.
    Rays { need: RayMask, reached: RayMask },
}

impl Plan {
    /// The rays it casts of a point's `rays` (every one for a full trace,
    /// none when skipped).
    pub fn cost(&self, rays: u32) -> u32 {
        match self {
            Plan::Skip => 0,
            Plan::Full { .. } => rays,
            Plan::Open => 0,
            Plan::Rays { need, .. } => need.count(),
        }
    }
}

/// What planning a static point learnt of its rays against the envelope
/// of what moves.
#[derive(Clone, Debug)]
pub(super) enum Learnt {
    /// Nothing new.
    Nothing,
    /// It was planned for the first time under this envelope.
    Seen,
    /// Its rays that reach the envelope.
    Rays(EnvelopeRays),
}

/// The rays of a static point that reach the envelope of what moves, with
/// their directions and lengths (`w`) in the mask's order.
#[derive(Clone, Debug)]
pub(super) struct EnvelopeRays {
    /// The rays.
    pub mask: RayMask,
    /// Their directions and lengths, in the mask's order.
    pub dirs: Box<[Vec4]>,
    /// Whether rays whose kept hit lies before the envelope were left out:
    /// the mask then holds while the point's scores are kept.
    pub with_scores: bool,
}

impl EnvelopeRays {
    /// Bytes held on the heap.
    pub fn heap_bytes(&self) -> u64 {
        self.mask.heap_bytes() + self.dirs.len() as u64 * 16
    }
}

impl Pipeline {
    /// How each point of `batch` is traced this step: in full for a moving
    /// instance (or without ray reuse); for a static one only the rays
    /// motion reaches (and those it reached while the point waited), with
    /// the other rays' scores kept where they are kept (the CPU tracer, or
    /// a backend that casts single rays), in
    /// full where it has none; not at all when none is reached and the
    /// point does not wait. Only a point's rays that reach the envelope
    /// are tested, once they are known; with each plan, what was learnt
    /// of the point's rays against the envelope.
    pub(super) fn plan(&self, batch: &Batch, motion: &StepMotion) -> Vec<(Plan, Learnt)> {
        let ao = self.config.ao;
        let rays = ao.rays;
        // Without skipping every point is traced in full (the baseline).
        let reuse = self.config.ray_reuse && self.config.skip;
        let cache = reuse && self.keeps_ray_scores();
        let (waiting_list, ray_cache) = (&self.waiting, &self.ray_cache);
        let (envelope_rays, masks) = (&self.envelope_rays, &self.envelope_masks);
        let rested = &self.early_rested;
        let unlimited = self.config.budget == RayBudget::Unlimited;
        (0..batch.ids.len())
            .into_par_iter()
            .map(|b| {
                let (i, k) = batch.owner[b];
                let key = key(i, k);
                let full = (Plan::Full { reached: rays }, Learnt::Nothing);
                if !reuse || motion.changed[i] || rested.binary_search(&key).is_ok() {
                    return full;
                }
                let waiting = waiting_list.get(key);
                let entry = if cache { ray_cache.get(key) } else { None };
                if entry.is_none() && waiting.is_some() {
                    // Waiting for a full trace: nothing to test.
                    return full;
                }
                // (A point planned late, with its scores, of an instance
                // that did not move, waits apart: `split_waiting`.)
                let state = envelope_rays.get(key);
                let stored = state.checked_sub(2).and_then(|n| masks.get(n as usize));
                // A mask that left out rays by their kept hits holds while
                // the scores are kept; without them the point learns its
                // rays again, as one that never had scores.
                let known = stored.filter(|e| !e.with_scores || entry.is_some());
                let relearn = stored.is_some() && known.is_none();
                if entry.is_none() && waiting.is_none() && known.is_some_and(|e| e.mask.is_empty())
                {
                    // No ray reaches the envelope, which still holds.
                    return (Plan::Skip, Learnt::Nothing);
                }
                let (reached, learnt) =
                    match PointRays::new(batch.ids[b], batch.points[b], batch.normals[b], &ao) {
                        Some(r) => {
                            let dirs = entry.map(|e| &e.rays[..]);
                            // The second plan under this envelope: which of
                            // its rays reach it, for this step and the next.
                            let learnt = match known {
                                Some(_) => Learnt::Nothing,
                                None if state == 1 || relearn => {
                                    // A ray whose kept hit lies before the
                                    // envelope hits something static there
                                    // while it holds: never reached. Not
                                    // so for a stale ray (its kept score
                                    // predates the motion that reached it).
                                    let scores = entry.map(|e| {
                                        let mut s = e.scores.to_vec();
                                        for k in e.stale.iter() {
                                            if let Some(x) = s.get_mut(k as usize) {
                                                *x = 1.0;
                                            }
                                        }
                                        s
                                    });
                                    let mask = reached_rays(
                                        &r,
                                        rays,
                                        &motion.envelope,
                                        ao.estimator,
                                        ao.radius,
                                        ReachQuery {
                                            dirs,
                                            scores: scores.as_deref(),
                                            ..ReachQuery::default()
                                        },
                                    );
                                    // Their directions, kept with them.
                                    let dirs = mask
                                        .iter()
                                        .map(|k| match dirs.and_then(|d| d.get(k as usize)) {
                                            Some(&d) => d,
                                            None => {
                                                let (d, len) = r.ray(k);
                                                Vec3::from(d).extend(len)
                                            }
                                        })
                                        .collect();
                                    Learnt::Rays(EnvelopeRays {
                                        mask,
                                        dirs,
                                        with_scores: entry.is_some(),
                                    })
                                }
                                None => Learnt::Seen,
                            };
                            let among = match &learnt {
                                Learnt::Rays(e) => Some(e),
                                _ => known,
                            };
                            let among = among.map(|e| Among {
                                mask: &e.mask,
                                dirs: Some(&e.dirs),
                            });
                            let reached = if among.is_some_and(|a| a.mask.is_empty()) {
                                RayMask::none(rays)
                            } else {
                                reached_rays(
                                    &r,
                                    rays,
                                    &motion.boxes,
                                    ao.estimator,
                                    ao.radius,
                                    ReachQuery {
                                        dirs,
                                        scores: entry.map(|e| &e.scores[..]),
                                        among,
                                        // Traced in full anyway without kept
                                        // scores: the first reached ray
                                        // decides, unless a budget ranks by
                                        // the share reached.
                                        first_only: entry.is_none() && unlimited,
                                    },
                                )
                            };
                            (reached, learnt)
                        }
                        // Nothing to trace from: a full trace is cheap (open).
                        None => (RayMask::all(rays), Learnt::Nothing),
                    };
                let plan = match entry {
                    Some(e) if !waiting.is_some_and(|w| w.1) => {
                        let mut need = reached.clone();
                        need.union(&e.stale);
                        if need.is_empty() {
                            Plan::Skip
                        } else {
                            Plan::Rays { need, reached }
                        }
                    }
                    _ if reached.is_empty() && waiting.is_none() => Plan::Skip,
                    _ => Plan::Full {
                        reached: reached.count(),
                    },
                };
                (plan, learnt)
            })
            .collect()
    }

    /// Keeps what planning learnt of points' rays against the envelope
    /// (`learnt[b]` for point `b` of `batch`).
    pub(super) fn remember_envelope(&mut self, batch: &Batch, learnt: Vec<Learnt>) {
        for (b, l) in learnt.into_iter().enumerate() {
            let key = key(batch.owner[b].0, batch.owner[b].1);
            match l {
                Learnt::Nothing => {}
                Learnt::Seen => self.envelope_rays.set(key, 1),
                Learnt::Rays(m) => match self
                    .envelope_rays
                    .get(key)
                    .checked_sub(2)
                    .and_then(|n| self.envelope_masks.get_mut(n as usize))
                {
                    // Learnt again: in the same place.
                    Some(e) => *e = m,
                    None => {
                        self.envelope_masks.push(m);
                        let n = self.envelope_masks.len() as u32 + 1;
                        self.envelope_rays.set(key, n);
                    }
                },
            }
        }
    }
}

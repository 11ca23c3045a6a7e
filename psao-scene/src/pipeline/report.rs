//! What one server frame did: counts and the time of each phase
//! ([`FrameReport`]).

use std::time::Duration;

/// What one server frame did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameReport {
    /// Points in the scene.
    pub points: u64,
    /// Points re-traced.
    pub traced: u64,
    /// Points that needed re-tracing but were out of the viewer's view
    /// (they wait until they come into view).
    pub culled: u64,
    /// Rays cast.
    pub rays: u64,
    /// Points within reach of motion whose rays all miss what moved: not
    /// traced, their AO is what it was
    /// ([`PipelineConfig::ray_reuse`](crate::PipelineConfig::ray_reuse)).
    pub unreached: u64,
    /// Rays of traced points whose scores were kept from their last trace
    /// instead of being cast again.
    pub rays_kept: u64,
    /// The step's ray budget (`None`: unlimited).
    pub budget: Option<u64>,
    /// Points that need tracing but wait for a later step (the ray
    /// budget), after this step.
    pub waiting: u64,
    /// The longest any of them has waited, in steps: since its last
    /// trace, or since the loop memory last verified it (`verified`).
    pub oldest_wait: u32,
    /// Points traced whatever the budget because they had waited their
    /// due (`wait_bound` steps less a few, spread over the points): a
    /// budget too small for the motion.
    pub overdue: u64,
    /// Waiting points the loop memory verified and the budget left
    /// waiting: traced at the same time within the scene's loop to an AO
    /// that would not be sent against what clients hold, so clients are
    /// not behind a full re-trace and their wait starts again
    /// ([`PipelineConfig::loop_verify`](crate::PipelineConfig::loop_verify)).
    pub verified: u64,
    /// Under a budget, the bound on waiting this step enforced: no point
    /// waits longer (`oldest_wait` is at most this). It is
    /// [`PipelineConfig::max_wait`](crate::PipelineConfig::max_wait)
    /// while the budget affords it and rises with demand up to
    /// [`PipelineConfig::max_wait_limit`](crate::PipelineConfig::max_wait_limit).
    /// 0 without a budget.
    pub wait_bound: u32,
    /// Points of moving instances that stopped casting rays early, their
    /// AO known to stay within the send threshold of what clients hold
    /// (and short of open where they hold less)
    /// ([`PipelineConfig::early`](crate::PipelineConfig::early)); counted
    /// in `traced` too.
    pub early: u64,
    /// Points traced whose rays, it was known without casting one, can
    /// hit nothing: their AO is 1
    /// ([`PipelineConfig::skip_open`](crate::PipelineConfig::skip_open));
    /// counted in `traced` too.
    pub open: u64,
    /// The rays the points known open (`open`) were chosen at and did not
    /// cast (not in `rays`): with every ray cast they would have cast
    /// these, the choices being the same.
    pub rays_open: u64,
    /// Points whose change passed the thresholds (set in their table).
    pub updated: u64,
    /// Points sent because they settled below the send threshold (their
    /// AO stopped changing,
    /// [`PipelineConfig::settle_steps`](crate::PipelineConfig::settle_steps)),
    /// counted in `updated` too.
    pub settled: u64,
    /// Transforms sent.
    pub transforms: u32,
    /// Skinned instances whose pose changed.
    pub deformed: u32,
    /// Instances whose new pose was degenerate (a singular or non-finite
    /// transform, or skinned vertices that overflow) and that kept their
    /// last valid pose instead.
    pub held: u32,
    /// Bytes of the frame sent (0 when none was).
    pub bytes: u64,
    /// Time to evaluate animations and skin meshes and points.
    pub t_animate: Duration,
    /// Time to choose the points to re-trace.
    pub t_select: Duration,
    /// Time to build BVHs.
    pub t_bvh: Duration,
    /// Time to trace.
    pub t_trace: Duration,
    /// Time to update tables and encode.
    pub t_encode: Duration,
    /// The parts of `t_trace`, where the step traced or had points
    /// waiting (zero otherwise).
    pub trace_phases: TracePhases,
}

/// How long the parts of a step's trace phase took
/// ([`FrameReport::t_trace`] holds
/// them all, and the few microseconds between them).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TracePhases {
    /// Gathering the points to trace (with those waiting) and planning
    /// which of their rays motion reached, up to the budget's setting.
    pub plan: Duration,
    /// Choosing the points the budget takes, the waiting list and the
    /// batch of the chosen points with what clients hold.
    pub choose: Duration,
    /// Casting the chosen points' rays and comparing their AO with what
    /// clients hold.
    pub cast: Duration,
    /// Setting the points past the thresholds, settling, and the buried
    /// points' fill.
    pub apply: Duration,
}

impl TracePhases {
    /// Adds `other`'s times to these.
    pub fn accumulate(&mut self, other: &TracePhases) {
        self.plan += other.plan;
        self.choose += other.choose;
        self.cast += other.cast;
        self.apply += other.apply;
    }
}

impl FrameReport {
    /// Adds `other`'s counts and times to this one (`points` is kept as the
    /// larger of the two, `waiting` is `other`'s, the later one's, and
    /// `oldest_wait` and `wait_bound` the larger).
    pub fn accumulate(&mut self, other: &FrameReport) {
        self.points = self.points.max(other.points);
        self.traced += other.traced;
        self.culled += other.culled;
        self.rays += other.rays;
        self.unreached += other.unreached;
        self.rays_kept += other.rays_kept;
        self.overdue += other.overdue;
        self.verified += other.verified;
        self.early += other.early;
        self.open += other.open;
        self.rays_open += other.rays_open;
        self.budget = match (self.budget, other.budget) {
            (Some(a), Some(b)) => Some(a + b),
            (a, b) => a.or(b),
        };
        self.waiting = other.waiting;
        self.oldest_wait = self.oldest_wait.max(other.oldest_wait);
        self.wait_bound = self.wait_bound.max(other.wait_bound);
        self.updated += other.updated;
        self.settled += other.settled;
        self.transforms += other.transforms;
        self.deformed += other.deformed;
        self.held += other.held;
        self.bytes += other.bytes;
        self.t_animate += other.t_animate;
        self.t_select += other.t_select;
        self.t_bvh += other.t_bvh;
        self.t_trace += other.t_trace;
        self.t_encode += other.t_encode;
        self.trace_phases.accumulate(&other.trace_phases);
    }

    /// Server time of the frame, all stages.
    pub fn total_time(&self) -> Duration {
        self.t_animate + self.t_select + self.t_bvh + self.t_trace + self.t_encode
    }
}

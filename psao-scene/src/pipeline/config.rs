//! Pipeline settings: what to generate, trace and send
//! ([`PipelineConfig`]), and per-viewer culling ([`ViewerCull`], and the
//! [`Views`] it culls to).

use psao_codec::{EncoderConfig, Thresholds};

pub use super::budget::RayBudget;
pub use super::early::EarlyDecisions;
use crate::model::camera::Frustum;
use crate::points::layout::LayoutParams;
use crate::trace::ao::AoParams;

/// Per-viewer culling: the server traces only points near what is seen,
/// by default the view of the scene's camera path, or the union of the
/// views given with [`Pipeline::set_views`](crate::Pipeline::set_views) (a
/// server's clients).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewerCull {
    /// Width over height of the viewer's image.
    pub aspect: f32,
    /// Far plane distance.
    pub far: f32,
    /// How far beyond the frustum (on top of the AO radius) points still
    /// count as in view: room for the camera to move before the next frame.
    pub margin: f32,
}

impl ViewerCull {
    /// The near plane distance culling uses: 5 cm, or half the far plane
    /// when that is nearer.
    pub fn near(&self) -> f32 {
        0.05f32.min(self.far * 0.5)
    }
}

impl Default for ViewerCull {
    fn default() -> Self {
        ViewerCull {
            aspect: 16.0 / 9.0,
            far: 100.0,
            margin: 0.5,
        }
    }
}

/// What culling culls to (with [`PipelineConfig::cull`] set).
#[derive(Clone, Debug, Default, PartialEq)]
pub enum Views {
    /// The scene's camera path at the pipeline's time (nothing is culled
    /// when the scene has none).
    #[default]
    CameraPath,
    /// The union of these frusta (a server's viewers). An empty list: no
    /// one looks, every point waits.
    Frusta(Vec<Frustum>),
    /// Everything: nothing is culled (a client that does not say what it
    /// sees is connected).
    All,
}

/// The default [`PipelineConfig::max_points`]: 2^26 points, about 6.7 GB
/// held by the pipeline.
pub const DEFAULT_MAX_POINTS: u64 = 1 << 26;

/// Which rigid parts that move a budget holds whole
/// ([`PipelineConfig::movers_whole`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MoversWhole {
    /// None: a moving part's points wait their turn like the others, and
    /// its transform goes out every step it moves.
    Off,
    /// Every rigid part that moves.
    On,
    /// A rigid part whose own AO depends on its pose: of its points traced
    /// lately under a budget (not stopped early; at least 64 of them;
    /// counts halve past 4,096, so the recent ones weigh most), at least
    /// [`POSE_DEPENDENT_SHARE`] went out (their AO moved past the send
    /// threshold, or settled). A part sliding over an even floor keeps its AO as it
    /// goes (on the default scene 2% of its traced points went out),
    /// so holding its transform back would only misplace it; a box turning
    /// by another (BoxAnimated: 31%) changes its own AO as it moves, and
    /// sending its transform with AO of another pose misplaces the
    /// occlusion instead. Not a part that turns in place (its bounds'
    /// centre travelled lately under a quarter of what their farthest
    /// corner did: a wheel on its axle, the milk truck's 68%): its
    /// occlusion stays with its surroundings, and a transform held back
    /// would turn it with the part. A part starts unheld, starts to be held in a step where none of
    /// its points is due (else it would be traced whole at once), and
    /// stays held until it is traced. Parts are held, most dependent
    /// first, while together they cost at most half the budget a step
    /// (each its cost spread over
    /// [`max_wait`](PipelineConfig::max_wait) steps): a scene of many
    /// moving parts holds those it can afford. The default.
    #[default]
    Auto,
}

/// The share of a rigid part's traced points that went out from which
/// [`MoversWhole::Auto`] holds it whole: between the default scene's
/// sliding box (2%) and BoxAnimated's box (31%).
pub const POSE_DEPENDENT_SHARE: f32 = 0.1;

/// Pipeline settings.
#[derive(Clone, Debug, PartialEq)]
pub struct PipelineConfig {
    /// Points spawned per unit of world area (half are kept): an instance
    /// placed by a scale gets its share of the world area it covers
    /// (skinned instances: of their mesh's own area).
    pub density: f32,
    /// Seed of point generation.
    pub seed: u64,
    /// AO tracing.
    pub ao: AoParams,
    /// When a point is sent again.
    pub thresholds: Thresholds,
    /// Grid layout.
    pub layout: LayoutParams,
    /// Frame encoding.
    pub encoder: EncoderConfig,
    /// Re-trace only what motion can reach (true), or every point every
    /// frame (false: the baseline the skipping is measured against).
    pub skip: bool,
    /// Keep static geometry in a BVH built once and rebuild only the
    /// moving part (true), or rebuild one BVH over everything whenever
    /// something moves (false: the baseline).
    pub split_bvh: bool,
    /// Trace only near one viewer's frustum (needs a scene camera path);
    /// `None` when one stream serves many viewers.
    pub cull: Option<ViewerCull>,
    /// Points buried inside solids take the AO of their visible
    /// neighbours instead of being traced (true; see the pipeline's
    /// `buried` module), or are traced like any other (false: the
    /// baseline).
    pub fill_buried: bool,
    /// Spawned points that sample elimination left with no kept point
    /// facing their way within the radius are kept too, and every mesh
    /// side of positive area spawns at least
    /// [`MIN_SPAWNED`](crate::MIN_SPAWNED) points (true: thin strips and
    /// small meshes are covered; see
    /// [`generate_points_with`](crate::generate_points_with)), or the
    /// points are elimination's alone (false: the baseline).
    pub fill_gaps: bool,
    /// Most points the whole scene may keep, checked against an estimate
    /// from the scene's area before any point is made
    /// ([`SceneError::TooManyPoints`](crate::SceneError::TooManyPoints)):
    /// a scene's node scales times the density bound the memory setup
    /// takes (about 100 bytes a point held, twice that at the peak).
    pub max_points: u64,
    /// Deforming (skinned or morphing) instances keep their points in the
    /// mesh's bind space (point format 1, spec/wire-format.md 6.1): they
    /// never move, only their AO is sent, and a client looks a pixel up by
    /// its bind-space position and normal (true); or in posed local space,
    /// moved and re-sent with every pose (false: format 0 only, for
    /// clients that know no other, and the baseline).
    pub bind_space: bool,
    /// A static point that motion may reach re-traces only the rays that
    /// enter what moved (the boxes of the moving instances before and
    /// after the step), and is not traced at all when none does; its
    /// other rays' scores are kept from its last trace (with the CPU
    /// tracer, or a backend that casts single rays,
    /// [`AoBackend::casts_rays`](crate::AoBackend::casts_rays), as
    /// psao-gpu's does with `GpuBackend::with_single_rays(true)`; the
    /// pipeline's `ray_cache`, up to
    /// [`ray_cache_bytes`](Self::ray_cache_bytes)). Frames are the same,
    /// byte for byte, as with every reached point traced in full (true);
    /// or every point within reach of motion is traced in full (false:
    /// the baseline).
    pub ray_reuse: bool,
    /// A point chosen for a full trace whose last trace came out open
    /// casts no ray when no triangle lies where its rays can hit
    /// ([`PointRays::surely_open`](crate::PointRays::surely_open)): its
    /// AO is 1, as its full trace's, bit for bit (true); or it casts them
    /// (false: the baseline). Frames are the same either way, with a
    /// fixed ray budget and early decisions too (such a point is chosen
    /// at the cost of its rays, and decides as its rays would); the step
    /// takes less time, which an automatic budget measures. Only with the
    /// CPU tracer and
    /// [`skip`](Self::skip): a backend (psao-gpu's) casts them, so the
    /// rays it reports cast may be more than the CPU's for the same
    /// frames.
    pub skip_open: bool,
    /// Most bytes the kept ray scores take (64 MiB: about 94,000 points
    /// of 32 rays, at 712 bytes each with their rays' directions);
    /// beyond it, points are traced in full.
    pub ray_cache_bytes: u64,
    /// How many rays a step may trace ([`RayBudget::Unlimited`]: every point
    /// motion reached, in its step). A backend that casts single rays
    /// ([`AoBackend::casts_rays`](crate::AoBackend::casts_rays), as psao-gpu's
    /// does with `GpuBackend::with_single_rays(true)`) keeps ray scores as the
    /// CPU tracer does, so the same points cost the same rays on both and both
    /// take the same decisions. One that does not keeps none, so each point it
    /// traces costs all its rays: with ray reuse or early decisions on, it may
    /// then put off other points than the CPU tracer would. Under a budget a
    /// backend reads every traced point's AO back (not only the changed ones),
    /// for the points' trends that rank them.
    pub budget: RayBudget,
    /// Under a budget, the most steps a point waits while the budget
    /// affords it (8): one that waited its due, this long less a few
    /// steps (under half of it, at most 8, spread over the points, so that
    /// points that began to wait together do not all come due in one
    /// step), is traced whatever the budget. The bound in force rises
    /// above it, up to [`max_wait_limit`](Self::max_wait_limit), when the
    /// points that came due alone cost more rays than a step's budget.
    pub max_wait: u32,
    /// Under a budget, the most steps the bound on waiting may rise to
    /// when demand exceeds the budget (60: a second at 60 Hz). The bound
    /// in force (`FrameReport::wait_bound`) goes up after each step whose
    /// points that came due alone cost more than its budget (by the share
    /// they overran it by, at least a step, at most doubling), and back
    /// down a step towards [`max_wait`](Self::max_wait) after each step
    /// with none of those and no wait beyond half of it: no point waits
    /// longer than it, and the
    /// server keeps its rate unless even this limit's overdue points cost
    /// more than a period. Equal to `max_wait`: a fixed bound, whatever
    /// the rate.
    pub max_wait_limit: u32,
    /// Under a budget, a moving or deforming instance's own points are
    /// traced in every step it moves, whatever the budget (which then
    /// holds only the static points motion reaches), instead of waiting
    /// their turn like the others (false, the default). A point of a mover
    /// that waits holds AO traced at an older pose while clients place it
    /// with the newest transform, so its AO slides over the scene with the
    /// motion: on BoxAnimated at N = 1024 that costs 9.5 dB under a budget
    /// a tenth of the demand, which this removes (BENCHMARKS.md, "the
    /// ray budget, second part"), at the price of steps over the budget
    /// where movers alone need more rays than it affords. Points traced so
    /// are counted in [`FrameReport::overdue`](crate::FrameReport::overdue).
    pub movers_every_step: bool,
    /// Under a budget, which rigid parts that move (not deforming ones)
    /// are *held whole* ([`MoversWhole`]; `Auto` by default): such a part is
    /// traced whole or not at all in a step, and while its points wait the
    /// transform clients hold stays the one they were traced in. Clients
    /// then look its points up where it was traced: occlusion from the
    /// scene around it stays where it was, as from a server at a lower
    /// rate, instead of sliding with the part. It is
    /// traced when its points fit in the budget, when it has been held
    /// for [`max_wait`](Self::max_wait) steps, or when it was placed
    /// ([`place_instance`](crate::Pipeline::place_instance), sent in its
    /// step). So it costs at most a budget a step on average, a part whose
    /// points cost more than `max_wait` budgets waits point by point, as
    /// without it. On the CPU a part that does not fit is traced over
    /// several steps at one pose (a *stage*): the step that holds it plans
    /// how many of its points each step traces (enough to end before the
    /// first of them comes due, and at least half the budget's worth; the
    /// budget pays for them before the other points) and so the step it
    /// ends in, and keeps the scene with the part where its animation
    /// takes it by that step. Each step traces a slice against that
    /// snapshot, and the last sets them all and sends the snapshot's
    /// transform with them: the part's AO arrives whole, consistent, and
    /// with the pose the part has then. A stage made to end early (a point
    /// come due under a lowered bound) while the part is elsewhere, or one
    /// of a part placed, is dropped and the part traced whole in that
    /// step. On a backend (no snapshot there) a part held is traced whole
    /// in one step, which can take up to
    /// `max_wait` periods (the reference server makes such a step up:
    /// spec/session.md section 6). Ignored with
    /// [`movers_every_step`](Self::movers_every_step).
    pub movers_whole: MoversWhole,
    /// Under a budget, once demand has raised the bound on waiting, a
    /// static point that has waited a few steps is planned *late* (true)
    /// instead of forgetting its kept scores and waiting for a full trace
    /// (false, the default): once, when the budget takes it, against the
    /// boxes of what moved in every step it waited (see the module docs
    /// of the budget). It then casts the rays motion reached, not all of
    /// them, so the same budget goes round more points: 0.4-1.1 dB less
    /// lost on the default scene at fixed budgets of 16,000-32,000 rays
    /// (BENCHMARKS.md). While their instance rests they wait apart from
    /// planning. Under the automatic budget, though, no gain is resolved
    /// on the default scene (three pairs of runs lost 0.9 dB more than
    /// without it on average, three others tied): off by default.
    pub plan_late: bool,
    /// Under a budget, where the scene's animations loop together
    /// ([`Scene::loop_period`](crate::Scene::loop_period), within 20
    /// seconds), each traced point's AO at that moment of the loop is
    /// remembered, in at most this many bytes (0: off). In a later round, a
    /// point whose remembered AO at the same moment would not be sent
    /// against what clients hold ranks as one with nothing to send (below
    /// the points that changed; it is still traced by its due, unless
    /// the memory verifies it, [`loop_verify`](Self::loop_verify)). It
    /// orders the points the budget traces and verifies waiting ones;
    /// nothing is sent from it, and it is dropped once an instance is
    /// placed by hand
    /// ([`Pipeline::place_instance`](crate::Pipeline::place_instance)),
    /// which breaks the loop (the pipeline's `loops` module). 64 MiB.
    pub loop_memory_bytes: u64,
    /// Under a budget, with the loop memory, where the scene's pose is a
    /// function of the time within its loop (every animation's duration
    /// divides the loop's exactly): a waiting point whose AO traced at
    /// the same time within the loop (to 0.1 ms, no jump of the pose
    /// between) would not be sent against what clients hold is verified:
    /// clients are not behind a full re-trace, and its wait starts again
    /// as if traced (the bound on waiting counts from the last trace or
    /// verification; [`FrameReport::verified`](crate::FrameReport::verified)
    /// counts them). Nothing is sent from the memory. On by default.
    pub loop_verify: bool,
    /// Early decisions (`Some`): a moving or deforming instance's point casts
    /// its rays in a spread order over the scores its last trace kept and stops
    /// once its AO is known, to the stated confidence, to stay within the send
    /// threshold of what clients hold and, where they hold less than open, to
    /// come out short of open (the pipeline's `early` module says how, and what
    /// error it can add). A point that goes on casts every ray and sends the
    /// full trace's AO. With the CPU tracer, or a backend that casts single
    /// rays ([`AoBackend::casts_rays`](crate::AoBackend::casts_rays), as
    /// psao-gpu's does with `GpuBackend::with_single_rays(true)`: it casts each
    /// point's rays a run at a time, all points' runs together, and the same
    /// rules decide on its scores); off on any other backend, which traces
    /// every ray. Off too while [`settle_steps`](Self::settle_steps) is set
    /// (settling needs every trace whole), without [`skip`](Self::skip) (the
    /// baseline), and below 8 rays a point. Moving points' scores take up to
    /// [`ray_cache_bytes`](Self::ray_cache_bytes) besides the static points'
    /// kept scores, plus four to eight bytes a point of the moving
    /// instances (each point's early stops in a row). `None` by default:
    /// every point chosen casts all its rays.
    /// (`psao serve`, `psao demo` and `psao bench` make them by default under
    /// a ray budget: BENCHMARKS.md, "the ray budget, eighteenth part",
    /// measures what they gain and cost there.)
    pub early: Option<EarlyDecisions>,
    /// Seconds the scene is posed ahead of the pipeline's clock: a step
    /// to time `t` traces and sends the scene's animation (and its camera
    /// path, for culling) at `t + lead`, so a frame that reaches its
    /// clients `lead` after its tick shows the pose they draw then, not
    /// the one of a tick earlier. A server sets it to its period plus the
    /// network's delay; placements
    /// ([`place_instance`](crate::Pipeline::place_instance)) are not
    /// predicted and apply as they come. 0: the scene at the clock's time.
    pub lead: f32,
    /// A point whose trace gives the AO its last trace gave (motion
    /// changes it no more), or that motion has just left (it is not traced
    /// again: it keeps that AO), is sent if its AO is this many 1/255
    /// steps or more from what clients hold, however far below the send
    /// threshold: without this the threshold's worth of error stays behind
    /// wherever motion passed and left AO short of open (1: to the
    /// quantization; 0: off, the default; a point that came out fully open
    /// is sent anyway, [`psao_codec::SentPoint::changed`]). A point motion
    /// has left casts no ray for it; frames stay the same with or without
    /// ray reuse (points dropped from a full cell aside, as before). It
    /// costs bytes for little on the bench's animated scenes
    /// (BENCHMARKS.md), so it is off unless asked for. With the
    /// Laine-Karras estimator at few rays (its AO moves in steps of
    /// `1 / rays`: at 24 rays above the default send threshold of 8/255)
    /// every change passes the threshold and nothing is left to settle.
    pub settle_steps: u8,
}

impl PipelineConfig {
    /// The defaults with `density` points spawned per square metre and
    /// `rays` AO rays per point (the two settings most callers choose).
    pub fn with_density_and_rays(density: f32, rays: u32) -> PipelineConfig {
        PipelineConfig {
            density,
            ao: AoParams {
                rays,
                ..AoParams::default()
            },
            ..PipelineConfig::default()
        }
    }
}

impl Default for PipelineConfig {
    fn default() -> Self {
        PipelineConfig {
            density: 64.0,
            seed: 1,
            ao: AoParams {
                rays: 64,
                ..AoParams::default()
            },
            thresholds: Thresholds::default(),
            layout: LayoutParams::default(),
            encoder: EncoderConfig::default(),
            skip: true,
            ray_reuse: true,
            skip_open: true,
            ray_cache_bytes: 64 << 20,
            budget: RayBudget::Unlimited,
            max_wait: 8,
            max_wait_limit: 60,
            movers_every_step: false,
            movers_whole: MoversWhole::Auto,
            plan_late: false,
            loop_memory_bytes: 64 << 20,
            loop_verify: true,
            early: None,
            lead: 0.0,
            settle_steps: 0,
            split_bvh: true,
            cull: None,
            fill_buried: true,
            fill_gaps: true,
            max_points: DEFAULT_MAX_POINTS,
            bind_space: true,
        }
    }
}

//! What the reference server streams: a [`FrameSource`] steps a scene and
//! encodes its frames. The server asks it for a frame each tick and for a
//! keyframe when a client needs one, hands it the clients' scene events
//! (`MOVE_INSTANCE`) and, when it culls, what the clients see
//! (`CAMERA`, spec/session.md 3.2).
//!
//! psao-scene's `Pipeline` is one source (feature `scene`, in the
//! `scene_source` module); a user's own ray tracer, a recorded stream or
//! a test's synthetic stream are others.

use glam::Affine3A;
use psao_codec::EncodedFrame;

use crate::control::CameraPose;

/// An error of a frame source, as text for the log or a client's
/// `EVENT_REFUSED` notice.
pub type SourceError = Box<dyn std::error::Error + Send + Sync + 'static>;

/// What `WELCOME` announces about a source's frames.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SourceInfo {
    /// The compression id its frames use (they are encoded once).
    pub compression: u8,
    /// Largest frame it encodes.
    pub max_frame_bytes: u32,
    /// Largest uncompressed payload it encodes.
    pub max_payload_bytes: u32,
    /// Bytes of the mirror a client needs for the scene.
    pub mirror_bytes: u64,
    /// The largest point format its frames define instances with (0, or 1
    /// where some are in bind space: spec/wire-format.md 6.1).
    pub point_format: u8,
    /// Whether its frames define instances with overflow chains
    /// (spec/wire-format.md 7.4).
    pub overflow: bool,
    /// Whether it culls to what the clients see (`WELCOME`'s
    /// `flags.culling`, for viewers); then the server calls
    /// [`FrameSource::set_views`] before each step.
    pub culls: bool,
}

/// What one step did, summed into the server's counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepReport {
    /// Points whose AO was traced.
    pub traced: u64,
    /// Points sent (changed past the thresholds).
    pub updated: u64,
    /// Points waiting out of every client's view.
    pub culled: u64,
    /// Points waiting for a later step's ray budget, after the step (the
    /// latest step's, when summed).
    pub waiting: u64,
    /// The longest any point has waited for the budget, in steps (the
    /// largest, when summed).
    pub oldest_wait: u32,
    /// The bound on waiting the step enforced, in steps: no point waits
    /// longer (0 without a budget; the largest, when summed).
    pub wait_bound: u32,
}

impl StepReport {
    /// Adds `other` to this.
    pub fn accumulate(&mut self, other: &StepReport) {
        self.traced += other.traced;
        self.updated += other.updated;
        self.culled += other.culled;
        self.waiting = other.waiting;
        self.oldest_wait = self.oldest_wait.max(other.oldest_wait);
        self.wait_bound = self.wait_bound.max(other.wait_bound);
    }
}

/// What the clients see, for a culling source.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ClientViews<'a> {
    /// A client that does not say what it sees is connected: cull nothing.
    All,
    /// Every client's last `CAMERA` (empty: no client, no one looks).
    Poses(&'a [CameraPose]),
}

/// A scene that steps and encodes frames for the reference server.
///
/// The server calls it from one thread, in this order each tick:
/// [`place`](FrameSource::place) for the clients' events,
/// [`set_views`](FrameSource::set_views) when it culls,
/// [`step`](FrameSource::step), then [`keyframe`](FrameSource::keyframe)
/// if a client needs one. A keyframe must carry the state of the last
/// frame stepped, with that frame's sequence, or a later one.
pub trait FrameSource: Send + 'static {
    /// What `WELCOME` announces; asked once, when the server starts.
    fn info(&self) -> SourceInfo;

    /// Advances the scene by `dt` seconds; the frame to send (`None` when
    /// nothing changed) and what the step did.
    fn step(&mut self, dt: f32) -> Result<(Option<EncodedFrame>, StepReport), SourceError>;

    /// A keyframe of the current state.
    fn keyframe(&mut self) -> Result<EncodedFrame, SourceError>;

    /// A client moves instance `instance` to `transform`
    /// (`MOVE_INSTANCE`); an error is sent back to that client as an
    /// `EVENT_REFUSED` notice.
    fn place(&mut self, instance: u32, transform: Affine3A) -> Result<(), SourceError>;

    /// What the clients see now; called before each step when
    /// [`SourceInfo::culls`] is set. The default ignores it.
    fn set_views(&mut self, views: ClientViews<'_>) {
        let _ = views;
    }
}

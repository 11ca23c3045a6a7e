//! The publisher's side of spec/moq.md 4 and 5, sans-IO: which frames go
//! into which group of the `frames` track, when a group rolls over to a
//! new keyframe, and which digests go on the `digest` track.
//!
//! The I/O layer steps its [`psao_proto::FrameSource`] each tick and hands
//! the result to [`Broadcaster::step`] with a way to encode a keyframe;
//! it writes the [`Write`]s it gets back, in order.

use std::time::{Duration, Instant};

use bytes::Bytes;
use psao_codec::EncodedFrame;
use psao_proto::{OwnMirror, SourceError, SourceInfo};

use crate::catalog::encode_digest;

/// When the publisher starts a new group (spec/moq.md 4).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupPolicy {
    /// A group rolls over once its deltas would pass this many times its
    /// keyframe's bytes (`R`).
    pub delta_ratio: f64,
    /// A group rolls over this long after it began, even with no delta
    /// (`T`): a joiner or a subscriber that lost a group waits at most
    /// this for a keyframe.
    pub max_age: Duration,
    /// A digest goes on the `digest` track for every group's keyframe and
    /// for every this many frames after it (0: no digest track).
    pub digest_every: u32,
}

impl Default for GroupPolicy {
    /// The reference publisher's: `R = 1`, `T = 2 s`, a digest every 60
    /// frames.
    fn default() -> GroupPolicy {
        GroupPolicy {
            delta_ratio: 1.0,
            max_age: Duration::from_secs(2),
            digest_every: 60,
        }
    }
}

/// One thing to write, in the order given.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Write {
    /// Finish the open `frames` group (if any) and start group `group`
    /// with this keyframe.
    Open {
        /// The new group's id.
        group: u64,
        /// Its first frame, a keyframe.
        keyframe: Bytes,
    },
    /// Append a delta to the open group `group`.
    Append {
        /// The open group's id.
        group: u64,
        /// The delta.
        frame: Bytes,
    },
    /// Write group `group` of the `digest` track: one frame, this `DIGEST`
    /// body.
    Digest {
        /// The digest track's group id.
        group: u64,
        /// `sequence` and digest, 8 bytes.
        body: Bytes,
    },
}

/// Why a group rolled over, counted in [`BroadcastStats`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Roll {
    First,
    Ratio,
    Age,
    Gap,
    Keyframe,
}

/// What a [`Broadcaster`] has written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BroadcastStats {
    /// Groups started.
    pub groups: u64,
    /// Keyframes written (one per group).
    pub keyframes: u64,
    /// Deltas appended.
    pub deltas: u64,
    /// Bytes of frames written (keyframes and deltas).
    pub frame_bytes: u64,
    /// Groups started because the deltas reached `R` times the keyframe.
    pub rolled_by_ratio: u64,
    /// Groups started because the group was `T` old.
    pub rolled_by_age: u64,
    /// Groups started because a delta did not follow the group's last
    /// frame (the source skipped a sequence).
    pub rolled_by_gap: u64,
    /// Digests written.
    pub digests: u64,
    /// Groups ended early because a write failed ([`Broadcaster::interrupt`]).
    pub interrupted: u64,
}

#[derive(Debug)]
struct OpenGroup {
    id: u64,
    started: Instant,
    keyframe_bytes: usize,
    delta_bytes: usize,
    /// Sequence of its last frame.
    last: u32,
    /// Frames since its keyframe (for digests).
    since_keyframe: u32,
}

/// The publisher's group plan and its own mirror (for digests).
#[derive(Debug)]
pub struct Broadcaster {
    policy: GroupPolicy,
    open: Option<OpenGroup>,
    next_group: u64,
    next_digest_group: u64,
    own: Option<OwnMirror>,
    stats: BroadcastStats,
}

/// The `base_sequence` of a frame (header bytes 12..16,
/// spec/wire-format.md 2).
fn base_sequence(frame: &[u8]) -> Option<u32> {
    frame
        .get(12..16)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

impl Broadcaster {
    /// A broadcaster for a source described by `info`, with no group yet.
    pub fn new(info: &SourceInfo, policy: GroupPolicy) -> Broadcaster {
        Broadcaster {
            own: (policy.digest_every > 0).then(|| OwnMirror::new(info)),
            policy,
            open: None,
            next_group: 0,
            next_digest_group: 0,
            stats: BroadcastStats::default(),
        }
    }

    /// What it has written so far.
    pub fn stats(&self) -> BroadcastStats {
        self.stats
    }

    /// Ends the open group: a frame of it could not be written, so its
    /// later deltas would not apply for anyone. The next step starts a new
    /// group with a keyframe (spec/moq.md 4).
    pub fn interrupt(&mut self) {
        if self.open.take().is_some() {
            self.stats.interrupted += 1;
        }
    }

    /// The id of the open `frames` group.
    pub fn open_group(&self) -> Option<u64> {
        self.open.as_ref().map(|g| g.id)
    }

    /// One tick: `frame` is what the source stepped (`None`: nothing
    /// changed); `keyframe` encodes a keyframe of the source's current
    /// state, called only when a group starts. Returns what to write.
    pub fn step(
        &mut self,
        now: Instant,
        frame: Option<EncodedFrame>,
        keyframe: impl FnOnce() -> Result<EncodedFrame, SourceError>,
    ) -> Result<Vec<Write>, SourceError> {
        let roll = match (&self.open, &frame) {
            (None, _) => Some(Roll::First),
            (Some(_), Some(f)) if f.keyframe => Some(Roll::Keyframe),
            (Some(g), Some(f)) => {
                if base_sequence(&f.bytes) != Some(g.last) {
                    Some(Roll::Gap)
                } else if now.duration_since(g.started) >= self.policy.max_age {
                    Some(Roll::Age)
                } else if (g.delta_bytes + f.bytes.len()) as f64
                    > self.policy.delta_ratio * g.keyframe_bytes as f64
                {
                    Some(Roll::Ratio)
                } else {
                    None
                }
            }
            (Some(g), None) => {
                (now.duration_since(g.started) >= self.policy.max_age).then_some(Roll::Age)
            }
        };
        let mut out = Vec::new();
        match roll {
            None => {
                // An open group and a delta that follows its last frame.
                let (Some(f), Some(g)) = (frame, self.open.as_mut()) else {
                    return Ok(out);
                };
                g.delta_bytes += f.bytes.len();
                g.last = f.sequence;
                g.since_keyframe += 1;
                let digest_now = self.policy.digest_every > 0
                    && g.since_keyframe.is_multiple_of(self.policy.digest_every);
                self.stats.deltas += 1;
                self.stats.frame_bytes += f.bytes.len() as u64;
                out.push(Write::Append {
                    group: g.id,
                    frame: f.bytes.clone(),
                });
                self.apply_own(&f, digest_now, &mut out);
            }
            Some(why) => {
                let kf = match frame {
                    Some(f) if f.keyframe => f,
                    _ => keyframe()?,
                };
                let id = self.next_group;
                self.next_group += 1;
                self.open = Some(OpenGroup {
                    id,
                    started: now,
                    keyframe_bytes: kf.bytes.len(),
                    delta_bytes: 0,
                    last: kf.sequence,
                    since_keyframe: 0,
                });
                self.stats.groups += 1;
                self.stats.keyframes += 1;
                self.stats.frame_bytes += kf.bytes.len() as u64;
                match why {
                    Roll::Ratio => self.stats.rolled_by_ratio += 1,
                    Roll::Age => self.stats.rolled_by_age += 1,
                    Roll::Gap => self.stats.rolled_by_gap += 1,
                    Roll::First | Roll::Keyframe => {}
                }
                out.push(Write::Open {
                    group: id,
                    keyframe: kf.bytes.clone(),
                });
                self.apply_own(&kf, true, &mut out);
            }
        }
        Ok(out)
    }

    /// Applies a written frame to the own mirror, and queues its digest
    /// when `digest_now`.
    fn apply_own(&mut self, frame: &EncodedFrame, digest_now: bool, out: &mut Vec<Write>) {
        let Some(own) = self.own.as_mut() else {
            return;
        };
        if own.apply(frame).is_err() {
            // A source bug: no digest until the next keyframe applies.
            return;
        }
        if digest_now && let (Some(seq), Some(d)) = (own.sequence(), own.digest()) {
            out.push(Write::Digest {
                group: self.next_digest_group,
                body: encode_digest(seq, d),
            });
            self.next_digest_group += 1;
            self.stats.digests += 1;
        }
    }
}

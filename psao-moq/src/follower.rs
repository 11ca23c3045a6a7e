//! A subscriber's side of spec/moq.md 3-5, sans-IO: the catalog, then the
//! `frames` track's groups into a [`psao_codec::Decoder`] (the codec's own
//! decoder and mirror, unchanged), and the `digest` track's digests
//! compared with the mirror.
//!
//! The I/O layer reads the catalog first ([`Follower::on_catalog`]), then
//! hands every frame of every `frames` group to [`Follower::on_frame`]
//! with its group id and index, and every `digest` frame to
//! [`Follower::on_digest`], in the order they arrive.

use std::collections::VecDeque;

use psao_codec::wire::sequence::is_newer;
use psao_codec::{DecodeError, Decoder, Event, Limits, Mirror};
use psao_proto::SessionError;
use psao_proto::client::decodable_compressions;
use psao_proto::control::Welcome;

use crate::catalog::{decode_catalog, decode_digest};

/// Digests held until the mirror reaches their sequence, the last to
/// arrive (spec/moq.md 5).
pub const HELD_DIGESTS: usize = 8;

/// Groups in a row whose keyframe may fail to decode before the subscriber
/// leaves (as a direct client's keyframes, spec/session.md 3.5).
pub const MAX_FAILED_KEYFRAMES: u32 = psao_proto::MAX_FAILED_KEYFRAMES;

/// Why a subscriber cannot follow a broadcast (spec/moq.md 3).
#[derive(Debug, thiserror::Error)]
pub enum FollowError {
    /// The catalog frame is malformed.
    #[error("catalog: {0}")]
    Catalog(#[from] SessionError),
    /// The catalog asks for more than this subscriber accepts.
    #[error("the broadcast needs {what} {needed}; this subscriber accepts {accepted}")]
    AboveLimits {
        /// Which limit.
        what: &'static str,
        /// The catalog's value.
        needed: u64,
        /// This subscriber's.
        accepted: u64,
    },
    /// A digest arrived before the catalog (it is ignored).
    #[error("a {0} arrived before the catalog")]
    BeforeCatalog(&'static str),
    /// The keyframes of this many groups in a row failed to decode
    /// (spec/moq.md 4: the subscriber leaves, as a direct client does,
    /// spec/session.md 3.5).
    #[error("the keyframes of {groups} groups in a row failed to decode; the last: {last}")]
    Undecodable {
        /// Groups whose keyframe failed, in a row.
        groups: u32,
        /// The last decode error.
        last: String,
    },
}

/// What one `frames` frame did.
#[derive(Debug, PartialEq)]
pub enum Followed {
    /// Applied; the mirror is at `sequence`.
    Applied {
        /// The mirror's sequence.
        sequence: u32,
        /// Whether it was a keyframe.
        keyframe: bool,
    },
    /// Not applied, and not a fault: a frame of a group whose keyframe was
    /// not applied (joined mid-group, or the group broke earlier), a group
    /// older than the newest seen, or a frame older than the mirror.
    Ignored,
    /// A delta that does not apply to the mirror (a frame of the group was
    /// lost): the rest of the group is ignored and the next group's
    /// keyframe repairs the mirror.
    WaitKeyframe,
    /// A frame that failed to decode; the mirror is unchanged and the rest
    /// of the group is ignored.
    Failed(DecodeError),
}

/// What a digest compared to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DigestCheck {
    /// The mirror at that sequence has that digest.
    Match,
    /// It has another: the mirror is out of sync until the next keyframe.
    Mismatch,
    /// Held until the mirror reaches its sequence.
    Held,
    /// The mirror is past it (or never held that state): dropped.
    Passed,
}

/// What a [`Follower`] has seen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FollowStats {
    /// `frames` frames received.
    pub frames: u64,
    /// Bytes of them.
    pub bytes: u64,
    /// Frames applied.
    pub applied: u64,
    /// Keyframes applied.
    pub keyframes: u64,
    /// Frames ignored (see [`Followed::Ignored`]).
    pub ignored: u64,
    /// Deltas that did not apply, or frames that failed to decode.
    pub broken: u64,
    /// Groups seen (with at least one frame).
    pub groups: u64,
    /// Group ids skipped between two groups seen (lost, expired, or
    /// never read because a newer one came first).
    pub groups_missed: u64,
    /// Digests that matched.
    pub digests_matched: u64,
    /// Digests that did not.
    pub digest_mismatches: u64,
}

#[derive(Debug)]
struct Group {
    id: u64,
    /// Its keyframe was applied, and nothing since broke.
    following: bool,
}

/// A subscriber's mirror of one broadcast.
#[derive(Debug)]
pub struct Follower {
    limits: Limits,
    catalog: Option<Welcome>,
    decoder: Decoder,
    group: Option<Group>,
    digests: VecDeque<(u32, u32)>,
    out_of_sync: bool,
    stats: FollowStats,
    /// Groups in a row whose keyframe failed to decode, and the last error.
    failed_keyframes: (u32, String),
}

impl Follower {
    /// A follower that decodes with these limits, before its catalog.
    pub fn new(limits: Limits) -> Follower {
        Follower {
            limits,
            catalog: None,
            decoder: Decoder::new(limits),
            group: None,
            digests: VecDeque::new(),
            out_of_sync: false,
            stats: FollowStats::default(),
            failed_keyframes: (0, String::new()),
        }
    }

    /// The catalog, once read.
    pub fn catalog(&self) -> Option<&Welcome> {
        self.catalog.as_ref()
    }

    /// Reads the catalog frame. A broadcast this subscriber cannot follow
    /// (its compression, point format or limits) is an error; so is a
    /// second catalog that differs from the first (spec/moq.md 3: the
    /// catalog never changes within a broadcast).
    pub fn on_catalog(&mut self, body: &[u8]) -> Result<&Welcome, FollowError> {
        let w = decode_catalog(body)?;
        let check = |what, needed: u64, accepted: u64| {
            if needed > accepted {
                Err(FollowError::AboveLimits {
                    what,
                    needed,
                    accepted,
                })
            } else {
                Ok(())
            }
        };
        check(
            "max_frame_bytes",
            w.max_frame_bytes.into(),
            self.limits.max_frame_bytes.into(),
        )?;
        check(
            "max_payload_bytes",
            w.max_payload_bytes.into(),
            self.limits.max_payload_bytes.into(),
        )?;
        check("point_format", w.point_format.into(), 1)?;
        if w.compression > 7 || decodable_compressions() & (1 << w.compression) == 0 {
            return Err(FollowError::AboveLimits {
                what: "compression",
                needed: w.compression.into(),
                accepted: decodable_compressions().into(),
            });
        }
        if let Some(old) = &self.catalog {
            if *old != w {
                return Err(FollowError::Catalog(SessionError::malformed(
                    "catalog",
                    "it changed within the subscription",
                )));
            }
            return Ok(self.catalog.insert(w));
        }
        // Frames above the catalog's limits break its promise: they fail to
        // decode, as any frame above the subscriber's own would (the
        // decoder holds no state yet: a catalog comes first).
        let mut limits = self.limits;
        limits.max_frame_bytes = w.max_frame_bytes;
        limits.max_payload_bytes = w.max_payload_bytes;
        self.decoder = Decoder::new(limits);
        Ok(self.catalog.insert(w))
    }

    /// Hands in frame `index` of group `group` of the `frames` track.
    pub fn on_frame(&mut self, group: u64, index: u64, frame: &[u8]) -> Followed {
        self.stats.frames += 1;
        self.stats.bytes += frame.len() as u64;
        if self.catalog.is_none() {
            self.stats.ignored += 1;
            return Followed::Ignored;
        }
        match &self.group {
            Some(g) if group < g.id => {
                // A group older than the newest one seen: its state is too.
                self.stats.ignored += 1;
                return Followed::Ignored;
            }
            Some(g) if group == g.id => {}
            prev => {
                if let Some(g) = prev {
                    self.stats.groups_missed =
                        self.stats.groups_missed.saturating_add(group - g.id - 1);
                }
                self.stats.groups += 1;
                self.group = Some(Group {
                    id: group,
                    following: false,
                });
            }
        }
        let compression = self.catalog.as_ref().map_or(0, |w| w.compression);
        let g = self.group.as_mut().expect("set above");
        if !g.following && index != 0 {
            // Joined inside this group, or it broke: wait for the next.
            self.stats.ignored += 1;
            return Followed::Ignored;
        }
        // A compression other than the catalog's (or none) breaks its
        // promise: a failed frame (spec/session.md 3.2, spec/moq.md 4).
        let result = match frame.get(6) {
            Some(&c) if c != 0 && c != compression => Err(DecodeError::HeaderField("compression")),
            _ => self.decoder.receive(frame),
        };
        match result {
            Ok(Event::Applied { sequence, keyframe }) => {
                g.following = true;
                self.stats.applied += 1;
                if keyframe {
                    self.stats.keyframes += 1;
                    self.out_of_sync = false;
                    self.failed_keyframes.0 = 0;
                }
                self.check_held();
                Followed::Applied { sequence, keyframe }
            }
            Ok(Event::Stale { .. }) => {
                // A frame older than the mirror: a duplicate delta leaves a
                // group followed as it was; a stale keyframe opening a group
                // (a publisher that restarted without a new announcement)
                // is not followed, and the mirror is not in sync.
                if index == 0 {
                    g.following = false;
                }
                self.stats.ignored += 1;
                Followed::Ignored
            }
            Ok(Event::NeedKeyframe { .. }) => {
                g.following = false;
                self.stats.broken += 1;
                Followed::WaitKeyframe
            }
            Err(e) => {
                g.following = false;
                self.stats.broken += 1;
                if index == 0 {
                    self.failed_keyframes = (self.failed_keyframes.0 + 1, e.to_string());
                }
                Followed::Failed(e)
            }
            // An outcome a later codec adds: not applied.
            Ok(_) => {
                self.stats.ignored += 1;
                Followed::Ignored
            }
        }
    }

    /// Hands in a frame of the `digest` track.
    pub fn on_digest(&mut self, body: &[u8]) -> Result<DigestCheck, FollowError> {
        if self.catalog.is_none() {
            return Err(FollowError::BeforeCatalog("digest"));
        }
        let (sequence, digest) = decode_digest(body)?;
        Ok(match self.decoder.mirror().sequence() {
            Some(have) if have == sequence => self.compare(digest),
            Some(have) if !is_newer(sequence, have) => DigestCheck::Passed,
            _ => {
                if self.digests.len() == HELD_DIGESTS {
                    self.digests.pop_front();
                }
                self.digests.push_back((sequence, digest));
                DigestCheck::Held
            }
        })
    }

    /// Compares held digests with the mirror that just moved; drops those
    /// it passed.
    fn check_held(&mut self) {
        let Some(have) = self.decoder.mirror().sequence() else {
            return;
        };
        let mut i = 0;
        while i < self.digests.len() {
            let (seq, d) = self.digests[i];
            if seq == have {
                self.digests.remove(i);
                self.compare(d);
            } else if !is_newer(seq, have) {
                self.digests.remove(i);
            } else {
                i += 1;
            }
        }
    }

    fn compare(&mut self, digest: u32) -> DigestCheck {
        if self.decoder.mirror().digest() == Some(digest) {
            self.stats.digests_matched += 1;
            DigestCheck::Match
        } else {
            self.stats.digest_mismatches += 1;
            self.out_of_sync = true;
            DigestCheck::Mismatch
        }
    }

    /// The mirror (empty before the first keyframe applied).
    pub fn mirror(&self) -> &Mirror {
        self.decoder.mirror()
    }

    /// The decoder, for a renderer that reads its changes.
    pub fn decoder_mut(&mut self) -> &mut Decoder {
        &mut self.decoder
    }

    /// Whether the mirror follows the broadcast: a keyframe applied, the
    /// open group not broken, and no digest mismatch since the last
    /// keyframe.
    pub fn in_sync(&self) -> bool {
        self.mirror().sequence().is_some()
            && !self.out_of_sync
            && self.group.as_ref().is_some_and(|g| g.following)
    }

    /// Whether to leave the broadcast: the keyframes of
    /// [`MAX_FAILED_KEYFRAMES`] groups in a row failed to decode (a
    /// broadcast this subscriber cannot follow, whatever it waits for).
    pub fn gave_up(&self) -> Option<FollowError> {
        let (groups, last) = &self.failed_keyframes;
        (*groups >= MAX_FAILED_KEYFRAMES).then(|| FollowError::Undecodable {
            groups: *groups,
            last: last.clone(),
        })
    }

    /// What it has seen.
    pub fn stats(&self) -> FollowStats {
        self.stats
    }

    /// Starts from no state for a new subscription (spec/moq.md 4,
    /// restarts): no catalog, no mirror, no group seen, no digest held, no
    /// keyframe failure counted. Its counts ([`Follower::stats`]) go on.
    pub fn restart(&mut self) {
        self.decoder = Decoder::new(self.limits);
        self.catalog = None;
        self.group = None;
        self.digests.clear();
        self.out_of_sync = false;
        self.failed_keyframes = (0, String::new());
    }
}

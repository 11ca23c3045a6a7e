//! The frames waiting for one client, bounded in bytes (spec/session.md,
//! section 5.2): a slow client falls behind and is resynchronized with a
//! keyframe; it never makes the server queue without bound.

use std::collections::VecDeque;

use bytes::Bytes;

/// What [`Outbox::push_delta`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pushed {
    /// Queued.
    Queued,
    /// Not queued: the client waits for a keyframe (it just joined, asked
    /// for one, or fell behind).
    Skipped,
    /// It did not fit: every queued frame was dropped and the client is now
    /// behind.
    FellBehind,
}

/// What a queued frame is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Delta,
    Keyframe,
    /// A keyframe that resynchronizes a client that fell behind: it goes
    /// out with a `NOTICE` code 2 (spec/session.md 5.2).
    Resync,
}

/// Frames waiting to be written to one client.
#[derive(Debug)]
pub struct Outbox {
    /// Frames, what each is, and the `DIGEST` to send before it.
    queue: VecDeque<(Bytes, Kind, Option<u32>)>,
    queued_bytes: usize,
    max_bytes: usize,
    /// Waiting for a keyframe: deltas are skipped until one is queued.
    awaiting_keyframe: bool,
    /// Fell behind: a keyframe is due once the queue has drained.
    behind: bool,
    /// How many times it fell behind.
    falls: u64,
    /// Frames dropped or skipped.
    dropped: u64,
    /// Bytes of the keyframe waiting in the queue (not counted against the
    /// bound on deltas), 0 when none waits.
    keyframe_bytes: usize,
}

impl Outbox {
    /// An outbox holding at most `max_bytes` of deltas (one always fits
    /// when none is queued) besides the keyframe waiting ahead of them. A
    /// new client waits for its first keyframe.
    pub fn new(max_bytes: usize) -> Outbox {
        Outbox {
            queue: VecDeque::new(),
            queued_bytes: 0,
            max_bytes,
            awaiting_keyframe: true,
            behind: false,
            falls: 0,
            dropped: 0,
            keyframe_bytes: 0,
        }
    }

    /// Offers a delta.
    pub fn push_delta(&mut self, frame: Bytes) -> Pushed {
        if self.awaiting_keyframe {
            self.dropped += 1;
            return Pushed::Skipped;
        }
        let deltas = self.queued_bytes - self.keyframe_bytes;
        if deltas > 0 && deltas + frame.len() > self.max_bytes {
            self.dropped += self.queue.len() as u64 + 1;
            self.queue.clear();
            self.queued_bytes = 0;
            self.keyframe_bytes = 0;
            self.awaiting_keyframe = true;
            self.behind = true;
            self.falls += 1;
            return Pushed::FellBehind;
        }
        self.queued_bytes += frame.len();
        self.queue.push_back((frame, Kind::Delta, None));
        Pushed::Queued
    }

    /// Skips a delta too large for the client (above its `WELCOME`
    /// limits): what is queued still goes out, then the client is
    /// resynchronized with a keyframe, as after a fall (spec/session.md
    /// 3.2). `FellBehind` when it was in sync, `Skipped` when it already
    /// waited for a keyframe.
    pub fn skip_oversized(&mut self) -> Pushed {
        self.dropped += 1;
        if self.awaiting_keyframe {
            return Pushed::Skipped;
        }
        self.awaiting_keyframe = true;
        self.behind = true;
        self.falls += 1;
        Pushed::FellBehind
    }

    /// Whether the client needs a keyframe now: it waits for one and
    /// nothing is left to write before it.
    pub fn wants_keyframe(&self) -> bool {
        self.awaiting_keyframe && self.queue.is_empty()
    }

    /// Whether deltas are skipped until a keyframe is queued (it just
    /// joined, asked for one, or fell behind).
    pub fn awaits_keyframe(&self) -> bool {
        self.awaiting_keyframe
    }

    /// Whether it fell behind since its last keyframe.
    pub fn is_behind(&self) -> bool {
        self.behind
    }

    /// Asks for a keyframe (the client requested one): deltas are skipped
    /// until it is queued. A keyframe already queued answers the request.
    pub fn request_keyframe(&mut self) {
        if self.keyframe_bytes == 0 {
            self.awaiting_keyframe = true;
        }
    }

    /// Queues a keyframe (whatever the queue holds: it may exceed the bound
    /// by this one frame). Returns whether it resynchronizes a client that
    /// fell behind (it is then popped as such, see [`pop_entry`]). If
    /// deltas behind it overflow the queue before it is written, it is
    /// dropped with them and the client is behind again.
    ///
    /// [`pop_entry`]: Outbox::pop_entry
    pub fn push_keyframe(&mut self, frame: Bytes) -> bool {
        self.queued_bytes += frame.len();
        self.keyframe_bytes += frame.len();
        let resync = std::mem::take(&mut self.behind);
        let kind = if resync { Kind::Resync } else { Kind::Keyframe };
        self.queue.push_back((frame, kind, None));
        self.awaiting_keyframe = false;
        resync
    }

    /// The next frame to write.
    pub fn pop(&mut self) -> Option<Bytes> {
        self.pop_entry().map(|(f, _, _)| f)
    }

    /// The next frame to write, whether it resynchronizes the client, and
    /// the digest to send before it ([`attach_digest`]).
    ///
    /// [`attach_digest`]: Outbox::attach_digest
    pub fn pop_entry(&mut self) -> Option<(Bytes, bool, Option<u32>)> {
        let (f, kind, digest) = self.queue.pop_front()?;
        self.queued_bytes -= f.len();
        if kind != Kind::Delta {
            self.keyframe_bytes -= f.len();
        }
        Some((f, kind == Kind::Resync, digest))
    }

    /// Attaches a mirror digest to the frame queued last (it goes out as
    /// `DIGEST` right before it, spec/session.md 3.8); false when the
    /// queue is empty.
    pub fn attach_digest(&mut self, digest: u32) -> bool {
        match self.queue.back_mut() {
            Some(entry) => {
                entry.2 = Some(digest);
                true
            }
            None => false,
        }
    }

    /// Bytes queued.
    pub fn queued_bytes(&self) -> usize {
        self.queued_bytes
    }

    /// Frames queued.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    /// Whether nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    /// How many times the client fell behind.
    pub fn falls(&self) -> u64 {
        self.falls
    }

    /// Frames dropped or skipped for this client.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

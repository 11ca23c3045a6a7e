//! The server's fan-out policy, sans-IO (spec/session.md 5.2): every frame
//! is encoded once and its bytes (shared, not copied) go into every
//! client's [`Outbox`]; one keyframe per state is shared by all who ask,
//! however many ask or how often; a client that fell behind is told so
//! with a `NOTICE` code 2 handed out with the keyframe that resynchronizes
//! it (one per resync, however often a queued keyframe was dropped before
//! it went out); other notices wait in a bounded queue per client.
//!
//! The I/O layer (the reference server, or a test's simulated link) adds
//! and removes clients, hands in the source's frames and the clients'
//! events, encodes a keyframe when [`Fanout::serve_keyframes`] says one is
//! wanted, and drains each client with [`Fanout::poll_transmit`].

use std::collections::BTreeMap;

use bytes::Bytes;
use psao_codec::EncodedFrame;

use crate::control::{CameraPose, NoticeCode};
use crate::outbox::{Outbox, Pushed};
use crate::server_conn::notice;

/// Most notices waiting for one client (the oldest are dropped).
pub const MAX_NOTICES: usize = 16;

/// What [`Fanout::serve_keyframes`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Keyframes {
    /// No client waits for a keyframe.
    NotWanted,
    /// The shared keyframe of the current state was queued for every
    /// client that wanted one (their writers have something to send).
    Shared,
    /// A keyframe is wanted and none of the current state exists: encode
    /// one and give it to [`Fanout::push_keyframe`].
    Encode,
}

/// A client of a [`Fanout`], numbered from 0 in the order they joined.
pub type ClientId = u64;

/// What to write to one client now: its notices (control stream) first,
/// then at most one frame (frame stream); or, once the client cannot be
/// served, why.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Transmit {
    /// `NOTICE` messages, encoded.
    pub notices: Vec<Bytes>,
    /// The next frame, if one waits.
    pub frame: Option<Bytes>,
    /// Set once the keyframe this client needs is above the limits of its
    /// `WELCOME`: close the connection with `capability_mismatch` and this
    /// reason (after writing what came before).
    pub refused: Option<String>,
}

/// The `uncompressed_len` of a frame (header bytes 20..24; 0 if short).
fn payload_len(frame: &[u8]) -> u32 {
    frame
        .get(20..24)
        .map_or(0, |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

#[derive(Debug)]
struct Slot {
    outbox: Outbox,
    notices: Vec<Bytes>,
    /// Whether its `HELLO` said it sends camera poses.
    viewer: bool,
    /// Its last `CAMERA`.
    view: Option<CameraPose>,
    /// The `max_frame_bytes` and `max_payload_bytes` of its `WELCOME`.
    limits: (u32, u32),
    /// Why it can no longer be served (a keyframe above its limits).
    refused: Option<String>,
    /// Digests (spec/session.md 3.8): every how many frames (0: none).
    digest_every: u16,
    /// Frames handed to it until the next periodic digest.
    digest_countdown: u32,
    /// It asked for a digest (`DIGEST_REQUEST`) not yet answered.
    digest_asked: bool,
    /// Whether its session has digests at all.
    digests: bool,
    /// The sequence of the last frame handed out to it.
    last_sent: Option<u32>,
}

/// The `sequence` of a frame (header bytes 8..12).
fn sequence_of(frame: &[u8]) -> Option<u32> {
    frame
        .get(8..12)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// A `DIGEST` as bytes.
fn digest_message(sequence: u32, digest: u32) -> Bytes {
    crate::control::Control::Digest { sequence, digest }
        .to_bytes()
        .freeze()
}

impl Slot {
    /// Whether the next frame queued for it carries a digest.
    fn digest_due(&self) -> bool {
        self.digests && (self.digest_asked || (self.digest_every > 0 && self.digest_countdown <= 1))
    }

    /// The frame just queued gets `digest` if one is due.
    fn queued(&mut self, digest: Option<u32>) {
        if !self.digests {
            return;
        }
        let due = self.digest_due();
        if self.digest_every > 0 {
            self.digest_countdown = self.digest_countdown.saturating_sub(1);
        }
        if let (true, Some(d)) = (due, digest)
            && self.outbox.attach_digest(d)
        {
            self.digest_asked = false;
            if self.digest_countdown == 0 {
                self.digest_countdown = u32::from(self.digest_every);
            }
        }
    }

    /// Whether `frame` is above this client's limits.
    fn too_large(&self, frame: &[u8]) -> bool {
        frame.len() as u64 > u64::from(self.limits.0) || payload_len(frame) > self.limits.1
    }

    fn notice(&mut self, n: Bytes) {
        if self.notices.len() >= MAX_NOTICES {
            self.notices.remove(0);
        }
        self.notices.push(n);
    }
}

/// The clients of one stream and the frames waiting for each.
#[derive(Debug)]
pub struct Fanout {
    clients: BTreeMap<ClientId, Slot>,
    next_id: ClientId,
    max_queue_bytes: usize,
    /// The last keyframe encoded, while no frame has been pushed since:
    /// it is the current state, for every client that asks.
    shared_keyframe: Option<Bytes>,
    /// The digest of the shared keyframe's state, if it was computed.
    shared_digest: Option<u32>,
    falls: u64,
    resyncs: u64,
    /// The largest frame and payload pushed so far.
    largest: (u32, u32),
}

impl Fanout {
    /// No clients yet; each will queue at most `max_queue_bytes` of deltas
    /// before it falls behind.
    pub fn new(max_queue_bytes: usize) -> Fanout {
        Fanout {
            clients: BTreeMap::new(),
            next_id: 0,
            max_queue_bytes,
            shared_keyframe: None,
            shared_digest: None,
            falls: 0,
            resyncs: 0,
            largest: (0, 0),
        }
    }

    /// Adds a client that has been welcomed (`viewer`: its `HELLO` said it
    /// sends camera poses). It waits for its first keyframe.
    pub fn add_client(&mut self, viewer: bool) -> ClientId {
        let id = self.next_id;
        self.next_id += 1;
        self.clients.insert(
            id,
            Slot {
                outbox: Outbox::new(self.max_queue_bytes),
                notices: Vec::new(),
                viewer,
                view: None,
                limits: (u32::MAX, u32::MAX),
                refused: None,
                digest_every: 0,
                digest_countdown: 0,
                digest_asked: false,
                digests: false,
                last_sent: None,
            },
        );
        id
    }

    /// The limits `id`'s `WELCOME` gave (`max_frame_bytes`,
    /// `max_payload_bytes`; none until set). A delta above them is not
    /// sent to it: it is resynchronized with a keyframe as if it had
    /// fallen behind. A keyframe above them cannot be sent at all: its
    /// [`Transmit::refused`] says so.
    pub fn set_limits(&mut self, id: ClientId, max_frame_bytes: u32, max_payload_bytes: u32) {
        if let Some(c) = self.clients.get_mut(&id) {
            c.limits = (max_frame_bytes, max_payload_bytes);
        }
    }

    /// Turns digests on for `id` (its session negotiated them), sent every
    /// `every` frames handed to it (0: only when asked), or changes the
    /// interval (`DIGEST_REQUEST`, spec/session.md 3.9).
    pub fn set_digests(&mut self, id: ClientId, every: u16) {
        if let Some(c) = self.clients.get_mut(&id) {
            c.digests = true;
            c.digest_every = every;
            c.digest_countdown = u32::from(every);
        }
    }

    /// `id` asked for a digest (`DIGEST_REQUEST`): it goes with the next
    /// frame handed to it, or, if none waits, out at once with
    /// [`answer_digests`](Fanout::answer_digests).
    pub fn request_digest(&mut self, id: ClientId) {
        if let Some(c) = self.clients.get_mut(&id).filter(|c| c.digests) {
            c.digest_asked = true;
        }
    }

    /// Whether a digest of the state after the frame about to be pushed
    /// (`keyframe`: a keyframe) is wanted: some client the frame will be
    /// queued for is due one, or (`idle_at`: the state's sequence, on a
    /// tick without a frame) a client that asked waits at that state with
    /// nothing queued. Compute it only then: it reads the whole mirror.
    pub fn wants_digest(&self, keyframe: bool, idle_at: Option<u32>) -> bool {
        self.clients.values().any(|c| {
            if !c.digests || c.refused.is_some() {
                return false;
            }
            let queued_to_it = if keyframe {
                c.outbox.wants_keyframe()
            } else {
                !c.outbox.awaits_keyframe()
            };
            (idle_at.is_none() && c.digest_due() && queued_to_it)
                || (c.digest_asked
                    && c.outbox.is_empty()
                    && !c.outbox.awaits_keyframe()
                    && idle_at.is_some()
                    && c.last_sent == idle_at)
        })
    }

    /// Answers the clients that asked for a digest and have nothing queued
    /// and are at `sequence` (the state `digest` is of): the `DIGEST` goes
    /// out with their notices. Returns how many were answered.
    pub fn answer_digests(&mut self, sequence: u32, digest: u32) -> usize {
        let mut n = 0;
        for c in self.clients.values_mut() {
            if c.digests
                && c.digest_asked
                && c.outbox.is_empty()
                && !c.outbox.wants_keyframe()
                && c.last_sent == Some(sequence)
            {
                c.digest_asked = false;
                c.notice(digest_message(sequence, digest));
                n += 1;
            }
        }
        n
    }

    /// The largest frame (bytes, without the record prefix) and the
    /// largest uncompressed payload pushed so far, keyframes included: a
    /// new client must accept at least these (spec/session.md 3.2).
    pub fn largest(&self) -> (u32, u32) {
        self.largest
    }

    fn saw(&mut self, frame: &[u8]) {
        self.largest.0 = self.largest.0.max(frame.len() as u32);
        self.largest.1 = self.largest.1.max(payload_len(frame));
    }

    /// Removes a client; whether it was there.
    pub fn remove_client(&mut self, id: ClientId) -> bool {
        self.clients.remove(&id).is_some()
    }

    /// Clients now.
    pub fn len(&self) -> usize {
        self.clients.len()
    }

    /// Whether there is no client.
    pub fn is_empty(&self) -> bool {
        self.clients.is_empty()
    }

    /// The clients, in the order they joined.
    pub fn clients(&self) -> impl Iterator<Item = ClientId> + '_ {
        self.clients.keys().copied()
    }

    /// Times a client fell behind, over all clients ever.
    pub fn falls(&self) -> u64 {
        self.falls
    }

    /// Keyframes handed out to resynchronize a client that fell behind,
    /// each with its `NOTICE` code 2, over all clients ever. At most
    /// [`falls`](Fanout::falls): a fall while a resync keyframe still
    /// waited drops it, and the next one resynchronizes.
    pub fn resyncs(&self) -> u64 {
        self.resyncs
    }

    /// The most bytes queued for one client now.
    pub fn max_queued_bytes(&self) -> usize {
        self.clients
            .values()
            .map(|c| c.outbox.queued_bytes())
            .max()
            .unwrap_or(0)
    }

    /// Bytes queued for `id` (0 for an unknown client).
    pub fn queued_bytes(&self, id: ClientId) -> usize {
        self.clients.get(&id).map_or(0, |c| c.outbox.queued_bytes())
    }

    /// Broadcasts a frame the source stepped (encoded once): it goes to
    /// every client that is in sync; a client it does not fit falls
    /// behind. Returns how many fell behind now. The shared keyframe is
    /// no longer the current state.
    pub fn push_frame(&mut self, frame: &EncodedFrame) -> u64 {
        self.push_frame_with_digest(frame, None)
    }

    /// [`push_frame`](Fanout::push_frame), with the digest of the mirror
    /// after it (spec/wire-format.md 7.5) for the clients due one (see
    /// [`wants_digest`](Fanout::wants_digest)).
    pub fn push_frame_with_digest(&mut self, frame: &EncodedFrame, digest: Option<u32>) -> u64 {
        self.shared_keyframe = None;
        self.saw(&frame.bytes);
        let mut falls = 0;
        for c in self.clients.values_mut() {
            let pushed = if c.too_large(&frame.bytes) {
                c.outbox.skip_oversized()
            } else {
                c.outbox.push_delta(frame.bytes.clone())
            };
            match pushed {
                Pushed::FellBehind => falls += 1,
                Pushed::Queued => c.queued(digest),
                Pushed::Skipped => {}
            }
        }
        self.falls += falls;
        falls
    }

    /// Whether some client waits for a keyframe (it just joined, asked for
    /// one, or fell behind and has drained).
    pub fn wants_keyframe(&self) -> bool {
        self.clients
            .values()
            .any(|c| c.refused.is_none() && c.outbox.wants_keyframe())
    }

    /// Hands the shared keyframe of the current state, if there is one, to
    /// every client that wants a keyframe; says whether it did, or whether
    /// one must be encoded.
    pub fn serve_keyframes(&mut self) -> Keyframes {
        if !self.wants_keyframe() {
            return Keyframes::NotWanted;
        }
        match self.shared_keyframe.clone() {
            Some(kf) => {
                self.queue_keyframe(kf);
                Keyframes::Shared
            }
            None => Keyframes::Encode,
        }
    }

    /// A keyframe of the current state, just encoded: it is shared with
    /// every client that wants one now, and with those that ask before the
    /// next frame.
    pub fn push_keyframe(&mut self, keyframe: &EncodedFrame) {
        self.push_keyframe_with_digest(keyframe, None);
    }

    /// [`push_keyframe`](Fanout::push_keyframe), with the digest of the
    /// state it holds for the clients due one. The digest is kept with
    /// the shared keyframe for later askers.
    pub fn push_keyframe_with_digest(&mut self, keyframe: &EncodedFrame, digest: Option<u32>) {
        self.saw(&keyframe.bytes);
        self.shared_keyframe = Some(keyframe.bytes.clone());
        self.shared_digest = digest;
        self.queue_keyframe(keyframe.bytes.clone());
    }

    fn queue_keyframe(&mut self, kf: Bytes) {
        let digest = self.shared_digest;
        for c in self.clients.values_mut() {
            if c.refused.is_some() || !c.outbox.wants_keyframe() {
                continue;
            }
            if c.too_large(&kf) {
                c.refused = Some(format!(
                    "a keyframe of {} bytes ({} uncompressed) is above the client's max_frame_bytes {} (max_payload_bytes {})",
                    kf.len(),
                    payload_len(&kf),
                    c.limits.0,
                    c.limits.1
                ));
            } else {
                c.outbox.push_keyframe(kf.clone());
                c.queued(digest);
            }
        }
    }

    /// `id` asked for a keyframe (`KEYFRAME_REQUEST`).
    pub fn request_keyframe(&mut self, id: ClientId) {
        if let Some(c) = self.clients.get_mut(&id) {
            c.outbox.request_keyframe();
        }
    }

    /// `id` said what it sees (`CAMERA`).
    pub fn set_view(&mut self, id: ClientId, pose: CameraPose) {
        if let Some(c) = self.clients.get_mut(&id) {
            c.view = Some(pose);
        }
    }

    /// Queues a notice for `id` (at most [`MAX_NOTICES`] wait; the oldest
    /// go first). `false` for an unknown client.
    pub fn notice(&mut self, id: ClientId, code: NoticeCode, text: &str) -> bool {
        match self.clients.get_mut(&id) {
            Some(c) => {
                c.notice(notice(code, text));
                true
            }
            None => false,
        }
    }

    /// What a culling server culls to (spec/session.md 3.2): every
    /// client's last `CAMERA`; `None` (cull nothing) while a client that
    /// does not say what it sees (not a viewer, or no `CAMERA` yet) is
    /// connected. With no client the list is empty: no one looks.
    pub fn views(&self) -> Option<Vec<CameraPose>> {
        self.clients
            .values()
            .map(|c| c.view.filter(|_| c.viewer))
            .collect()
    }

    /// What to write to `id` now; `None` for an unknown client. A
    /// keyframe that resynchronizes the client comes with its `NOTICE`
    /// code 2, last among the notices (write the notices first).
    pub fn poll_transmit(&mut self, id: ClientId) -> Option<Transmit> {
        let c = self.clients.get_mut(&id)?;
        let mut notices = std::mem::take(&mut c.notices);
        let frame = c.outbox.pop_entry().map(|(frame, resync, digest)| {
            if resync {
                self.resyncs += 1;
                notices.push(notice(
                    NoticeCode::FellBehind,
                    "fell behind; resynchronizing with a keyframe",
                ));
            }
            c.last_sent = sequence_of(&frame);
            if let (Some(d), Some(s)) = (digest, c.last_sent) {
                notices.push(digest_message(s, d));
            }
            frame
        });
        Some(Transmit {
            notices,
            frame,
            refused: c.refused.clone(),
        })
    }
}

//! A whole client session for a page: psao-proto's sans-IO
//! [`ClientSession`] (HELLO, WELCOME, frame records, ACKs, keyframe
//! requests, digests) over whatever carries its two streams (WebTransport,
//! spec/session.md 9). The page moves bytes; the protocol is the native
//! client's own code.
//!
//! A browser has no `std::time::Instant`, so the session's timers
//! (repeating an unanswered keyframe request in a still scene, closing
//! after the frame stream finished) do not run; a request is still
//! repeated after 2 s of frames.

use psao_proto::codes::Close;
use psao_proto::records::RecordReader;
use psao_proto::{ClientConfig, ClientSession, SessionError};
use wasm_bindgen::prelude::*;

use crate::mirror_view::{GpuFlat, reconstruct, take_changes_flat, transform12};

/// Why a session must close: a code of spec/session.md 7 and its reason.
/// Close the WebTransport session with them
/// (`wt.close({closeCode: e.code, reason: e.reason})`).
#[wasm_bindgen]
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SessionClose {
    code: u32,
    reason: String,
}

#[wasm_bindgen]
impl SessionClose {
    /// The close code (spec/session.md 7).
    #[wasm_bindgen(getter)]
    pub fn code(&self) -> u32 {
        self.code
    }
    /// Why, for people.
    #[wasm_bindgen(getter)]
    pub fn reason(&self) -> String {
        self.reason.clone()
    }
}

impl From<SessionError> for SessionClose {
    fn from(e: SessionError) -> Self {
        let close = Close::from(e);
        SessionClose {
            code: close.code.code(),
            reason: close.reason.to_string(),
        }
    }
}

/// A session's counters (psao-proto's `ClientStats`).
#[wasm_bindgen]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SessionStats {
    /// Frames applied.
    pub applied: f64,
    /// Keyframes among them.
    pub keyframes: f64,
    /// Frames that failed to decode.
    pub failed: f64,
    /// Stale frames ignored.
    pub stale: f64,
    /// Keyframes requested.
    pub requests: f64,
    /// Frame record bytes received (with their 4-byte prefixes).
    pub bytes: f64,
    /// Digests found equal to the mirror's.
    pub digests_matched: f64,
    /// Digests found different.
    pub digest_mismatches: f64,
    /// Digests dropped unchecked.
    pub digests_dropped: f64,
    /// Frame records discarded by `drop_next_frame`.
    pub dropped_by_test: f64,
}

/// One client session (see the module's documentation).
#[wasm_bindgen]
#[derive(Debug)]
pub struct WasmSession {
    inner: ClientSession,
    records: RecordReader,
    drop_next: bool,
    dropped: u64,
    bytes: u64,
    /// Mismatches counted at the last keyframe.
    mismatches_at_keyframe: u64,
    keyframes_seen: u64,
    /// The GPU layout of the mirror, and the count of applied frames it
    /// was made at (the three buffers are read together: made once).
    flat: std::cell::RefCell<Option<(u64, GpuFlat)>>,
}

impl Default for WasmSession {
    fn default() -> Self {
        Self::new()
    }
}

#[wasm_bindgen]
impl WasmSession {
    /// A session with the default limits, offering digests; its `HELLO`
    /// is queued ([`take_transmit`](Self::take_transmit)).
    #[wasm_bindgen(constructor)]
    pub fn new() -> WasmSession {
        let config = ClientConfig::default();
        let records = RecordReader::new(config.limits.max_frame_bytes.max(1 << 16));
        WasmSession {
            inner: ClientSession::new(config),
            records,
            drop_next: false,
            dropped: 0,
            bytes: 0,
            mismatches_at_keyframe: 0,
            keyframes_seen: 0,
            flat: std::cell::RefCell::new(None),
        }
    }

    /// Bytes to write to the control stream, if any.
    pub fn take_transmit(&mut self) -> Option<Vec<u8>> {
        self.inner.take_transmit().map(|b| b.to_vec())
    }

    /// Bytes read from the control stream.
    pub fn on_control(&mut self, bytes: &[u8]) -> Result<(), SessionClose> {
        self.inner.on_control(bytes).map_err(SessionClose::from)
    }

    /// Bytes read from the frame stream: whole records are applied.
    pub fn on_frames(&mut self, mut bytes: &[u8]) -> Result<(), SessionClose> {
        while !bytes.is_empty() {
            let Some(frame) = self.records.read(&mut bytes).map_err(SessionClose::from)? else {
                break;
            };
            self.bytes += 4 + frame.len() as u64;
            if std::mem::take(&mut self.drop_next) {
                self.dropped += 1;
                continue;
            }
            self.inner.apply(&frame).map_err(SessionClose::from)?;
            let s = self.inner.stats();
            if s.keyframes != self.keyframes_seen {
                self.keyframes_seen = s.keyframes;
                self.mismatches_at_keyframe = s.digest_mismatches;
            }
        }
        Ok(())
    }

    /// Asks for a digest now and every `every` frames (spec/session.md
    /// 3.9); false before `WELCOME` or when the server offers none.
    pub fn request_digests(&mut self, every: u16) -> bool {
        self.inner.request_digests(every)
    }

    /// A test hook: the next whole frame record is read and discarded, as
    /// if it had been lost (the session then asks for a keyframe).
    pub fn drop_next_frame(&mut self) {
        self.drop_next = true;
    }

    /// Whether `WELCOME` came.
    pub fn welcomed(&self) -> bool {
        self.inner.welcome().is_some()
    }

    /// The frame rate `WELCOME` announced (0 before it).
    pub fn frame_rate(&self) -> u32 {
        self.inner.welcome().map_or(0, |w| w.frame_rate as u32)
    }

    /// The scene's name from `WELCOME` (empty before it).
    pub fn scene(&self) -> String {
        self.inner
            .welcome()
            .map_or_else(String::new, |w| w.scene.clone())
    }

    /// The mirror's sequence, once it holds a state.
    pub fn sequence(&self) -> Option<u32> {
        self.inner.mirror().sequence()
    }

    /// The mirror's digest (spec/wire-format.md 7.5), once it holds a state.
    pub fn digest(&self) -> Option<u32> {
        self.inner.mirror().digest()
    }

    /// Welcomed, holding a state, no keyframe awaited and no digest
    /// mismatch since the last keyframe.
    pub fn in_sync(&self) -> bool {
        let s = self.inner.stats();
        self.welcomed()
            && self.sequence().is_some()
            && !self.inner.awaiting_keyframe()
            && s.digest_mismatches == self.mismatches_at_keyframe
    }

    /// The counters.
    pub fn stats(&self) -> SessionStats {
        let s = self.inner.stats();
        SessionStats {
            applied: s.applied as f64,
            keyframes: s.keyframes as f64,
            failed: s.failed as f64,
            stale: s.stale as f64,
            requests: s.requests as f64,
            bytes: self.bytes as f64,
            digests_matched: s.digests_matched as f64,
            digest_mismatches: s.digest_mismatches as f64,
            digests_dropped: s.digests_dropped as f64,
            dropped_by_test: self.dropped as f64,
        }
    }

    /// What changed in the mirror since the last call (see
    /// `WasmDecoder::take_changes`).
    pub fn take_changes(&mut self) -> Vec<u32> {
        take_changes_flat(self.inner.mirror_mut())
    }

    /// `reconstruct.wgsl`'s binding 0: 48 words per instance id, from 0
    /// to the largest (all zero: not sampled); an error for an id above
    /// `MAX_GPU_INSTANCE_ID`. The three buffers are made once per applied
    /// frame.
    pub fn gpu_instances(&self) -> Result<Vec<u32>, String> {
        self.with_flat(|f| f.records.clone())
    }

    /// Binding 1: every instance's bucket entries, (key, cell) pairs.
    pub fn gpu_buckets(&self) -> Result<Vec<u32>, String> {
        self.with_flat(|f| f.buckets.clone())
    }

    /// Binding 2: every instance's point words.
    pub fn gpu_words(&self) -> Result<Vec<u32>, String> {
        self.with_flat(|f| f.words.clone())
    }

    /// `f` of the mirror's GPU layout, made anew after each applied frame.
    fn with_flat<R>(&self, f: impl FnOnce(&GpuFlat) -> R) -> Result<R, String> {
        let applied = self.inner.stats().applied;
        let mut cache = self.flat.borrow_mut();
        if cache.as_ref().is_none_or(|(at, _)| *at != applied) {
            *cache = Some((applied, GpuFlat::of(self.inner.mirror())?));
        }
        Ok(f(&cache.as_ref().expect("made above").1))
    }

    /// Whether instance `id` is looked up in bind space (point format 1).
    pub fn bind_space(&self, id: u32) -> bool {
        self.inner
            .mirror()
            .instance(id)
            .is_some_and(|i| i.def().bind_space())
    }

    /// Instance `id`'s local-to-world transform from the stream: 12
    /// floats (x, y, z axes, translation).
    pub fn transform(&self, id: u32) -> Option<Vec<f32>> {
        transform12(self.inner.mirror(), id)
    }

    /// AO per pixel on the CPU from a G-buffer (positions and normals 4
    /// floats a pixel, instance ids; `0xFFFFFFFF`: nothing hit).
    pub fn reconstruct(&self, positions: &[f32], normals: &[f32], ids: &[u32]) -> Vec<f32> {
        reconstruct(self.inner.mirror(), positions, normals, ids)
    }
}

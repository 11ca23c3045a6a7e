//! # psao-wasm
//!
//! psao-codec's [`Decoder`] and mirror for a browser page, through
//! wasm-bindgen: hand it every frame received ([`WasmDecoder::receive`]),
//! read what happened ([`Received`]), the ranges of the mirror that changed
//! since the last look ([`WasmDecoder::take_changes`]), the mirror's
//! digest (spec/wire-format.md 7.5) and an instance's words and buckets to
//! upload. Nothing is reimplemented: the codec's own decoder runs, with
//! zstd decoded in pure Rust (psao-codec's `zstd-pure`), so it builds for
//! `wasm32-unknown-unknown` with no C compiler.
//!
//! [`WasmSession`] is a whole client session (psao-proto's sans-IO
//! `ClientSession`: HELLO, frame records, ACKs, keyframe requests,
//! digests) for a page that carries its streams over WebTransport
//! (spec/session.md 9), with the mirror's GPU buffers for psao-gpu's
//! `reconstruct.wgsl` and AO per pixel on the CPU where WebGPU is missing.
//!
//! Build: `cargo build -p psao-wasm --release --target
//! wasm32-unknown-unknown`, then `wasm-bindgen --target web` (or
//! `nodejs`) on `psao_wasm.wasm`. The same API runs natively (the tests).

use psao_codec::{Decoder, Event, Limits};
use wasm_bindgen::prelude::*;

mod mirror_view;
mod session;

pub use mirror_view::MAX_GPU_INSTANCE_ID;
pub use session::{SessionClose, SessionStats, WasmSession};

/// The 256 decoded octahedral normals of spec/wire-format.md 6, 4 floats
/// each (w unused): `reconstruct.wgsl`'s binding 3.
#[wasm_bindgen]
pub fn normal_table() -> Vec<f32> {
    psao_codec::normal_table()
        .iter()
        .flat_map(|n| n.extend(0.0).to_array())
        .collect()
}

/// What a frame did to the mirror.
#[wasm_bindgen]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Applied: the mirror is at the frame's sequence.
    Applied = 0,
    /// Older than the mirror's state: ignored.
    Stale = 1,
    /// Does not apply to the mirror's state (a frame was missed, or no
    /// keyframe yet): ignored; ask the server for a keyframe.
    NeedKeyframe = 2,
    /// An outcome a later codec adds; read the mirror's sequence.
    Other = 3,
}

/// What one frame did, as [`WasmDecoder::receive`] reports it.
#[wasm_bindgen]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Received {
    /// What happened.
    pub kind: Outcome,
    /// Applied: the mirror's new sequence; otherwise the frame's.
    pub sequence: u32,
    /// Whether it was a keyframe (applied frames).
    pub keyframe: bool,
}

/// Kinds in [`WasmDecoder::take_changes`]'s list.
pub mod change_kind {
    /// The instance was defined or redefined: upload all of it.
    pub const DEFINED: u32 = 0;
    /// The instance was removed.
    pub const REMOVED: u32 = 1;
    /// The instance's transform changed.
    pub const TRANSFORM: u32 = 2;
    /// Bucket entries `start..end` changed.
    pub const BUCKETS: u32 = 3;
    /// Words `start..end` changed.
    pub const WORDS: u32 = 4;
}

/// The decoder and its mirror.
#[wasm_bindgen]
#[derive(Debug)]
pub struct WasmDecoder {
    inner: Decoder,
}

#[wasm_bindgen]
impl WasmDecoder {
    /// A decoder with the default receiver limits (spec/wire-format.md 9)
    /// but for these three (a browser tab's memory is the page's to cap;
    /// `Infinity` for no cap on the mirror). A mirror cap that is not a
    /// number above 0 is an error.
    #[wasm_bindgen(constructor)]
    pub fn new(
        max_frame_bytes: u32,
        max_payload_bytes: u32,
        max_mirror_bytes: f64,
    ) -> Result<WasmDecoder, String> {
        let max_mirror_bytes = match max_mirror_bytes {
            f if f == f64::INFINITY => u64::MAX,
            f if f.is_finite() && f >= 1.0 => f as u64,
            f => {
                return Err(format!(
                    "max_mirror_bytes {f}: not a number above 0 (Infinity for no cap)"
                ));
            }
        };
        let limits = Limits {
            max_frame_bytes,
            max_payload_bytes,
            max_mirror_bytes,
            ..Limits::default()
        };
        Ok(WasmDecoder {
            inner: Decoder::new(limits),
        })
    }

    /// A decoder with the default receiver limits of spec/wire-format.md 9.
    pub fn with_default_limits() -> WasmDecoder {
        WasmDecoder {
            inner: Decoder::new(Limits::default()),
        }
    }

    /// Sets one receiver limit by its name in spec/wire-format.md 9
    /// (`max_frame_bytes`, `max_payload_bytes`, `max_messages`,
    /// `max_instances`, `max_table_log2`, `max_cell_pool`,
    /// `max_mirror_bytes`), before the first frame; false for an unknown
    /// name, or once the mirror holds a state.
    pub fn set_limit(&mut self, name: &str, value: f64) -> bool {
        if self.inner.mirror().sequence().is_some() || !(value.is_finite() && value >= 0.0) {
            return false;
        }
        let mut limits = *self.inner.limits();
        if !limits.set(name, value as u64) {
            return false;
        }
        self.inner = Decoder::new(limits);
        true
    }

    /// Decodes and applies one frame. A frame that fails (malformed, above
    /// a limit, corrupt) leaves the mirror as it was and is an error whose
    /// text starts with the spec's error class (spec/wire-format.md 9),
    /// e.g. `checksum: ...`.
    pub fn receive(&mut self, frame: &[u8]) -> Result<Received, String> {
        match self.inner.receive(frame) {
            Ok(Event::Applied { sequence, keyframe }) => Ok(Received {
                kind: Outcome::Applied,
                sequence,
                keyframe,
            }),
            Ok(Event::Stale { sequence, .. }) => Ok(Received {
                kind: Outcome::Stale,
                sequence,
                keyframe: false,
            }),
            Ok(Event::NeedKeyframe { sequence, .. }) => Ok(Received {
                kind: Outcome::NeedKeyframe,
                sequence,
                keyframe: false,
            }),
            Ok(_) => Ok(Received {
                kind: Outcome::Other,
                sequence: self.inner.mirror().sequence().unwrap_or(0),
                keyframe: false,
            }),
            Err(e) => Err(format!("{}: {e}", e.code())),
        }
    }

    /// The mirror's sequence (`undefined` before the first keyframe).
    pub fn sequence(&self) -> Option<u32> {
        self.inner.mirror().sequence()
    }

    /// The mirror's digest (spec/wire-format.md 7.5; `undefined` before the
    /// first keyframe), to compare with a server's `DIGEST`.
    pub fn digest(&self) -> Option<u32> {
        self.inner.mirror().digest()
    }

    /// Bytes the mirror holds.
    pub fn mirror_bytes(&self) -> f64 {
        self.inner.mirror().bytes() as f64
    }

    /// The ids of the instances the mirror holds, ascending.
    pub fn instances(&self) -> Vec<u32> {
        self.inner.mirror().instances().map(|(id, _)| id).collect()
    }

    /// A copy of an instance's words (one point each: spec/wire-format.md
    /// 6), empty if there is no such instance.
    pub fn words(&self, instance: u32) -> Vec<u32> {
        self.inner
            .mirror()
            .instance(instance)
            .map_or_else(Vec::new, |m| m.words().to_vec())
    }

    /// What changed since the last call, flat: `[all, kind, instance,
    /// start, end, kind, instance, start, end, ...]`. `all` is 1 when
    /// everything may have changed (a keyframe): upload every instance. For
    /// kinds (`change_kind`) without a range, start and end are 0.
    pub fn take_changes(&mut self) -> Vec<u32> {
        mirror_view::take_changes_flat(self.inner.mirror_mut())
    }
}

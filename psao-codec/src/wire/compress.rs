//! Payload compression: the calls into zstd / lz4_flex, and reading a
//! compression id off the wire.

use crate::error::{DecodeError, DecompressFault, EncodeError};
use crate::wire::compression::Compression;

impl Compression {
    /// The compression of an id.
    pub fn from_id(id: u8) -> Result<Compression, DecodeError> {
        match id {
            0 => Ok(Compression::None),
            1 => Ok(Compression::Lz4),
            2 => Ok(Compression::Zstd),
            other => Err(DecodeError::UnknownCompression(other)),
        }
    }
}

/// Reusable decompression state (a zstd context), kept by a decoder.
#[derive(Default)]
pub(crate) struct Decompressor {
    #[cfg(feature = "zstd")]
    zstd: Option<zstd::bulk::Decompressor<'static>>,
    /// Without the C library: ruzstd's decoder (feature `zstd-pure`).
    #[cfg(all(feature = "zstd-pure", not(feature = "zstd")))]
    ruzstd: Option<ruzstd::decoding::FrameDecoder>,
}

/// Decodes zstd frames with ruzstd (pure Rust, for targets without a C
/// compiler such as wasm32) into `dst`, which ends up at most `len` bytes:
/// an output longer than that is corrupt, as with the C library.
#[cfg(feature = "zstd-pure")]
#[cfg_attr(feature = "zstd", allow(dead_code))]
fn ruzstd_into(
    decoder: &mut ruzstd::decoding::FrameDecoder,
    src: &[u8],
    len: usize,
    dst: &mut Vec<u8>,
) -> Result<(), DecompressFault> {
    dst.clear();
    dst.resize(len, 0);
    let n = decoder
        .decode_all(src, dst)
        .map_err(|_| DecompressFault::Corrupt)?;
    dst.truncate(n);
    Ok(())
}

impl std::fmt::Debug for Decompressor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Decompressor")
    }
}

impl Decompressor {
    /// Decompresses `src` into `dst`, which must end up exactly `len` bytes
    /// long. `len` has been checked against the receiver's limit, so
    /// reserving it is bounded.
    pub(crate) fn decompress_into(
        &mut self,
        compression: Compression,
        src: &[u8],
        len: usize,
        dst: &mut Vec<u8>,
    ) -> Result<(), DecodeError> {
        let fail = |fault| DecodeError::Decompress { compression, fault };
        match compression {
            Compression::None => {
                dst.clear();
                dst.extend_from_slice(src);
            }
            #[cfg(feature = "lz4")]
            Compression::Lz4 => {
                crate::wire::lz4_block::check_lz4_block(src, len).map_err(fail)?;
                // Only growth is zero-filled; the scratch keeps its length.
                dst.resize(len, 0);
                let n = lz4_flex::block::decompress_into(src, dst)
                    .map_err(|_| fail(DecompressFault::Corrupt))?;
                dst.truncate(n);
            }
            #[cfg(feature = "zstd")]
            Compression::Zstd => {
                crate::wire::zstd_frames::check_zstd_frames(src).map_err(fail)?;
                dst.clear();
                dst.reserve_exact(len);
                let z = match &mut self.zstd {
                    Some(z) => z,
                    slot => slot.insert(
                        zstd::bulk::Decompressor::new()
                            .map_err(|_| fail(DecompressFault::Corrupt))?,
                    ),
                };
                z.decompress_to_buffer(src, dst)
                    .map_err(|_| fail(DecompressFault::Corrupt))?;
            }
            #[cfg(all(feature = "zstd-pure", not(feature = "zstd")))]
            Compression::Zstd => {
                crate::wire::zstd_frames::check_zstd_frames(src).map_err(fail)?;
                let d = self
                    .ruzstd
                    .get_or_insert_with(ruzstd::decoding::FrameDecoder::new);
                ruzstd_into(d, src, len, dst).map_err(fail)?;
            }
            #[allow(unreachable_patterns)]
            other => return Err(DecodeError::CompressionUnavailable(other)),
        }
        if dst.len() != len {
            return Err(fail(DecompressFault::Length));
        }
        Ok(())
    }
}

/// Reusable compression state (a zstd context), kept by an encoder.
#[derive(Default)]
pub(crate) struct Compressor {
    #[cfg(feature = "zstd")]
    zstd: Option<(i32, zstd::bulk::Compressor<'static>)>,
    #[cfg(feature = "zstd")]
    buf: Vec<u8>,
}

impl std::fmt::Debug for Compressor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Compressor")
    }
}

impl Compressor {
    /// Appends the compressed form of `src` to `dst`.
    pub(crate) fn compress_into(
        &mut self,
        compression: Compression,
        zstd_level: i32,
        src: &[u8],
        dst: &mut Vec<u8>,
    ) -> Result<(), EncodeError> {
        let failed = |e: std::io::Error| EncodeError::Compressor(e.to_string());
        match compression {
            Compression::None => dst.extend_from_slice(src),
            #[cfg(feature = "lz4")]
            Compression::Lz4 => {
                let start = dst.len();
                dst.resize(
                    start + lz4_flex::block::get_maximum_output_size(src.len()),
                    0,
                );
                let n = lz4_flex::block::compress_into(src, &mut dst[start..])
                    .map_err(|e| EncodeError::Compressor(e.to_string()))?;
                dst.truncate(start + n);
            }
            #[cfg(feature = "zstd")]
            Compression::Zstd => {
                if self.zstd.as_ref().is_none_or(|z| z.0 != zstd_level) {
                    let c = zstd::bulk::Compressor::new(zstd_level).map_err(failed)?;
                    self.zstd = Some((zstd_level, c));
                }
                if let Some((_, z)) = &mut self.zstd {
                    // A Vec is written from its start, so compress into
                    // our own buffer and append.
                    self.buf.clear();
                    self.buf.reserve(zstd::zstd_safe::compress_bound(src.len()));
                    z.compress_to_buffer(src, &mut self.buf).map_err(failed)?;
                    dst.extend_from_slice(&self.buf);
                }
            }
            #[allow(unreachable_patterns)]
            other => return Err(EncodeError::CompressionUnavailable(other)),
        }
        let _ = (zstd_level, failed);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each compression round-trips when built in, and is refused with a
    /// typed error when its feature is off (CI runs this with
    /// `--no-default-features` too).
    #[test]
    fn built_in_compressions_roundtrip_and_others_are_refused() {
        let src: Vec<u8> = (0..4000u32).map(|i| (i % 13) as u8).collect();
        for c in [Compression::None, Compression::Lz4, Compression::Zstd] {
            let mut wire = Vec::new();
            let encoded = Compressor::default().compress_into(c, 3, &src, &mut wire);
            let mut out = Vec::new();
            let decoded = Decompressor::default().decompress_into(c, &wire, src.len(), &mut out);
            if c.available() {
                encoded.unwrap();
                decoded.unwrap();
                assert_eq!(out, src);
            } else {
                assert_eq!(encoded, Err(EncodeError::CompressionUnavailable(c)));
                if !c.decodable() {
                    assert_eq!(decoded, Err(DecodeError::CompressionUnavailable(c)));
                }
            }
        }
    }

    /// ruzstd decodes what the C library encodes, byte for byte, and
    /// refuses a wrong length the same way (both features on: the decoder
    /// uses the C library, this calls ruzstd itself).
    #[cfg(all(feature = "zstd", feature = "zstd-pure"))]
    #[test]
    fn ruzstd_decodes_what_zstd_encodes() {
        let mut d = ruzstd::decoding::FrameDecoder::new();
        for size in [0usize, 1, 100, 4096, 100_000, 700_000] {
            let src = crate::wire::runs_and_noise(size, 0x9e37_79b9);
            for level in [1, 3, 19] {
                let mut wire = Vec::new();
                Compressor::default()
                    .compress_into(Compression::Zstd, level, &src, &mut wire)
                    .unwrap();
                let mut out = Vec::new();
                ruzstd_into(&mut d, &wire, src.len(), &mut out).unwrap();
                assert!(out == src, "size {size}, level {level}");
                if size > 0 {
                    assert!(ruzstd_into(&mut d, &wire, src.len() - 1, &mut out).is_err());
                    ruzstd_into(&mut d, &wire, src.len() + 1, &mut out).unwrap();
                    assert_eq!(
                        out.len(),
                        src.len(),
                        "short output is the caller's to refuse"
                    );
                }
            }
        }
    }

    /// The spec's valid zstd vectors (a frame, a skippable frame then a
    /// frame, a payload over two frames) apply with whichever zstd decoder
    /// the build has, ruzstd alone included (CI builds this with
    /// `--no-default-features --features lz4,zstd-pure`), to the digest
    /// their files give.
    #[cfg(any(feature = "zstd", feature = "zstd-pure"))]
    #[test]
    fn the_spec_zstd_vectors_apply() {
        for text in [
            include_str!("../../../spec/vectors/05-keyframe-zstd.txt"),
            include_str!("../../../spec/vectors/60-zstd-skippable-then-frame.txt"),
            include_str!("../../../spec/vectors/61-zstd-two-frames.txt"),
        ] {
            let line = |key: &str| {
                text.lines()
                    .find_map(|l| l.strip_prefix(key))
                    .expect("the line")
                    .to_string()
            };
            let hex = line("frame ");
            let frame: Vec<u8> = (0..hex.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).expect("hex"))
                .collect();
            let mut d = crate::Decoder::new(crate::Limits::default());
            assert_eq!(
                d.receive(&frame),
                Ok(crate::Event::Applied {
                    sequence: 5,
                    keyframe: true
                })
            );
            let digest = u32::from_str_radix(&line("digest "), 16).expect("hex");
            assert_eq!(d.mirror().digest(), Some(digest));
        }
    }

    #[test]
    fn wrong_length_is_refused() {
        let src = vec![7u8; 100];
        for c in [Compression::Lz4, Compression::Zstd]
            .into_iter()
            .filter(|c| c.available())
        {
            let mut wire = Vec::new();
            Compressor::default()
                .compress_into(c, 3, &src, &mut wire)
                .unwrap();
            let mut out = Vec::new();
            let mut d = Decompressor::default();
            for len in [99, 101] {
                assert!(
                    matches!(
                        d.decompress_into(c, &wire, len, &mut out),
                        Err(DecodeError::Decompress { compression, .. }) if compression == c
                    ),
                    "{c:?} to {len} bytes"
                );
            }
        }
    }
}

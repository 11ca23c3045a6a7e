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
                assert_eq!(decoded, Err(DecodeError::CompressionUnavailable(c)));
            }
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

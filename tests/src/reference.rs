//! An independent reference of the frame layer of spec/wire-format.md
//! (section 3: header, limits, length, checksum, compression; checks 1-6
//! of its order), written from the spec without psao-codec's code, for
//! differential tests: where the codec's decoder and this one disagree on
//! a frame's class, one of them breaks the spec.
//!
//! Its LZ4 decoder is its own, enforcing the end-of-block rules while it
//! decodes (the codec walks the block first, then lets lz4_flex decode);
//! its zstd path is libzstd's streaming decoder with a 2^27 window limit
//! (the codec checks frame headers itself, then decodes in one pass),
//! after its own walk of the block headers for the one rule libzstd's
//! streaming decoder does not enforce (a compressed block of under 2
//! bytes, spec 3.2).

use psao_codec::Limits;

/// What the frame layer says about a frame: its payload, or the error
/// class of spec/wire-format.md section 9.
pub fn frame_layer(bytes: &[u8], limits: &Limits) -> Result<Vec<u8>, &'static str> {
    // 1. Frame length against the limit.
    if bytes.len() as u64 > u64::from(limits.max_frame_bytes) {
        return Err("frame_too_large");
    }
    // 2. The header, field by field in table order.
    if bytes.len() < 32 {
        return Err("truncated");
    }
    let u32_at = |i: usize| u32::from_le_bytes(bytes[i..i + 4].try_into().expect("4 bytes"));
    if &bytes[0..4] != b"PSAO" {
        return Err("bad_magic");
    }
    if bytes[4] != 1 {
        return Err("unsupported_version");
    }
    let flags = bytes[5];
    if flags & 0xFC != 0 {
        return Err("header_field");
    }
    let keyframe = flags & 1 != 0;
    let checksummed = flags & 2 != 0;
    let compression = bytes[6];
    if compression > 2 {
        return Err("unknown_compression");
    }
    if bytes[7] != 0 {
        return Err("header_field");
    }
    let (sequence, base) = (u32_at(8), u32_at(12));
    let newer = |a: u32, b: u32| {
        let d = a.wrapping_sub(b);
        d != 0 && d < 1 << 31
    };
    if keyframe && base != sequence || !keyframe && !newer(sequence, base) {
        return Err("header_field");
    }
    let count = u32_at(16);
    if count == 0 {
        return Err("header_field");
    }
    let (uncompressed, compressed) = (u32_at(20), u32_at(24));
    if compression == 0 && compressed != uncompressed {
        return Err("header_field");
    }
    let crc = u32_at(28);
    if !checksummed && crc != 0 {
        return Err("header_field");
    }
    // 3. Limits on the announced sizes.
    if uncompressed > limits.max_payload_bytes {
        return Err("payload_too_large");
    }
    if count > limits.max_messages {
        return Err("too_many_messages");
    }
    // 4. The total length.
    let total = 32 + u64::from(compressed);
    if (bytes.len() as u64) < total {
        return Err("truncated");
    }
    if bytes.len() as u64 > total {
        return Err("trailing_bytes");
    }
    // 5. The checksum over header bytes 0..28 and the payload as sent.
    let wire = &bytes[32..];
    if checksummed {
        let mut h = crc32fast::Hasher::new();
        h.update(&bytes[..28]);
        h.update(wire);
        if h.finalize() != crc {
            return Err("checksum");
        }
    }
    // 6. Decompression to exactly `uncompressed` bytes.
    let n = uncompressed as usize;
    let payload = match compression {
        0 => Some(wire.to_vec()),
        1 => lz4(wire, n),
        _ => zstd_payload(wire, n),
    };
    payload.ok_or("decompress")
}

/// Decodes one LZ4 block to exactly `n` bytes, or `None` if it breaks the
/// block format or its end-of-block rules.
fn lz4(src: &[u8], n: usize) -> Option<Vec<u8>> {
    fn length(src: &[u8], i: &mut usize, nibble: u8) -> Option<usize> {
        let mut len = nibble as usize;
        if nibble == 15 {
            loop {
                let b = *src.get(*i)?;
                *i += 1;
                len += b as usize;
                if b != 255 {
                    break;
                }
            }
        }
        Some(len)
    }
    let mut out: Vec<u8> = Vec::with_capacity(n);
    let mut i = 0;
    let mut matched = false;
    loop {
        let token = *src.get(i)?;
        i += 1;
        let lit = length(src, &mut i, token >> 4)?;
        out.extend_from_slice(src.get(i..i.checked_add(lit)?)?);
        i += lit;
        if out.len() > n {
            return None;
        }
        if i == src.len() {
            // The last sequence: literals only, at least 5 after a match.
            if matched && lit < 5 {
                return None;
            }
            break;
        }
        let offset = u16::from_le_bytes([*src.get(i)?, *src.get(i + 1)?]) as usize;
        i += 2;
        if offset == 0 || offset > out.len() {
            return None;
        }
        let len = length(src, &mut i, token & 15)? + 4;
        // The match must start at least 12 bytes before the end.
        if out.len() + 12 > n || out.len() + len > n {
            return None;
        }
        let start = out.len() - offset;
        for k in 0..len {
            let b = out[start + k];
            out.push(b);
        }
        matched = true;
    }
    (out.len() == n).then_some(out)
}

/// Decodes a zstd payload (one or more frames, skippable ones allowed, at
/// least one zstd frame) with libzstd's streaming decoder, its window
/// limited to 2^27, to exactly `n` bytes.
fn zstd_payload(src: &[u8], n: usize) -> Option<Vec<u8>> {
    use std::io::Read;
    // At least one frame that is not skippable: skip skippable frames by
    // their length fields, then require a zstd frame's magic.
    let mut at = 0usize;
    loop {
        let magic = u32::from_le_bytes(src.get(at..at + 4)?.try_into().ok()?);
        if magic & 0xFFFF_FFF0 != 0x184D_2A50 {
            if magic != 0xFD2F_B528 {
                return None;
            }
            break;
        }
        let size = u32::from_le_bytes(src.get(at + 4..at + 8)?.try_into().ok()?) as usize;
        at = at.checked_add(8 + size)?;
        if at > src.len() {
            return None;
        }
    }
    if short_compressed_block(src) {
        return None;
    }
    let mut d = zstd::stream::read::Decoder::with_buffer(src).ok()?;
    d.window_log_max(27).ok()?;
    let mut out = Vec::with_capacity(n);
    // Read one byte more than wanted: a longer output is an error.
    let got = d.take(n as u64 + 1).read_to_end(&mut out).ok()?;
    (got == n).then_some(out)
}

/// Whether a zstd frame of `src` holds a block of type `Compressed_Block`
/// with a `Block_Size` under 2 (spec/wire-format.md 3.2, RFC 8878
/// 3.1.1.3), which libzstd's streaming decoder takes as an empty block. A
/// walk of frame and block headers only; what it cannot walk (cut short,
/// unknown magic) it leaves to libzstd, which rejects it.
fn short_compressed_block(src: &[u8]) -> bool {
    let byte = |i: usize| src.get(i).copied();
    let mut at = 0usize;
    while let Some(magic) = src.get(at..at + 4) {
        let magic = u32::from_le_bytes(magic.try_into().expect("4 bytes"));
        if (0x184D_2A50..=0x184D_2A5F).contains(&magic) {
            let Some(size) = src.get(at + 4..at + 8) else {
                return false;
            };
            at += 8 + u32::from_le_bytes(size.try_into().expect("4 bytes")) as usize;
            continue;
        }
        if magic != 0xFD2F_B528 {
            return false;
        }
        let Some(fhd) = byte(at + 4) else {
            return false;
        };
        let single_segment = fhd & 0x20 != 0;
        let content_size_bytes = match (fhd >> 6, single_segment) {
            (0, false) => 0,
            (0, true) => 1,
            (1, _) => 2,
            (2, _) => 4,
            _ => 8,
        };
        let dictionary_bytes = [0, 1, 2, 4][usize::from(fhd & 3)];
        at += 5 + usize::from(!single_segment) + dictionary_bytes + content_size_bytes;
        loop {
            let (Some(b0), Some(b1), Some(b2)) = (byte(at), byte(at + 1), byte(at + 2)) else {
                return false;
            };
            let header = u32::from(b0) | u32::from(b1) << 8 | u32::from(b2) << 16;
            let (last, kind, size) = (header & 1 == 1, (header >> 1) & 3, header as usize >> 3);
            if kind == 2 && size < 2 {
                return true;
            }
            at += 3 + if kind == 1 { 1 } else { size };
            if last {
                break;
            }
        }
        if fhd & 0x04 != 0 {
            at += 4;
        }
    }
    false
}

/// Compares psao-codec's `decode_frame` with [`frame_layer`] on one frame:
/// the same error class for a frame-layer failure; the same payload bytes
/// when the frame layer passes (the codec may then still refuse the frame
/// at the message layer). The disagreement, described, otherwise.
pub fn compare(frame: &[u8], limits: &Limits) -> Result<(), String> {
    use psao_codec::DecodeError;
    use psao_codec::wire::{Scratch, decode_frame};
    let reference = frame_layer(frame, limits);
    let mut scratch = Scratch::default();
    let ours = decode_frame(frame, limits, &mut scratch);
    match (&reference, &ours) {
        (Err(class), Err(e)) if e.code() == *class => Ok(()),
        (Ok(p), Ok(view)) if view.payload() == &p[..] => Ok(()),
        (Ok(_), Err(DecodeError::Message { .. })) => Ok(()),
        _ => Err(format!(
            "reference {:?}, codec {:?}, frame {}",
            reference.as_ref().map(|p| p.len()),
            ours.as_ref().map(|v| v.payload().len()),
            frame.iter().map(|b| format!("{b:02x}")).collect::<String>()
        )),
    }
}

/// A frame around `wire` (any bytes) as the payload of `compression`,
/// with a correct length, `uncompressed_len` as given and, when
/// `checksum`, a correct CRC: so that mutated compressed data reaches
/// decompression instead of failing the header or the checksum.
pub fn frame_around(
    wire: &[u8],
    compression: u8,
    uncompressed_len: u32,
    checksum: bool,
) -> Vec<u8> {
    let mut f = b"PSAO".to_vec();
    f.push(1);
    f.push(1 | (checksum as u8) << 1);
    f.push(compression);
    f.push(0);
    for v in [7u32, 7, 1, uncompressed_len, wire.len() as u32] {
        f.extend(v.to_le_bytes());
    }
    let crc = if checksum {
        let mut h = crc32fast::Hasher::new();
        h.update(&f);
        h.update(wire);
        h.finalize()
    } else {
        0
    };
    f.extend(crc.to_le_bytes());
    f.extend_from_slice(wire);
    f
}

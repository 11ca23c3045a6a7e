//! The zstd payload rules of spec/wire-format.md 3.2, checked on the frame
//! headers (RFC 8878 section 3.1) before anything is decompressed: one or
//! more frames, each a zstd frame or a skippable frame, at least one of
//! them a zstd frame; no dictionary; no reserved bit; a `Window_Size` of at
//! most 2^27 bytes; nothing after the last frame. libzstd's one-pass
//! decompression (used after this) does not check the window.

use crate::error::DecompressFault;

/// RFC 8878 3.1.1: the magic of a zstd frame.
const ZSTD_MAGIC: u32 = 0xFD2F_B528;
/// RFC 8878 3.1.2: skippable frames use magics `0x184D2A50..=0x184D2A5F`.
const SKIPPABLE_MAGIC: u32 = 0x184D_2A50;
/// The largest `Window_Size` a frame may ask for.
pub(crate) const MAX_WINDOW: u64 = 1 << 27;

/// Reads `n <= 8` little-endian bytes at `at`.
fn le(src: &[u8], at: usize, n: usize) -> Option<u64> {
    let b = src.get(at..at.checked_add(n)?)?;
    Some(b.iter().rev().fold(0u64, |v, &x| v << 8 | u64::from(x)))
}

/// The header of the zstd frame at the start of `frame`: checks the rules
/// above and returns its `Window_Size`.
fn window_of(frame: &[u8], offset: u32) -> Result<u64, DecompressFault> {
    let cut = DecompressFault::NotAFrame { offset };
    let descriptor = *frame.get(4).ok_or(cut)?;
    let fcs_flag = descriptor >> 6;
    let single_segment = descriptor & 0x20 != 0;
    if descriptor & 0x08 != 0 {
        return Err(DecompressFault::ReservedBit { offset });
    }
    let mut at = 5;
    let mut window = 0;
    if !single_segment {
        let w = *frame.get(at).ok_or(cut)?;
        at += 1;
        let base = 1u64 << (10 + (w >> 3));
        window = base + (base / 8) * u64::from(w & 7);
    }
    let dict_len = [0, 1, 2, 4][usize::from(descriptor & 3)];
    let id = le(frame, at, dict_len).ok_or(cut)?;
    at += dict_len;
    if id != 0 {
        return Err(DecompressFault::Dictionary {
            offset,
            id: id as u32,
        });
    }
    if single_segment {
        // The window is the content size (RFC 8878 3.1.1.1.2).
        let fcs_len = [1, 2, 4, 8][usize::from(fcs_flag)];
        let fcs = le(frame, at, fcs_len).ok_or(cut)?;
        window = if fcs_len == 2 { fcs + 256 } else { fcs };
    }
    if window > MAX_WINDOW {
        return Err(DecompressFault::Window { offset, window });
    }
    Ok(window)
}

/// Checks a zstd payload's frame structure (see the module docs).
pub(crate) fn check_zstd_frames(src: &[u8]) -> Result<(), DecompressFault> {
    let mut at = 0usize;
    let mut zstd_frames = 0u32;
    while at < src.len() {
        let offset = at as u32;
        let rest = &src[at..];
        let magic = le(rest, 0, 4).ok_or(DecompressFault::NotAFrame { offset })? as u32;
        let len = if magic & !0xF == SKIPPABLE_MAGIC {
            let size = le(rest, 4, 4).ok_or(DecompressFault::NotAFrame { offset })?;
            let len = 8 + size;
            if len > rest.len() as u64 {
                return Err(DecompressFault::Corrupt);
            }
            len as usize
        } else if magic == ZSTD_MAGIC {
            window_of(rest, offset)?;
            zstd_frames += 1;
            zstd::zstd_safe::find_frame_compressed_size(rest)
                .map_err(|_| DecompressFault::Corrupt)?
        } else {
            return Err(DecompressFault::NotAFrame { offset });
        };
        at += len;
    }
    if zstd_frames == 0 {
        return Err(DecompressFault::NoFrame);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A zstd frame by hand (RFC 8878): no content size, no checksum, the
    /// window descriptor `wd`, one raw block holding `data`.
    fn raw_frame(wd: u8, data: &[u8]) -> Vec<u8> {
        let mut f = ZSTD_MAGIC.to_le_bytes().to_vec();
        f.extend([0x00, wd]);
        let block = 1 | (data.len() as u32) << 3; // last block, raw
        f.extend(&block.to_le_bytes()[..3]);
        f.extend(data);
        f
    }

    fn skippable(n: usize) -> Vec<u8> {
        let mut f = (SKIPPABLE_MAGIC + 3).to_le_bytes().to_vec();
        f.extend((n as u32).to_le_bytes());
        f.extend(std::iter::repeat_n(0xAB, n));
        f
    }

    #[test]
    fn windows_up_to_2_pow_27_pass_and_larger_fail() {
        // Exponent 17: 2^27; mantissa 1 adds 2^24.
        assert_eq!(check_zstd_frames(&raw_frame(17 << 3, b"abc")), Ok(()));
        assert_eq!(
            check_zstd_frames(&raw_frame(17 << 3 | 1, b"abc")),
            Err(DecompressFault::Window {
                offset: 0,
                window: (1 << 27) + (1 << 24)
            })
        );
        // A single-segment frame's window is its content size.
        let big = zstd::bulk::compress(&vec![0u8; 1000], 3).unwrap();
        assert_eq!(check_zstd_frames(&big), Ok(()));
    }

    #[test]
    fn empty_and_skippable_only_payloads_hold_no_frame() {
        assert_eq!(check_zstd_frames(&[]), Err(DecompressFault::NoFrame));
        assert_eq!(
            check_zstd_frames(&skippable(5)),
            Err(DecompressFault::NoFrame)
        );
        let mut both = skippable(5);
        both.extend(raw_frame(0, b"x"));
        assert_eq!(check_zstd_frames(&both), Ok(()));
    }

    #[test]
    fn broken_headers_are_named() {
        let mut f = raw_frame(0, b"x");
        f[4] |= 0x08;
        assert_eq!(
            check_zstd_frames(&f),
            Err(DecompressFault::ReservedBit { offset: 0 })
        );
        let mut f = raw_frame(0, b"x");
        f[4] |= 0x01;
        f.insert(6, 7);
        assert_eq!(
            check_zstd_frames(&f),
            Err(DecompressFault::Dictionary { offset: 0, id: 7 })
        );
        // Legacy v0.7 magic, and junk after a good frame.
        assert_eq!(
            check_zstd_frames(&0xFD2F_B527u32.to_le_bytes()),
            Err(DecompressFault::NotAFrame { offset: 0 })
        );
        let mut f = raw_frame(0, b"x");
        let n = f.len() as u32;
        f.extend([1, 2]);
        assert_eq!(
            check_zstd_frames(&f),
            Err(DecompressFault::NotAFrame { offset: n })
        );
        // A skippable frame longer than the payload.
        let mut s = skippable(5);
        s.truncate(10);
        assert_eq!(check_zstd_frames(&s), Err(DecompressFault::Corrupt));
    }
}

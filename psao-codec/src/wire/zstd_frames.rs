//! The zstd payload rules of spec/wire-format.md 3.2, checked on the frame
//! headers (RFC 8878 section 3.1) before anything is decompressed: one or
//! more frames, each a zstd frame or a skippable frame, at least one of
//! them a zstd frame; no dictionary; no reserved bit; a `Window_Size` of at
//! most 2^27 bytes; no compressed block under 2 bytes and no block above
//! the smaller of the window and 128 KiB (found on the block headers,
//! walked to find each frame's end); nothing after the last frame. libzstd's one-pass
//! decompression (used after this; ruzstd's with feature `zstd-pure`)
//! does not check the window.

use crate::error::DecompressFault;

/// RFC 8878 3.1.1: the magic of a zstd frame.
const ZSTD_MAGIC: u32 = 0xFD2F_B528;
/// RFC 8878 3.1.2: skippable frames use magics `0x184D2A50..=0x184D2A5F`.
const SKIPPABLE_MAGIC: u32 = 0x184D_2A50;
/// The largest `Window_Size` a frame may ask for.
pub(crate) const MAX_WINDOW: u64 = 1 << 27;
/// RFC 8878 3.1.1.2.4: no block holds or regenerates more than 128 KiB.
const BLOCK_MAX: u64 = 128 << 10;

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

/// The bytes of the zstd frame at the start of `frame`, whose
/// `Window_Size` is `window`, from its header and block headers (RFC 8878
/// 3.1.1: header, blocks up to the one marked last, the checksum if the
/// header says so). Corrupt: a frame cut short, a reserved block type, a
/// compressed block of under 2 bytes (3.1.1.3: it starts with a literals
/// and a sequences section header), which libzstd's streaming decoder
/// would take as an empty block (spec 3.2, vector 63), or a block above
/// `Block_Maximum_Size`, the smaller of `window` and 128 KiB (3.1.1.2.4:
/// a raw or compressed block's content, the bytes an RLE block repeats),
/// which libzstd's one-pass decoder lets through for raw and RLE blocks
/// (vector 64). The same walk with and without the C library; the tests
/// check it against the C library's own on the frames it writes.
fn frame_size(frame: &[u8], window: u64) -> Result<usize, DecompressFault> {
    let cut = DecompressFault::Corrupt;
    let descriptor = *frame.get(4).ok_or(cut)?;
    let single_segment = descriptor & 0x20 != 0;
    let fcs_len = match descriptor >> 6 {
        0 => usize::from(single_segment),
        f => [0, 2, 4, 8][usize::from(f)],
    };
    let dict_len = [0, 1, 2, 4][usize::from(descriptor & 3)];
    let mut at = 5 + usize::from(!single_segment) + dict_len + fcs_len;
    loop {
        let header = le(frame, at, 3).ok_or(cut)?;
        at += 3;
        let size = (header >> 3) as usize;
        if size as u64 > window.min(BLOCK_MAX) {
            return Err(cut);
        }
        at += match (header >> 1) & 3 {
            0 => size,
            1 => 1,
            2 if size >= 2 => size,
            _ => return Err(cut),
        };
        if at > frame.len() {
            return Err(cut);
        }
        if header & 1 == 1 {
            break;
        }
    }
    if descriptor & 0x04 != 0 {
        at += 4;
    }
    if at > frame.len() {
        return Err(cut);
    }
    Ok(at)
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
            let window = window_of(rest, offset)?;
            zstd_frames += 1;
            frame_size(rest, window)?
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

    /// The walk finds the frame sizes the C library finds, on frames it
    /// writes (levels, sizes, checksums on and off) and on every prefix
    /// and a few corruptions of them (both corrupt, or the same size).
    #[cfg(feature = "zstd")]
    #[test]
    fn the_walk_agrees_with_the_c_library() {
        for size in [0usize, 1, 300, 5000, 200_000] {
            let src = crate::wire::runs_and_noise(size, 0x2545_f491);
            for (level, checksum) in [(1, false), (3, true), (19, false)] {
                let mut c = zstd::bulk::Compressor::new(level).unwrap();
                c.include_checksum(checksum).unwrap();
                let mut frame = c.compress(&src).unwrap();
                frame.extend([1, 2, 3]); // what follows the frame
                let whole = zstd::zstd_safe::find_frame_compressed_size(&frame).unwrap();
                assert_eq!(
                    frame_size(&frame, MAX_WINDOW),
                    Ok(whole),
                    "size {size} level {level}"
                );
                for cut in [whole - 1, whole / 2, 6] {
                    let c_says = zstd::zstd_safe::find_frame_compressed_size(&frame[..cut]).ok();
                    assert_eq!(
                        frame_size(&frame[..cut], MAX_WINDOW).ok(),
                        c_says,
                        "cut at {cut}"
                    );
                }
                // A reserved block type in the first block header (the
                // writer puts no dictionary id: window, then content size).
                let mut bad = frame.clone();
                let single = bad[4] & 0x20 != 0;
                let fcs_len = match bad[4] >> 6 {
                    0 => usize::from(single),
                    f => [0, 2, 4, 8][usize::from(f)],
                };
                bad[5 + usize::from(!single) + fcs_len] |= 0b110;
                assert_eq!(
                    frame_size(&bad, MAX_WINDOW).ok(),
                    zstd::zstd_safe::find_frame_compressed_size(&bad).ok()
                );
            }
        }
    }

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

    /// Vector 63: a compressed block of `Block_Size` 0 or 1 is corrupt,
    /// also after a good raw block, where libzstd's streaming decoder
    /// would yield the raw block's bytes; 2 bytes pass the walk (whether
    /// they decompress is the decompressor's to say).
    #[test]
    fn compressed_blocks_under_two_bytes_are_corrupt() {
        let with_last = |size: u32| {
            let mut f = ZSTD_MAGIC.to_le_bytes().to_vec();
            f.extend([0x00, 0x50]);
            f.extend(&(3u32 << 3).to_le_bytes()[..3]); // raw, not last
            f.extend(b"abc");
            f.extend(&(1 | 2 << 1 | size << 3).to_le_bytes()[..3]);
            f.extend(std::iter::repeat_n(0u8, size as usize));
            f
        };
        for size in [0, 1] {
            assert_eq!(
                check_zstd_frames(&with_last(size)),
                Err(DecompressFault::Corrupt),
                "Block_Size {size}"
            );
        }
        assert_eq!(check_zstd_frames(&with_last(2)), Ok(()));
    }

    /// Vector 64: a block above `Block_Maximum_Size` (the smaller of the
    /// window and 128 KiB) is corrupt, whether raw (its content) or RLE
    /// (the bytes it repeats); at the limit it passes.
    #[test]
    fn blocks_above_the_block_maximum_are_corrupt() {
        // A 1 KiB window (descriptor 0): raw blocks of 1024 and 1025 bytes.
        assert_eq!(check_zstd_frames(&raw_frame(0, &[7; 1024])), Ok(()));
        assert_eq!(
            check_zstd_frames(&raw_frame(0, &[7; 1025])),
            Err(DecompressFault::Corrupt)
        );
        let rle = |wd: u8, n: u32| {
            let mut f = ZSTD_MAGIC.to_le_bytes().to_vec();
            f.extend([0x00, wd]);
            f.extend(&(1 | 1 << 1 | n << 3).to_le_bytes()[..3]);
            f.push(0xAB);
            f
        };
        assert_eq!(check_zstd_frames(&rle(0, 1024)), Ok(()));
        assert_eq!(
            check_zstd_frames(&rle(0, 1025)),
            Err(DecompressFault::Corrupt)
        );
        // A window of 2^20 (descriptor 0x50): 128 KiB is the limit.
        assert_eq!(check_zstd_frames(&rle(0x50, 128 << 10)), Ok(()));
        assert_eq!(
            check_zstd_frames(&rle(0x50, (128 << 10) + 1)),
            Err(DecompressFault::Corrupt)
        );
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

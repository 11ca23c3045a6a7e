//! The LZ4 block rules of spec/wire-format.md 3.2, checked before a block
//! is decoded: every sequence is whole, every match reaches back into
//! output already written, the block decodes to exactly the announced
//! length, and it keeps the LZ4 end-of-block rules. lz4_flex decodes
//! blocks that break the last ones; liblz4 refuses them, and the spec
//! makes every decoder refuse them so that two conforming mirrors agree.

use crate::error::DecompressFault;

/// The last match must start at least this many bytes before the end.
const MATCH_START_MARGIN: u64 = 12;
/// After a match, the block ends with at least this many literals.
const LAST_LITERALS: u64 = 5;

/// Reads an LZ4 length: the 4-bit `nibble`, extended by bytes of 255 and
/// one final byte below 255 when the nibble is 15.
fn length(src: &[u8], at: &mut usize, nibble: u8) -> Result<u64, DecompressFault> {
    let mut n = u64::from(nibble);
    if nibble == 15 {
        loop {
            let b = *src.get(*at).ok_or(DecompressFault::Corrupt)?;
            *at += 1;
            n += u64::from(b);
            if b != 255 {
                break;
            }
        }
    }
    Ok(n)
}

/// Checks one LZ4 block that must decode to `len` bytes, without decoding
/// it (it only walks the sequence headers).
pub(crate) fn check_lz4_block(src: &[u8], len: usize) -> Result<(), DecompressFault> {
    let len = len as u64;
    let mut at = 0usize;
    let mut out = 0u64;
    let mut last_match: Option<u64> = None;
    loop {
        let Some(&token) = src.get(at) else {
            // The block ended right after a match (or is empty).
            return Err(if last_match.is_some() {
                DecompressFault::EndOfBlock
            } else {
                DecompressFault::Corrupt
            });
        };
        at += 1;
        let literals = length(src, &mut at, token >> 4)?;
        let end = (at as u64)
            .checked_add(literals)
            .filter(|&e| e <= src.len() as u64)
            .ok_or(DecompressFault::Corrupt)?;
        at = end as usize;
        out += literals;
        if out > len {
            return Err(DecompressFault::Length);
        }
        if at == src.len() {
            // The last sequence: literals only.
            if out != len {
                return Err(DecompressFault::Length);
            }
            if let Some(start) = last_match
                && (start + MATCH_START_MARGIN > len || literals < LAST_LITERALS)
            {
                return Err(DecompressFault::EndOfBlock);
            }
            return Ok(());
        }
        let offset = match src.get(at..at + 2) {
            Some(b) => u64::from(u16::from_le_bytes([b[0], b[1]])),
            None => return Err(DecompressFault::Corrupt),
        };
        at += 2;
        if offset == 0 || offset > out {
            return Err(DecompressFault::Corrupt);
        }
        let matched = length(src, &mut at, token & 15)? + 4;
        last_match = Some(out);
        out += matched;
        if out > len {
            return Err(DecompressFault::Length);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_lz4_flex_writes_pass() {
        for n in [1usize, 4, 5, 12, 13, 64, 1000, 70_000] {
            let src: Vec<u8> = (0..n).map(|i| (i % 7) as u8).collect();
            let block = lz4_flex::block::compress(&src);
            assert_eq!(check_lz4_block(&block, n), Ok(()), "{n} bytes");
            assert_eq!(check_lz4_block(&block, n + 1), Err(DecompressFault::Length));
        }
    }

    #[test]
    fn end_of_block_rules_are_enforced() {
        // The case: one literal, a match of 4, then an empty last
        // sequence: 5 bytes of zeros, the last match 1 byte from the start.
        assert_eq!(
            check_lz4_block(&[0x10, 0x00, 0x01, 0x00, 0x00], 5),
            Err(DecompressFault::EndOfBlock)
        );
        // Ends right after a match.
        assert_eq!(
            check_lz4_block(&[0x10, 0x00, 0x01, 0x00], 5),
            Err(DecompressFault::EndOfBlock)
        );
        // 13 literals "a".."m", then a match of 4 starting at byte 13. With
        // 9 literals after it the block is 26 bytes and the match starts 13
        // before its end: fine. With 4 literals after it, the match starts
        // 8 bytes before the end and only 4 literals close the block.
        let mut ok = vec![0xD0];
        ok.extend(b"abcdefghijklm");
        ok.extend([0x0D, 0x00]); // offset 13, match 4
        let mut good = ok.clone();
        good.push(0x90);
        good.extend(b"nopqrstuv");
        assert_eq!(check_lz4_block(&good, 13 + 4 + 9), Ok(()));
        let mut short = ok;
        short.push(0x40);
        short.extend(b"nopq");
        assert_eq!(
            check_lz4_block(&short, 13 + 4 + 4),
            Err(DecompressFault::EndOfBlock)
        );
    }

    #[test]
    fn malformed_blocks_are_corrupt() {
        assert_eq!(check_lz4_block(&[], 1), Err(DecompressFault::Corrupt));
        // Literals run past the block.
        assert_eq!(
            check_lz4_block(&[0x30, 1, 2], 3),
            Err(DecompressFault::Corrupt)
        );
        // Offset 0, and an offset before the start.
        let zero = [0x50, 1, 2, 3, 4, 5, 0, 0, 0x50, 1, 2, 3, 4, 5];
        assert_eq!(check_lz4_block(&zero, 19), Err(DecompressFault::Corrupt));
        let far = [0x50, 1, 2, 3, 4, 5, 9, 0, 0x50, 1, 2, 3, 4, 5];
        assert_eq!(check_lz4_block(&far, 19), Err(DecompressFault::Corrupt));
        // A length extension cut off.
        assert_eq!(
            check_lz4_block(&[0xF0, 255], 300),
            Err(DecompressFault::Corrupt)
        );
    }
}

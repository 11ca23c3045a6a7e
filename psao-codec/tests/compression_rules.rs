//! Spec/wire-format.md 3.2's compression rules, where the libraries alone
//! would let a frame through: libzstd's one-pass decompression ignores the
//! window a frame asks for, and lz4_flex decodes blocks that break the LZ4
//! end-of-block rules. Each case shows the library accepting the bytes,
//! then the decoder refusing the frame with the fault the spec names.

use psao_codec::*;
use psao_tests::raw;

/// An instance and its transform: the payload ends in zero bytes that an
/// LZ4 match can copy.
fn messages() -> Vec<Vec<u8>> {
    vec![
        raw::define(1, &raw::DEF),
        raw::transform(1, 1, 3.0),
        raw::END.to_vec(),
    ]
}

fn payload() -> Vec<u8> {
    messages().concat()
}

fn frame_with(compression: u8, wire: Vec<u8>) -> Vec<u8> {
    let mut f = raw::key(1, messages());
    f.compression = compression;
    f.wire = Some(wire);
    f.bytes()
}

fn fault(frame: &[u8]) -> DecompressFault {
    match Decoder::new(Limits::default()).receive(frame) {
        Err(DecodeError::Decompress { fault, .. }) => fault,
        other => panic!("expected a decompress error, got {other:?}"),
    }
}

#[test]
fn a_window_above_2_pow_27_is_refused_though_libzstd_decodes_it() {
    let p = payload();
    let big = raw::zstd_raw_frame(0x89, &p);
    assert_eq!(zstd::bulk::decompress(&big, p.len()).unwrap(), p);
    assert_eq!(
        fault(&frame_with(2, big)),
        DecompressFault::Window {
            offset: 0,
            window: (1 << 27) + (1 << 24)
        }
    );
    // A skippable frame first moves the offset the error names.
    let mut later = raw::zstd_skippable(4);
    later.extend(raw::zstd_raw_frame(0x89, &p));
    assert!(matches!(
        fault(&frame_with(2, later)),
        DecompressFault::Window { offset: 12, .. }
    ));
}

#[test]
fn payloads_without_a_zstd_frame_are_refused() {
    assert_eq!(fault(&frame_with(2, Vec::new())), DecompressFault::NoFrame);
    assert_eq!(
        fault(&frame_with(2, raw::zstd_skippable(9))),
        DecompressFault::NoFrame
    );
}

#[test]
fn an_lz4_block_breaking_the_end_rules_is_refused_though_lz4_flex_decodes_it() {
    let p = payload();
    let block = raw::lz4_late_match(&p);
    assert_eq!(lz4_flex::block::decompress(&block, p.len()).unwrap(), p);
    assert_eq!(fault(&frame_with(1, block)), DecompressFault::EndOfBlock);
    // The same payload as lz4_flex writes it applies.
    let good = frame_with(1, lz4_flex::block::compress(&p));
    assert!(Decoder::new(Limits::default()).receive(&good).is_ok());
}

#[test]
fn corrupt_and_short_data_name_their_fault() {
    let p = payload();
    let mut z = zstd::bulk::compress(&p, 3).unwrap();
    let n = z.len();
    z[n / 2] ^= 0xFF;
    z[n - 1] ^= 0xFF;
    assert_eq!(fault(&frame_with(2, z)), DecompressFault::Corrupt);
    // A valid block that holds one byte less than announced.
    let short = lz4_flex::block::compress(&p[..p.len() - 1]);
    assert_eq!(fault(&frame_with(1, short)), DecompressFault::Length);
}

//! Writes the test vectors of `spec/vectors/`.
//!
//! Frames are assembled byte by byte from spec/wire-format.md (not with the
//! crate's encoder), decoded with `psao-codec`, and stored with the outcome
//! of every frame and the final mirror state. `tests/vectors.rs` replays
//! them, so the code and the committed vectors cannot drift apart silently.
//!
//! `cargo run -p psao-codec --example gen_vectors [-- OUT_DIR]`

use std::fmt::Write as _;
use std::path::PathBuf;

use glam::UVec3;
use psao_codec::{Decoder, InstanceDef, Limits};

use psao_tests::raw::*;

// ---- vectors ----

struct Vector {
    name: &'static str,
    about: &'static str,
    limits: Vec<(&'static str, u64)>,
    frames: Vec<Vec<u8>>,
    notes: Vec<String>,
}

fn v(name: &'static str, about: &'static str, frames: Vec<Vec<u8>>) -> Vector {
    Vector {
        name,
        about,
        limits: Vec::new(),
        frames,
        notes: Vec::new(),
    }
}

fn with_limit(mut vector: Vector, name: &'static str, value: u64) -> Vector {
    vector.limits.push((name, value));
    vector
}

/// Keyframe 5 of instance 1 holding one point in cell (1,0,0): key 1,
/// bucket 1, cell 0.
fn base_keyframe() -> Frame {
    let mut f = key(
        5,
        vec![
            define(1, &DEF),
            transform(1, 1, 3.0),
            buckets(1, &[(1, &[(1, 0)])]),
            cells_full(1, &[(0, &[W1])]),
            END.to_vec(),
        ],
    );
    f.checksum = true;
    f
}

/// Keyframe 5: instance 1 (defined by `first`) as in vector 02's, and an
/// empty instance 2 of `DEF`.
fn two_instances(first: &InstanceDef) -> Frame {
    key(
        5,
        vec![
            define(1, first),
            transform(1, 1, 3.0),
            buckets(1, &[(1, &[(1, 0)])]),
            cells_full(1, &[(0, &[W1])]),
            define(2, &DEF),
            END.to_vec(),
        ],
    )
}

const W1: u32 = 0x8C21_77C8; // pos (1,1,3), normal 0x77 (+Z), ao 200
const W2: u32 = 0x8000_7440; // pos (0,0,0), normal 0x74, ao 64

fn annotate_base(bytes: &[u8]) -> Vec<String> {
    let fields: &[(usize, &str)] = &[
        (4, "magic \"PSAO\""),
        (1, "version 1"),
        (1, "flags 0x03: KEYFRAME | CHECKSUM"),
        (1, "compression 0 (none)"),
        (1, "reserved"),
        (4, "sequence 5"),
        (4, "base_sequence 5 (= sequence in a keyframe)"),
        (4, "message_count 5"),
        (4, "uncompressed_len"),
        (4, "compressed_len (= uncompressed_len)"),
        (4, "checksum: CRC-32 of bytes 0..28 and the payload"),
        (1, "DefineInstance 0x01"),
        (4, "  instance 1"),
        (12, "  origin 0 0 0"),
        (12, "  cell_size 0.5 0.5 0.5"),
        (12, "  dims 4 4 4"),
        (
            4,
            "  table_log2 3, bucket_capacity 4, cell_capacity 4, point_format 0",
        ),
        (4, "  cell_pool 16"),
        (12, "  radius 0.25, t_n 0.1, t_d 0.7"),
        (1, "Transform 0x03"),
        (4, "  instance 1"),
        (4, "  transform_sequence 1"),
        (48, "  matrix: identity, translation (3, 2, 0)"),
        (1, "Buckets 0x04"),
        (4, "  instance 1"),
        (4, "  count 1"),
        (1, "  bucket index list: 1"),
        (1, "  entries: 1"),
        (
            4,
            "  keys, planar: key 1 = cell (1,0,0): 1 + 0*4*17 + 0*4*4*31",
        ),
        (4, "  cells, planar: cell 0"),
        (1, "CellsFull 0x05"),
        (4, "  instance 1"),
        (4, "  count 1"),
        (1, "  cell index list: 0"),
        (1, "  points: 1"),
        (
            4,
            "  words, planar: 0x8c2177c8 = A, pos (1,1,3), normal 0x77 (+Z), ao 200",
        ),
        (1, "EndOfFrame 0x00"),
    ];
    let mut out = Vec::new();
    let mut at = 0;
    for &(n, what) in fields {
        let hex: String = bytes[at..at + n]
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        out.push(format!("{at:4} {hex:<24} {what}"));
        at += n;
    }
    assert_eq!(at, bytes.len(), "annotation covers the frame");
    out
}

fn vectors() -> Vec<Vector> {
    let kf = base_keyframe();
    let kfb = kf.bytes();
    let mut list = Vec::new();

    list.push(v(
        "01-keyframe-empty",
        "A keyframe with no instance: just EndOfFrame.",
        vec![key(0, vec![END.to_vec()]).bytes()],
    ));
    let mut two = v(
        "02-keyframe-one-point",
        "Keyframe 5: instance 1, its transform, one bucket and one cell holding one point. Annotated below.",
        vec![kfb.clone()],
    );
    two.notes = annotate_base(&kfb);
    list.push(two);
    list.push(v(
        "03-delta-xor-ao-free",
        "Deltas 6-8: a second point by XOR, AO deltas (+10, -5 mod 256), then the cell freed and its bucket emptied.",
        vec![
            kfb.clone(),
            delta(6, 5, vec![cells_xor(1, &[(0, 0b10, &[W2])]), END.to_vec()]).bytes(),
            delta(7, 6, vec![cells_ao(1, &[(0, 0b11, &[10, 251])]), END.to_vec()]).bytes(),
            delta(8, 7, vec![free(1, &[0]), buckets(1, &[(1, &[])]), END.to_vec()]).bytes(),
        ],
    ));
    let mut lz = kf.clone();
    lz.compression = 1;
    list.push(v(
        "04-keyframe-lz4",
        "The keyframe of 02 with an LZ4 block payload.",
        vec![lz.bytes()],
    ));
    let mut zs = kf.clone();
    zs.compression = 2;
    list.push(v(
        "05-keyframe-zstd",
        "The keyframe of 02 with a zstd payload.",
        vec![zs.bytes()],
    ));
    let d6 = delta(6, 5, vec![cells_ao(1, &[(0, 1, &[1])]), END.to_vec()]).bytes();
    list.push(v(
        "06-stale-duplicate",
        "Delta 6 twice (the second is stale), then keyframe 5 again (stale: the mirror is at 6).",
        vec![kfb.clone(), d6.clone(), d6.clone(), kfb.clone()],
    ));
    list.push(v(
        "07-gap-need-keyframe",
        "A delta before any keyframe, then keyframe 5, then delta 7 based on 6 (6 was lost): need keyframe, state unchanged.",
        vec![
            d6.clone(),
            kfb.clone(),
            delta(7, 6, vec![cells_ao(1, &[(0, 1, &[1])]), END.to_vec()]).bytes(),
        ],
    ));
    let mut wrap = kf.clone();
    wrap.seq = u32::MAX;
    wrap.base = u32::MAX;
    list.push(v(
        "08-wraparound",
        "Keyframe at 2^32-1, then delta 0 based on 2^32-1: sequences wrap.",
        vec![
            wrap.bytes(),
            delta(
                0,
                u32::MAX,
                vec![cells_ao(1, &[(0, 1, &[7])]), END.to_vec()],
            )
            .bytes(),
        ],
    ));
    list.push(v(
        "09-transform-order",
        "Transform sequence 1 stored; a late transform 0 in delta 6 is ignored; transform 2 in delta 7 replaces it.",
        vec![
            kfb.clone(),
            delta(6, 5, vec![transform(1, 0, 9.0), END.to_vec()]).bytes(),
            delta(7, 6, vec![transform(1, 2, 4.0), END.to_vec()]).bytes(),
        ],
    ));
    list.push(v(
        "10-redefine-and-remove",
        "Keyframe with instances 1 and 2; a delta redefines 1 (which clears it) and removes 2.",
        vec![
            two_instances(&DEF).bytes(),
            delta(6, 5, vec![define(1, &DEF), remove(2), END.to_vec()]).bytes(),
        ],
    ));
    list.push(v(
        "11-coalesced-delta",
        "A delta from 5 straight to 9 (a server coalescing four deltas for a slow client).",
        vec![
            kfb.clone(),
            delta(9, 5, vec![cells_ao(1, &[(0, 1, &[2])]), END.to_vec()]).bytes(),
        ],
    ));
    list.push(v(
        "12-atomic-rollback",
        "Delta 6 sets transform 2 and adds a point, then breaks compaction in its third message: nothing of it applies.",
        vec![
            kfb.clone(),
            delta(
                6,
                5,
                vec![
                    transform(1, 2, 8.0),
                    cells_xor(1, &[(0, 0b10, &[W2])]),
                    cells_xor(1, &[(0, 0b1000, &[W2])]),
                    END.to_vec(),
                ],
            )
            .bytes(),
        ],
    ));

    // ---- one vector per error class ----
    let bad = |f: &dyn Fn(&mut Vec<u8>)| {
        let mut b = kfb.clone();
        f(&mut b);
        b
    };
    let after_kf = |name, about, messages: Vec<Vec<u8>>| {
        let mut m = messages;
        m.push(END.to_vec());
        v(name, about, vec![kfb.clone(), delta(6, 5, m).bytes()])
    };
    list.push(v(
        "13-truncated",
        "The keyframe of 02 cut to 20 bytes.",
        vec![kfb[..20].to_vec()],
    ));
    list.push(v(
        "14-trailing-bytes",
        "The keyframe of 02 with one extra byte.",
        vec![bad(&|b| b.push(0))],
    ));
    list.push(v(
        "15-bad-magic",
        "Magic \"PSAP\".",
        vec![bad(&|b| b[3] = b'P')],
    ));
    list.push(v(
        "16-unsupported-version",
        "Version 2.",
        vec![bad(&|b| b[4] = 2)],
    ));
    list.push(v(
        "17-header-field",
        "Reserved flag bit 2 set.",
        vec![bad(&|b| b[5] |= 4)],
    ));
    list.push(v(
        "18-unknown-compression",
        "Compression id 3.",
        vec![bad(&|b| b[6] = 3)],
    ));
    list.push(with_limit(
        v(
            "19-frame-too-large",
            "A receiver limited to 40-byte frames.",
            vec![kfb.clone()],
        ),
        "max_frame_bytes",
        40,
    ));
    list.push(with_limit(
        v(
            "20-payload-too-large",
            "A receiver limited to 4-byte payloads.",
            vec![kfb.clone()],
        ),
        "max_payload_bytes",
        4,
    ));
    list.push(with_limit(
        v(
            "21-too-many-messages",
            "A receiver limited to 2 messages per frame.",
            vec![kfb.clone()],
        ),
        "max_messages",
        2,
    ));
    list.push(v(
        "22-checksum",
        "One payload byte flipped under a checksum.",
        vec![bad(&|b| *b.last_mut().expect("payload") ^= 0x40)],
    ));
    let mut z = kf.clone();
    z.compression = 2;
    let mut zb = z.bytes();
    let n = zb.len();
    zb[n - 6] ^= 0xFF;
    zb[28..32].fill(0);
    zb[5] &= !2;
    list.push(v(
        "23-decompress",
        "A zstd payload with corrupted bytes (no checksum).",
        vec![zb],
    ));
    list.push(after_kf(
        "24-unknown-message-type",
        "Message type 0x09.",
        vec![vec![0x09]],
    ));
    let mut short = delta(6, 5, vec![define(3, &DEF)[..30].to_vec()]);
    short.count = Some(1);
    list.push(v(
        "25-message-truncated",
        "A DefineInstance cut after 30 bytes.",
        vec![kfb.clone(), short.bytes()],
    ));
    let mut missing = delta(6, 5, vec![cells_ao(1, &[(0, 1, &[1])])]);
    missing.count = Some(1);
    list.push(v(
        "26-missing-end",
        "A payload whose only message is not EndOfFrame.",
        vec![kfb.clone(), missing.bytes()],
    ));
    let mut after = delta(6, 5, vec![END.to_vec(), END.to_vec()]);
    after.count = Some(1);
    list.push(v(
        "27-after-end",
        "Bytes after EndOfFrame.",
        vec![kfb.clone(), after.bytes()],
    ));
    let mut nonmin = vec![0x08];
    u32le(&mut nonmin, 1);
    u32le(&mut nonmin, 1);
    nonmin.extend_from_slice(&[0x80, 0x00]);
    list.push(after_kf(
        "28-varint",
        "A non-minimal varint (0x80 0x00) in CellsFree.",
        vec![nonmin],
    ));
    let mut overflow = vec![0x08];
    u32le(&mut overflow, 1);
    u32le(&mut overflow, 2);
    varint(&mut overflow, u32::MAX);
    varint(&mut overflow, 0);
    list.push(after_kf(
        "29-index-overflow",
        "An index list 2^32-1 then one more.",
        vec![overflow],
    ));
    list.push(after_kf(
        "30-zero-mask",
        "A CellsAo mask of 0.",
        vec![cells_ao(1, &[(0, 0, &[])])],
    ));
    let mut big = vec![0x04];
    u32le(&mut big, 1);
    u32le(&mut big, 1);
    big.extend_from_slice(&[1, 17]);
    big.extend(std::iter::repeat_n(0u8, 17 * 8));
    list.push(after_kf(
        "31-count-too-large",
        "A bucket listing 17 entries.",
        vec![big],
    ));
    list.push(after_kf(
        "32-invalid-definition",
        "Dims 0 x 4 x 4.",
        vec![define(
            3,
            &InstanceDef {
                dims: UVec3::new(0, 4, 4),
                ..DEF
            },
        )],
    ));
    let mut nan = transform(1, 2, 0.0);
    nan[9..13].copy_from_slice(&f32::NAN.to_le_bytes());
    list.push(after_kf(
        "33-non-finite-transform",
        "A NaN in a transform.",
        vec![nan],
    ));
    list.push(after_kf(
        "34-unknown-instance",
        "An AO delta for instance 9.",
        vec![cells_ao(9, &[(0, 1, &[1])])],
    ));
    list.push(with_limit(
        v(
            "35-instance-limit",
            "A receiver holding 1 instance gets a keyframe defining 2.",
            vec![key(1, vec![define(1, &DEF), define(2, &DEF), END.to_vec()]).bytes()],
        ),
        "max_instances",
        1,
    ));
    list.push(with_limit(
        v(
            "36-resource-limit",
            "A receiver with 100 bytes of mirror memory.",
            vec![kfb.clone()],
        ),
        "max_mirror_bytes",
        100,
    ));
    list.push(after_kf(
        "37-bucket-index",
        "Bucket 8 of an 8-bucket table.",
        vec![buckets(1, &[(8, &[])])],
    ));
    list.push(after_kf(
        "38-bucket-over-capacity",
        "Five entries in a bucket of 4.",
        vec![buckets(
            1,
            &[(1, &[(1, 0), (9, 1), (17 * 4 + 1, 2), (33, 3), (41, 4)])],
        )],
    ));
    list.push(after_kf(
        "39-key-not-in-grid",
        "Key 17 names no cell of a 4x4x4 grid (17 div 4 = 4 is not a multiple of 17).",
        vec![buckets(1, &[(1, &[(17, 0)])])],
    ));
    list.push(after_kf(
        "40-key-wrong-bucket",
        "Key 1 listed in bucket 2.",
        vec![buckets(1, &[(2, &[(1, 0)])])],
    ));
    list.push(after_kf(
        "41-duplicate-key",
        "Key 1 twice in bucket 1.",
        vec![buckets(1, &[(1, &[(1, 0), (1, 1)])])],
    ));
    list.push(after_kf(
        "42-cell-index",
        "Cell 16 of a 16-cell pool.",
        vec![free(1, &[16])],
    ));
    list.push(after_kf(
        "43-slot-beyond-capacity",
        "XOR mask bit 4 with 4 slots per cell.",
        vec![cells_xor(1, &[(0, 0b1_0000, &[W2])])],
    ));
    list.push(after_kf(
        "44-invalid-word",
        "CellsFull with a normal code u = 15.",
        vec![cells_full(1, &[(1, &[word([0, 0, 0], 0x77, 1) | 0x0F00])])],
    ));
    list.push(after_kf(
        "45-compaction",
        "XOR puts a point in slot 2 while slot 1 is empty.",
        vec![cells_xor(1, &[(0, 0b100, &[W2])])],
    ));
    list.push(after_kf(
        "46-ao-to-empty-slot",
        "AO delta for empty slot 1.",
        vec![cells_ao(1, &[(0, 0b10, &[1])])],
    ));
    let (w3, w4, w5, w6) = (
        word([5, 9, 17], 0x3a, 17),
        word([31, 0, 30], 0xe0, 255),
        word([12, 24, 6], 0x0e, 0),
        word([2, 27, 11], 0x5c, 99),
    );
    list.push(v(
        "47-keyframe-planar",
        "Planar arrays of several values: bucket 1 holds keys 1 (cell (1,0,0)) and 993 (cell (1,0,2)), bucket 6 key 70 (cell (2,1,0)); cells of 2, 1 and 3 points.",
        vec![key(
            3,
            vec![
                define(1, &DEF),
                buckets(1, &[(1, &[(1, 0), (993, 1)]), (6, &[(70, 2)])]),
                cells_full(1, &[(0, &[W1, W2]), (1, &[w3]), (2, &[w4, w5, w6])]),
                END.to_vec(),
            ],
        )
        .bytes()],
    ));
    // DEF's mirror is 8*8*4 + 4*16*4 = 512 bytes. Freeing a cell costs
    // 32 + 4*4 = 48 of the rewrite budget: 10 fit 512, 11 do not.
    assert_eq!(DEF.mirror_bytes(), 512);
    list.push(with_limit(
        v(
            "48-rewrite-budget",
            "max_mirror_bytes 512: a delta freeing 10 cells spends 480 of the rewrite budget and applies; freeing 11 spends 528 and fails.",
            vec![
                kfb.clone(),
                delta(6, 5, vec![free(1, &(0..10).collect::<Vec<_>>()), END.to_vec()]).bytes(),
                delta(7, 6, vec![free(1, &(0..11).collect::<Vec<_>>()), END.to_vec()]).bytes(),
            ],
        ),
        "max_mirror_bytes",
        512,
    ));
    list.push(with_limit(
        v(
            "49-allocation-budget",
            "max_mirror_bytes 1000: one redefinition spends 512 of the allocation budget and applies; two in one delta spend 1024 and fail at the second.",
            vec![
                kfb.clone(),
                delta(6, 5, vec![define(1, &DEF), END.to_vec()]).bytes(),
                delta(7, 6, vec![define(1, &DEF), define(1, &DEF), END.to_vec()]).bytes(),
            ],
        ),
        "max_mirror_bytes",
        1000,
    ));
    let bind = InstanceDef {
        point_format: 1,
        overflow: false,
        ..DEF
    };
    list.push(v(
        "50-point-format-bind",
        "Point format 1 (bind space, section 6.1): instance 1 of vector 02 defined as a deforming mesh's bind-space grid, and instance 2 of format 0 beside it, in one keyframe; the words apply as format 0's, and the state reports each instance's format.",
        vec![
            two_instances(&bind).bytes(),
        ],
    ));
    list.push(after_kf(
        "51-point-format-unknown",
        "Point format 2 is unknown.",
        vec![define(
            3,
            &InstanceDef {
                point_format: 2,
                overflow: false,
                ..DEF
            },
        )],
    ));
    // Overflow chains (section 7.4): DEF with OVERFLOW (byte 44 = 0x80).
    // Dx = 4, so link j of cell (1,0,0) (key 1) has key 1 + 4j, in bucket
    // (1 + j * 0x9E3779B9) mod 8: link 1 in bucket 2.
    assert_eq!(1u32.wrapping_add(0x9E37_79B9) & 7, 2);
    let chained = InstanceDef {
        overflow: true,
        ..DEF
    };
    let (w7, w8) = (word([8, 20, 3], 0x10, 33), word([30, 2, 16], 0x77, 180));
    let chain_kf = key(
        5,
        vec![
            define(1, &chained),
            buckets(1, &[(1, &[(1, 0)]), (2, &[(5, 1)])]),
            cells_full(1, &[(0, &[W1, W2, w3, w4]), (1, &[w7, w8])]),
            END.to_vec(),
        ],
    )
    .bytes();
    list.push(v(
        "52-overflow-chain",
        "OVERFLOW: cell (1,0,0) (key 1, bucket 1) is full in pool cell 0 and goes on in its link 1 (key 1 + 1*Dx = 5, in bucket (1 + 0x9E3779B9) mod 8 = 2), pool cell 1, with two more points: six points in a cell of 4 slots. Then a delta moves the chain's last point into slot 1 of link 0, as an encoder does when a point leaves, and the cell holds five.",
        vec![
            chain_kf.clone(),
            delta(
                6,
                5,
                vec![
                    cells_xor(1, &[(0, 0b10, &[W2 ^ w8]), (1, 0b10, &[w8])]),
                    END.to_vec(),
                ],
            )
            .bytes(),
        ],
    ));
    list.push(v(
        "53-overflow-key-beyond-links",
        "OVERFLOW: key 276 = 0 + 4*69 (r' = 69, y = 69 div 17 = 4 = Dy, j = 69 mod 17 = 1) is no link of any cell of the 4x4x4 grid.",
        vec![
            chain_kf,
            delta(6, 5, vec![buckets(1, &[(4, &[(276, 2)])]), END.to_vec()]).bytes(),
        ],
    ));
    list.push(v(
        "55-overflow-link-wrong-bucket",
        "OVERFLOW: link key 5 filed in bucket 5 (its own key mod T) instead of bucket 2 (section 7.4).",
        vec![
            key(
                5,
                vec![
                    define(1, &chained),
                    buckets(1, &[(1, &[(1, 0)]), (5, &[(5, 1)])]),
                    END.to_vec(),
                ],
            )
            .bytes(),
        ],
    ));
    list.push(after_kf(
        "54-overflow-key-without-flag",
        "Without OVERFLOW, key 5 (link 1 of cell (1,0,0) in a chained grid) names no cell.",
        vec![buckets(1, &[(5, &[(5, 1)])])],
    ));
    // Section 3.2's compression rules, one vector per choice the spec makes.
    let payload: Vec<u8> = kf.messages.concat();
    let with_wire = |compression: u8, wire: Vec<u8>| {
        let mut f = base_keyframe();
        f.compression = compression;
        f.wire = Some(wire);
        f.bytes()
    };
    list.push(v(
        "56-zstd-empty",
        "A keyframe with compression 2, uncompressed_len 0 and no payload byte: zstd data is one or more zstd frames, so zero bytes are `decompress` (not `missing_end`, which the same frame uncompressed gives).",
        vec![{
            let mut f = key(1, Vec::new());
            f.count = Some(1);
            f.compression = 2;
            f.wire = Some(Vec::new());
            f.bytes()
        }],
    ));
    list.push(v(
        "57-zstd-window-too-large",
        "The keyframe of 02 as one zstd frame written by hand (RFC 8878: no content size, one raw block) whose Window_Descriptor 0x89 asks for 2^27 + 2^24 bytes: above 2^27, so `decompress`.",
        vec![with_wire(2, zstd_raw_frame(0x89, &payload))],
    ));
    list.push(v(
        "58-zstd-window-at-limit",
        "The same frame with Window_Descriptor 0x88 (exactly 2^27): accepted.",
        vec![with_wire(2, zstd_raw_frame(0x88, &payload))],
    ));
    list.push(v(
        "59-zstd-skippable-only",
        "A zstd payload made only of a skippable frame (magic 0x184D2A53, 4 user bytes): it holds no zstd frame, so `decompress`.",
        vec![with_wire(2, zstd_skippable(4))],
    ));
    let mut skip_then = zstd_skippable(4);
    skip_then.extend(zstd_raw_frame(0x50, &payload));
    list.push(v(
        "60-zstd-skippable-then-frame",
        "A skippable frame, then the keyframe of 02 as a hand-written zstd frame (window 2^20): the skippable frame is ignored, the frame applies.",
        vec![with_wire(2, skip_then)],
    ));
    let (head, tail) = payload.split_at(payload.len() / 2);
    let mut two = zstd_raw_frame(0x50, head);
    two.extend(zstd_raw_frame(0x50, tail));
    list.push(v(
        "61-zstd-two-frames",
        "The keyframe of 02's payload split over two zstd frames: decompressed one after the other, it applies.",
        vec![with_wire(2, two)],
    ));
    list.push(v(
        "62-lz4-end-of-block",
        "The keyframe of 02 as an LZ4 block whose one match starts fewer than 12 bytes before the end: it decodes to the right bytes, but breaks the end-of-block rules, so `decompress` (section 3.2: MUST reject).",
        vec![with_wire(1, lz4_late_match(&payload))],
    ));
    // A raw block not marked last, then a last Compressed_Block of
    // Block_Size 0 (block header 0x000005).
    let mut empty_last = zstd_raw_frame(0x50, &payload);
    empty_last[6] &= !1;
    empty_last.extend([0x05, 0x00, 0x00]);
    list.push(v(
        "63-zstd-empty-compressed-block",
        "The keyframe of 02 in one zstd frame (window 2^20, no content size) as a raw block, then a last block of type Compressed_Block and Block_Size 0. A compressed block holds at least a Literals_Section_Header and a Sequences_Section_Header (RFC 8878 3.1.1.3), so the frame is invalid: `decompress`, although libzstd's streaming decoder takes the empty block as an empty block and yields the keyframe.",
        vec![with_wire(2, empty_last)],
    ));
    // The keyframe of 02 padded with zeros to 2,000 bytes, one raw block
    // in a frame whose window is 1 KiB (descriptor 0x00).
    let mut padded = payload.clone();
    padded.resize(2000, 0);
    list.push(v(
        "64-zstd-block-above-maximum",
        "The keyframe of 02 padded with zero bytes to 2,000, as one raw block of a zstd frame whose Window_Descriptor 0x00 gives a 1 KiB window: a block holds at most Block_Maximum_Size, the smaller of Window_Size and 128 KiB (RFC 8878 3.1.1.2.4), so `decompress` (libzstd's one-pass decoder lets such a raw block through; its streaming decoder rejects it).",
        vec![{
            let mut f = base_keyframe();
            f.count = Some(f.messages.len() as u32);
            f.messages = vec![padded.clone()];
            f.compression = 2;
            f.wire = Some(zstd_raw_frame(0x00, &padded));
            f.bytes()
        }],
    ));
    assert_eq!(W1, word([1, 1, 3], 0x77, 200));
    assert_eq!(W2, word([0, 0, 0], 0x74, 64));
    list
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

fn main() {
    let dir: PathBuf = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../spec/vectors"));
    std::fs::create_dir_all(&dir).expect("create vector dir");
    for vector in vectors() {
        let mut limits = Limits::default();
        let mut text = String::new();
        writeln!(text, "# {}", vector.name).ok();
        writeln!(text, "# {}", vector.about).ok();
        for line in &vector.notes {
            writeln!(text, "#   {line}").ok();
        }
        for (name, value) in &vector.limits {
            assert!(limits.set(name, *value), "unknown limit {name}");
            writeln!(text, "limit {name} {value}").ok();
        }
        let mut decoder = Decoder::new(limits);
        for frame in &vector.frames {
            writeln!(text, "frame {}", hex(frame)).ok();
            let expect = outcome(&decoder.receive(frame));
            writeln!(text, "expect {expect}").ok();
        }
        match decoder.mirror().digest() {
            Some(d) => writeln!(text, "digest {d:08x}").ok(),
            None => writeln!(text, "digest none").ok(),
        };
        writeln!(text, "state").ok();
        text.push_str(&decoder.mirror().describe());
        std::fs::write(dir.join(format!("{}.txt", vector.name)), text).expect("write vector");
    }
    println!("wrote vectors to {}", dir.display());
}

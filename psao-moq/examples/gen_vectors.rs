//! Writes the MoQ subscriber vectors of `spec/vectors/moq/` (spec/moq.md).
//!
//! Each vector is a sequence of what a subscriber receives, in order: the
//! catalog, `frames` frames with their group id and index, `digest` track
//! frames. Frames are assembled byte by byte (psao_tests::raw, from
//! spec/wire-format.md), the outcomes come from psao-moq's `Follower`, and
//! `tests/vectors.rs` replays every file, so the code and the committed
//! vectors cannot drift apart silently.
//!
//! `cargo run -p psao-moq --example gen_vectors [-- OUT_DIR]`

use std::fmt::Write as _;
use std::path::PathBuf;

use psao_codec::Limits;
use psao_moq::catalog::{encode_catalog, encode_digest};
use psao_moq::{DigestCheck, Followed, Follower};
use psao_proto::control::Welcome;
use psao_tests::raw::{DEF, END, buckets, cells_ao, cells_full, define, delta, key, transform};

/// One word: position (1,1,3), normal +Z, AO 200.
const W1: u32 = 0x8C21_77C8;

/// A keyframe at `seq`: instance 1 with one point, whose AO is 200 at 5
/// and one more at each later sequence, as the deltas of [`step`] leave it
/// (a group's keyframe holds the state its publisher reached).
fn keyframe(seq: u32) -> Vec<u8> {
    keyframe_compressed(seq, 0)
}

/// [`keyframe`] with the payload compressed as `compression` says.
fn keyframe_compressed(seq: u32, compression: u8) -> Vec<u8> {
    let word = (W1 & !0xff) | (200 + seq - 5);
    let mut f = key(
        seq,
        vec![
            define(1, &DEF),
            transform(1, 1, 3.0),
            buckets(1, &[(1, &[(1, 0)])]),
            cells_full(1, &[(0, &[word])]),
            END.to_vec(),
        ],
    );
    f.checksum = true;
    f.compression = compression;
    f.bytes()
}

/// A delta from `seq - 1` to `seq`: the point's AO up by 1.
fn step(seq: u32) -> Vec<u8> {
    delta(
        seq,
        seq - 1,
        vec![cells_ao(1, &[(0, 0b1, &[1])]), END.to_vec()],
    )
    .bytes()
}

fn catalog(max_frame_bytes: u32) -> Vec<u8> {
    encode_catalog(&Welcome {
        version: 1,
        compression: 0,
        point_format: 0,
        max_frame_bytes,
        max_payload_bytes: max_frame_bytes,
        frame_rate: 60,
        culling: false,
        overflow: false,
        digest: true,
        scene: "vectors".into(),
    })
    .to_vec()
}

/// What a vector feeds a subscriber.
enum In {
    Catalog(Vec<u8>),
    Frame(u64, u64, Vec<u8>),
    /// A digest of `(sequence, digest)`, or `None` for the digest the
    /// mirror holds at that point (`Some(wrong)` to make a wrong one).
    Digest(u32, Option<u32>),
}

struct Vector {
    name: &'static str,
    about: &'static str,
    limits: Vec<(&'static str, u64)>,
    input: Vec<In>,
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// The digest a follower of this input holds once its mirror is at `seq`
/// (replaying the frames up to there).
fn digest_at(input: &[In], upto: usize, seq: u32) -> u32 {
    let mut f = Follower::new(Limits::default());
    for i in &input[..upto] {
        match i {
            In::Catalog(c) => {
                let _ = f.on_catalog(c);
            }
            In::Frame(g, k, b) => {
                f.on_frame(*g, *k, b);
                if f.mirror().sequence() == Some(seq) {
                    return f.mirror().digest().expect("a state");
                }
            }
            In::Digest(..) => {}
        }
    }
    f.mirror().digest().unwrap_or(0)
}

fn write(v: &Vector) -> String {
    let mut out = format!("# {}\n# {}\n", v.name, v.about);
    let mut limits = Limits::default();
    for (n, val) in &v.limits {
        assert!(limits.set(n, *val));
        writeln!(out, "limit {n} {val}").unwrap();
    }
    let mut f = Follower::new(limits);
    for (at, i) in v.input.iter().enumerate() {
        match i {
            In::Catalog(c) => {
                writeln!(out, "catalog {}", hex(c)).unwrap();
                match f.on_catalog(c) {
                    Ok(_) => writeln!(out, "expect catalog ok").unwrap(),
                    Err(psao_moq::FollowError::AboveLimits { what, .. }) => writeln!(
                        out,
                        "expect catalog above_limits {}",
                        what.split(' ').next().unwrap()
                    )
                    .unwrap(),
                    Err(_) => writeln!(out, "expect catalog error").unwrap(),
                }
            }
            In::Frame(g, k, b) => {
                writeln!(out, "frame {g} {k} {}", hex(b)).unwrap();
                let e = match f.on_frame(*g, *k, b) {
                    Followed::Applied { sequence, keyframe } => format!(
                        "applied {sequence} {}",
                        if keyframe { "keyframe" } else { "delta" }
                    ),
                    Followed::Ignored => "ignored".into(),
                    Followed::WaitKeyframe => "wait_keyframe".into(),
                    Followed::Failed(_) => "failed".into(),
                };
                writeln!(out, "expect {e}").unwrap();
            }
            In::Digest(seq, wrong) => {
                let d = match wrong {
                    Some(w) => *w,
                    None => digest_at(&v.input, v.input.len(), *seq),
                };
                let _ = at;
                let body = encode_digest(*seq, d);
                writeln!(out, "digest {}", hex(&body)).unwrap();
                let e = match f.on_digest(&body) {
                    Ok(DigestCheck::Match) => "match",
                    Ok(DigestCheck::Mismatch) => "mismatch",
                    Ok(DigestCheck::Held) => "held",
                    Ok(DigestCheck::Passed) => "passed",
                    Err(psao_moq::FollowError::BeforeCatalog(_)) => "ignored",
                    Err(_) => "error",
                };
                writeln!(out, "expect digest {e}").unwrap();
            }
        }
        writeln!(out, "in_sync {}", if f.in_sync() { "yes" } else { "no" }).unwrap();
    }
    if let Some(e) = f.gave_up() {
        writeln!(
            out,
            "gave_up {}",
            match e {
                psao_moq::FollowError::Undecodable { groups, .. } => groups,
                _ => 0,
            }
        )
        .unwrap();
    }
    let s = f.stats();
    writeln!(
        out,
        "end sequence {} digest {} matched {} mismatched {}",
        f.mirror()
            .sequence()
            .map_or("none".into(), |q| q.to_string()),
        f.mirror()
            .digest()
            .map_or("none".into(), |d| format!("{d:08x}")),
        s.digests_matched,
        s.digest_mismatches
    )
    .unwrap();
    out
}

fn vectors() -> Vec<Vector> {
    use In::*;
    let cat = || Catalog(catalog(1 << 20));
    vec![
        Vector {
            name: "01-groups-in-order",
            about: "Group 0 opens with keyframe 5 and goes on with deltas 6 and 7; group 1 opens with keyframe 7 (the state the mirror holds, as a group rolled over in a still moment: it applies all the same); a digest of 7 matches.",
            limits: vec![],
            input: vec![
                cat(),
                Frame(0, 0, keyframe(5)),
                Frame(0, 1, step(6)),
                Frame(0, 2, step(7)),
                Frame(1, 0, keyframe(7)),
                Digest(7, None),
                Frame(1, 1, step(8)),
            ],
        },
        Vector {
            name: "02-join-mid-group",
            about: "Joining at frame 1 of group 0: its frames are ignored until group 1's keyframe, then the group is followed.",
            limits: vec![],
            input: vec![
                cat(),
                Frame(0, 1, step(6)),
                Frame(0, 2, step(7)),
                Frame(1, 0, keyframe(7)),
                Frame(1, 1, step(8)),
            ],
        },
        Vector {
            name: "03-lost-frame",
            about: "Delta 6 of group 0 is lost: delta 7 waits for a keyframe and the rest of the group is ignored; group 1's keyframe repairs the mirror.",
            limits: vec![],
            input: vec![
                cat(),
                Frame(0, 0, keyframe(5)),
                Frame(0, 2, step(7)),
                Frame(0, 3, step(8)),
                Frame(1, 0, keyframe(8)),
                Frame(1, 1, step(9)),
            ],
        },
        Vector {
            name: "04-lost-and-late-groups",
            about: "Group 1 is lost (group 2 arrives next, counted as one missed); group 1 arriving late is older than the newest group seen and is ignored.",
            limits: vec![],
            input: vec![
                cat(),
                Frame(0, 0, keyframe(5)),
                Frame(0, 1, step(6)),
                Frame(2, 0, keyframe(9)),
                Frame(1, 0, keyframe(7)),
                Frame(1, 1, step(8)),
                Frame(2, 1, step(10)),
            ],
        },
        Vector {
            name: "05-digests",
            about: "A digest of 7 arrives before its frame and is held until the mirror reaches 7; one of 6 (passed) is dropped; a wrong one of 7 puts the mirror out of sync until group 1's keyframe.",
            limits: vec![],
            input: vec![
                cat(),
                Digest(7, None),
                Frame(0, 0, keyframe(5)),
                Frame(0, 1, step(6)),
                Frame(0, 2, step(7)),
                Digest(6, None),
                Digest(7, Some(0x1234_5678)),
                Frame(1, 0, keyframe(7)),
            ],
        },
        Vector {
            name: "06-catalog-above-limits",
            about: "A subscriber that accepts frames of at most 65536 bytes cannot follow a broadcast whose catalog says 1 MiB.",
            limits: vec![("max_frame_bytes", 65_536)],
            input: vec![cat()],
        },
        Vector {
            name: "07-before-the-catalog",
            about: "A frame and a digest before the catalog are ignored; the catalog then lets the next group's keyframe apply.",
            limits: vec![],
            input: vec![
                Frame(0, 0, keyframe(5)),
                Digest(5, Some(0)),
                cat(),
                Frame(1, 0, keyframe(6)),
            ],
        },
        Vector {
            name: "08-corrupt-keyframe",
            about: "Group 0's keyframe fails to decode (a flipped payload byte breaks its checksum): the group is ignored; group 1's keyframe applies.",
            limits: vec![],
            input: vec![
                cat(),
                Frame(0, 0, {
                    let mut k = keyframe(5);
                    let n = k.len();
                    k[n - 2] ^= 0xff;
                    k
                }),
                Frame(0, 1, step(6)),
                Frame(1, 0, keyframe(6)),
            ],
        },
        Vector {
            name: "09-keyframes-fail-again",
            about: "The keyframes of two groups in a row fail to decode (payloads above the subscriber's max_payload_bytes, and the catalog's): it leaves the broadcast (spec/moq.md 4).",
            limits: vec![("max_payload_bytes", 4096)],
            input: vec![
                Catalog(catalog(4096)),
                Frame(0, 0, big_keyframe(5)),
                Frame(1, 0, big_keyframe(6)),
            ],
        },
        Vector {
            name: "10-mirror-limit",
            about: "The broadcast's instances need a hash table of 2^3 buckets and this subscriber accepts at most 2^2 (max_table_log2): two groups' keyframes fail and it leaves.",
            limits: vec![("max_table_log2", 2)],
            input: vec![cat(), Frame(0, 0, keyframe(5)), Frame(1, 0, keyframe(6))],
        },
        Vector {
            name: "11-compression-off-catalog",
            about: "The catalog says no compression; a keyframe compressed with LZ4 breaks that promise and fails; the next group's plain keyframe applies.",
            limits: vec![],
            input: vec![
                cat(),
                Frame(0, 0, lz4_keyframe(5)),
                Frame(1, 0, keyframe(6)),
            ],
        },
        Vector {
            name: "12-stale-keyframe",
            about: "Group 1 opens with keyframe 5, older than the mirror's 7 (a publisher restarted without announcing anew): the group is not followed and the mirror is not in sync until a group opens at or past 7.",
            limits: vec![],
            input: vec![
                cat(),
                Frame(0, 0, keyframe(7)),
                Frame(1, 0, keyframe(5)),
                Frame(1, 1, step(6)),
                Frame(2, 0, keyframe(8)),
            ],
        },
    ]
}

/// [`keyframe`] compressed with LZ4 (compression 1).
fn lz4_keyframe(seq: u32) -> Vec<u8> {
    keyframe_compressed(seq, 1)
}

/// A keyframe at `seq` whose payload is above 4096 bytes (5000 filler
/// bytes after its definition: the decoder refuses the frame for its size
/// before it reads them).
fn big_keyframe(seq: u32) -> Vec<u8> {
    let mut f = key(seq, vec![define(1, &DEF), vec![0x7f; 5000], END.to_vec()]);
    f.checksum = true;
    f.bytes()
}

fn main() {
    let dir = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../spec/vectors/moq"));
    std::fs::create_dir_all(&dir).expect("the vectors' directory");
    for v in vectors() {
        let path = dir.join(format!("{}.txt", v.name));
        std::fs::write(&path, write(&v)).expect("writing a vector");
        println!("wrote {}", path.display());
    }
}

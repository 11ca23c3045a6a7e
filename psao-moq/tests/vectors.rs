//! Replays the MoQ subscriber vectors of `spec/vectors/moq/` (written by
//! `examples/gen_vectors.rs`, format in their README) against `Follower`:
//! every outcome, `in_sync` after every input, and the end state.

use std::path::PathBuf;

use psao_codec::Limits;
use psao_moq::{DigestCheck, FollowError, Followed, Follower};

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).expect("hex"))
        .collect()
}

fn replay(path: &PathBuf) -> usize {
    let text = std::fs::read_to_string(path).unwrap();
    let mut limits = Limits::default();
    let mut follower: Option<Follower> = None;
    let mut last = String::new();
    let mut checks = 0;
    for (n, line) in text.lines().enumerate() {
        let at = format!("{}:{}", path.display(), n + 1);
        let (word, rest) = line.split_once(' ').unwrap_or((line, ""));
        if word == "#" || word.is_empty() {
            continue;
        }
        if word == "limit" {
            let (name, v) = rest.split_once(' ').unwrap();
            assert!(limits.set(name, v.parse().unwrap()), "{at}");
            continue;
        }
        let f = follower.get_or_insert_with(|| Follower::new(limits));
        match word {
            "catalog" => {
                last = match f.on_catalog(&unhex(rest)) {
                    Ok(_) => "catalog ok".into(),
                    Err(FollowError::AboveLimits { what, .. }) => {
                        format!("catalog above_limits {}", what.split(' ').next().unwrap())
                    }
                    Err(_) => "catalog error".into(),
                }
            }
            "frame" => {
                let mut p = rest.split(' ');
                let g: u64 = p.next().unwrap().parse().unwrap();
                let i: u64 = p.next().unwrap().parse().unwrap();
                last = match f.on_frame(g, i, &unhex(p.next().unwrap())) {
                    Followed::Applied { sequence, keyframe } => format!(
                        "applied {sequence} {}",
                        if keyframe { "keyframe" } else { "delta" }
                    ),
                    Followed::Ignored => "ignored".into(),
                    Followed::WaitKeyframe => "wait_keyframe".into(),
                    Followed::Failed(_) => "failed".into(),
                }
            }
            "digest" => {
                last = format!(
                    "digest {}",
                    match f.on_digest(&unhex(rest)) {
                        Ok(DigestCheck::Match) => "match",
                        Ok(DigestCheck::Mismatch) => "mismatch",
                        Ok(DigestCheck::Held) => "held",
                        Ok(DigestCheck::Passed) => "passed",
                        Err(FollowError::BeforeCatalog(_)) => "ignored",
                        Err(_) => "error",
                    }
                )
            }
            "expect" => {
                assert_eq!(last, rest, "{at}");
                checks += 1;
            }
            "in_sync" => {
                assert_eq!(f.in_sync(), rest == "yes", "{at}");
                checks += 1;
            }
            "gave_up" => {
                match f.gave_up() {
                    Some(FollowError::Undecodable { groups, .. }) => {
                        assert_eq!(groups.to_string(), rest, "{at}")
                    }
                    other => panic!("{at}: {other:?}"),
                }
                checks += 1;
            }
            "end" => {
                if rest.starts_with("sequence") && !text.contains("\ngave_up ") {
                    assert!(f.gave_up().is_none(), "{at}: gave up");
                }
                let s = f.stats();
                let got = format!(
                    "sequence {} digest {} matched {} mismatched {}",
                    f.mirror()
                        .sequence()
                        .map_or("none".into(), |q| q.to_string()),
                    f.mirror()
                        .digest()
                        .map_or("none".into(), |d| format!("{d:08x}")),
                    s.digests_matched,
                    s.digest_mismatches
                );
                assert_eq!(got, rest, "{at}");
                checks += 1;
            }
            other => panic!("{at}: unknown line `{other}`"),
        }
    }
    checks
}

#[test]
fn every_moq_vector_replays() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../spec/vectors/moq");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "txt"))
        .collect();
    files.sort();
    assert!(
        files.len() >= 8,
        "{} vectors in {}",
        files.len(),
        dir.display()
    );
    for f in &files {
        assert!(replay(f) > 2, "{} checks nothing", f.display());
    }
}

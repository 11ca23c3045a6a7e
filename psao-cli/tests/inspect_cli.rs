//! `psao inspect` as a tool in a pipeline: a reader that closes the pipe
//! early (`psao inspect FILE | head`) ends it quietly, with success and
//! nothing on stderr, instead of a panic (exit 101).

use std::io::{BufRead, BufReader, Write};
use std::process::{Command, Stdio};

/// A capture (spec/capture.md) repeating vector 01's frame `n` times.
fn capture(n: usize) -> std::path::PathBuf {
    let vector = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../spec/vectors/01-keyframe-empty.txt"
    ))
    .unwrap();
    let hex = vector
        .lines()
        .find_map(|l| l.strip_prefix("frame "))
        .unwrap();
    let frame: Vec<u8> = (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
        .collect();
    let mut bytes = b"PSAOCAP1".to_vec();
    bytes.extend(1u16.to_le_bytes());
    bytes.resize(16, 0);
    for k in 0..n as u64 {
        bytes.extend((k * 1000).to_le_bytes());
        bytes.extend((frame.len() as u32).to_le_bytes());
        bytes.extend(&frame);
    }
    let path = std::env::temp_dir().join(format!("psao-inspect-{}.cap", std::process::id()));
    std::fs::File::create(&path)
        .unwrap()
        .write_all(&bytes)
        .unwrap();
    path
}

#[test]
fn inspect_ends_quietly_when_its_reader_goes_away() {
    let path = capture(50_000);
    let mut child = Command::new(env!("CARGO_BIN_EXE_psao"))
        .arg("inspect")
        .arg(&path)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    // The reader is dropped here: the pipe closes with output still to come.
    assert!(first.starts_with("#1 "), "first line: {first}");
    let out = child.wait_with_output().unwrap();
    let _ = std::fs::remove_file(&path);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "status {:?}: {stderr}", out.status);
    assert!(stderr.is_empty(), "stderr: {stderr}");
}

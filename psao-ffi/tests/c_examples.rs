//! The C and C++ examples, built with the system's compilers under
//! AddressSanitizer and UndefinedBehaviorSanitizer against the static
//! library cargo built for this test run, and run:
//!
//! - `examples/c/replay_vectors.c` replays every vector of spec/vectors
//!   through the C API and must pass them all;
//! - `examples/cpp/server.cpp` runs a server loop; its frames must decode in
//!   the Rust decoder, from the first keyframe and from the late joiner's,
//!   to a mirror equal to the server's table.
//!
//! A sanitizer report fails the run (`-fno-sanitize-recover=all`, and
//! ASan's exit code). `CC` and `CXX` choose the compilers (default `cc` and
//! `c++`).

use std::path::{Path, PathBuf};
use std::process::Command;

use psao_codec::{Decoder, Event, Limits};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The static library cargo built with this test's rlib: rustc writes
/// both crate types in one invocation into `deps/`, next to the test
/// binary (`cargo build` also copies it one level up).
fn static_lib() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let deps = exe.parent().unwrap();
    let lib = deps.join("libpsao_ffi.a");
    assert!(
        lib.exists(),
        "{} is missing: cargo builds it with the crate's staticlib target",
        lib.display()
    );
    lib
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("psao-ffi-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Compiles `source` with sanitizers into `out`.
fn compile(compiler_var: &str, default: &str, std: &str, source: &Path, out: &Path) {
    let compiler = std::env::var(compiler_var).unwrap_or_else(|_| default.to_string());
    let status = Command::new(&compiler)
        .arg(std)
        .args(["-Wall", "-Wextra", "-Werror", "-g", "-O1"])
        .args(["-fsanitize=address,undefined", "-fno-sanitize-recover=all"])
        .arg("-fno-omit-frame-pointer")
        .arg("-I")
        .arg(repo().join("include"))
        .arg(source)
        .arg(static_lib())
        .args(["-lm", "-lpthread", "-ldl", "-o"])
        .arg(out)
        .status()
        .unwrap_or_else(|e| panic!("cannot run the compiler `{compiler}`: {e}"));
    assert!(
        status.success(),
        "{compiler} failed on {}",
        source.display()
    );
}

fn run(exe: &Path, args: &[&Path]) -> String {
    let out = Command::new(exe)
        .args(args)
        .env(
            "ASAN_OPTIONS",
            "detect_leaks=1:abort_on_error=0:exitcode=23",
        )
        .env("UBSAN_OPTIONS", "print_stacktrace=1:halt_on_error=1")
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success(),
        "{} failed ({}):\n{text}",
        exe.display(),
        out.status
    );
    assert!(
        !text.contains("Sanitizer") && !text.contains("runtime error"),
        "sanitizer report:\n{text}"
    );
    text
}

#[test]
fn c_program_replays_every_vector_through_the_c_api() {
    let dir = scratch("replay");
    let exe = dir.join("replay_vectors");
    compile(
        "CC",
        "cc",
        "-std=c11",
        &repo().join("psao-ffi/examples/c/replay_vectors.c"),
        &exe,
    );
    let vectors = repo().join("spec/vectors");
    let text = run(&exe, &[&vectors]);
    let count = std::fs::read_dir(&vectors)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .path()
                .extension()
                .is_some_and(|x| x == "txt")
        })
        .count();
    assert!(count >= 62, "spec/vectors holds {count} vectors");
    assert!(
        text.contains(&format!("{count} vectors, {count} passed, 0 failed")),
        "{text}"
    );
    std::fs::remove_dir_all(dir).ok();
}

fn u32s(bytes: &[u8]) -> impl Iterator<Item = u32> + '_ {
    bytes
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
}

#[test]
fn cpp_server_frames_decode_in_rust_to_its_table() {
    let dir = scratch("server");
    let exe = dir.join("server");
    compile(
        "CXX",
        "c++",
        "-std=c++17",
        &repo().join("psao-ffi/examples/cpp/server.cpp"),
        &exe,
    );
    let text = run(&exe, &[&dir]);
    assert!(text.contains("0 dropped"), "{text}");

    // frames.bin: length-prefixed frames.
    let stream = std::fs::read(dir.join("frames.bin")).unwrap();
    let mut frames = Vec::new();
    let mut at = 0;
    while at < stream.len() {
        let len = u32::from_le_bytes(stream[at..at + 4].try_into().unwrap()) as usize;
        frames.push(&stream[at + 4..at + 4 + len]);
        at += 4 + len;
    }
    assert!(frames.len() > 10, "{} frames", frames.len());

    // A client from the start, and a late joiner from the second keyframe.
    let mut first = Decoder::new(Limits::default());
    let mut late = Decoder::new(Limits::default());
    let mut keyframes = 0;
    for f in &frames {
        match first
            .receive(f)
            .expect("the Rust decoder accepts the C++ frames")
        {
            Event::Applied { keyframe: true, .. } => keyframes += 1,
            Event::Applied { .. } | Event::Stale { .. } => {}
            other => panic!("unexpected {other:?}"),
        }
        if keyframes >= 2 {
            late.receive(f).unwrap();
        }
    }
    assert_eq!(keyframes, 2);
    assert_eq!(first.mirror().sequence(), late.mirror().sequence());
    assert_eq!(first.mirror().digest(), late.mirror().digest());

    // table.bin: instance, entries, (key, cell) pairs, words, words.
    let dump = std::fs::read(dir.join("table.bin")).unwrap();
    let mut v = u32s(&dump);
    let instance = v.next().unwrap();
    let entries = v.next().unwrap() as usize;
    let buckets: Vec<(u32, u32)> = (0..entries)
        .map(|_| (v.next().unwrap(), v.next().unwrap()))
        .collect();
    let words = v.next().unwrap() as usize;
    let table_words: Vec<u32> = v.by_ref().take(words).collect();
    assert_eq!(table_words.len(), words);
    assert!(v.next().is_none());

    for decoder in [&first, &late] {
        let m = decoder
            .mirror()
            .instance(instance)
            .expect("instance mirrored");
        let mirror_buckets: Vec<(u32, u32)> = m.buckets().iter().map(|e| (e.key, e.cell)).collect();
        assert_eq!(mirror_buckets, buckets, "bucket entries");
        assert_eq!(m.words(), &table_words[..], "point words");
        assert!(m.transform().is_some());
    }
    assert!(table_words.iter().filter(|&&w| w != 0).count() == 3000);
    std::fs::remove_dir_all(dir).ok();
}

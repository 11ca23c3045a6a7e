//! `psao serve --publish`, `psao view --subscribe`, `psao record
//! --subscribe` and `psao demo --relay` as a user runs them, through a real
//! `moq-relay` process (spec/moq.md), and their errors on bad options.
//!
//! Without a moq-relay binary (`$PSAO_MOQ_RELAY` or on the `PATH`) the
//! relay tests say they skip, unless `PSAO_REQUIRE_RELAY` is set.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use psao_moq::net::{LocalRelay, RelayCert, find_relay_binary};
use psao_proto::tls::fingerprint_hex;

const PSAO: &str = env!("CARGO_BIN_EXE_psao");

/// A scratch directory, removed when dropped.
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn scratch(name: &str) -> Scratch {
    let d = std::env::temp_dir().join(format!("psao-relay-cli-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    Scratch(d)
}

/// A relay (`None`: no binary and none required).
fn relay(dir: &Scratch) -> Option<(LocalRelay, PathBuf)> {
    let Some(bin) = find_relay_binary() else {
        assert!(
            std::env::var_os("PSAO_REQUIRE_RELAY").is_none(),
            "PSAO_REQUIRE_RELAY is set and no moq-relay was found"
        );
        eprintln!("skipped: no moq-relay (set PSAO_MOQ_RELAY or put it on the PATH)");
        return None;
    };
    let cert = RelayCert::generate(&dir.0).unwrap();
    let r = LocalRelay::start(&bin, &cert, None, dir.0.join("relay.log")).unwrap();
    Some((r, bin))
}

fn run(args: &[&str]) -> Output {
    Command::new(PSAO).args(args).output().unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// `psao serve --publish` until it says it publishes (or fails).
fn publishing_server(relay: &LocalRelay, fp: &str) -> Child {
    let mut child = Command::new(PSAO)
        .args([
            "serve",
            "--bind",
            "127.0.0.1:0",
            "--publish",
            &relay.url(""),
            "--relay-fingerprint",
            fp,
            "--group-seconds",
            "1",
            "--seconds",
            "30",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let until = Instant::now() + Duration::from_secs(120);
    let mut seen = String::new();
    loop {
        let mut line = String::new();
        if out.read_line(&mut line).unwrap() == 0 || Instant::now() > until {
            let _ = child.kill();
            panic!("psao serve did not publish:\n{seen}");
        }
        seen.push_str(&line);
        if line.starts_with("publishing broadcast psao/default") {
            break;
        }
    }
    // Keep draining its status lines so it never blocks on a full pipe.
    std::thread::spawn(move || for _ in out.lines() {});
    child
}

#[test]
fn serve_publishes_and_view_and_record_follow_through_the_relay() {
    let dir = scratch("follow");
    let Some((relay, _)) = relay(&dir) else {
        return;
    };
    let fp = fingerprint_hex(&relay.fingerprint);
    let mut server = publishing_server(&relay, &fp);
    let url = relay.url("psao/default");
    let view = run(&[
        "view",
        "--subscribe",
        &url,
        "--fingerprint",
        &fp,
        "--seconds",
        "3",
    ]);
    let v = text(&view);
    assert!(view.status.success(), "{v}");
    assert!(v.contains("broadcast of scene `default`"), "{v}");
    assert!(v.contains("in sync    1 of 1 at the end"), "{v}");
    assert!(
        !v.contains("digests    0 matched"),
        "digests were checked: {v}"
    );
    let cap = dir.0.join("s.psaocap");
    let cap_s = cap.to_str().unwrap();
    let rec = run(&[
        "record",
        "--subscribe",
        &url,
        "--fingerprint",
        &fp,
        "--seconds",
        "2",
        "--out",
        cap_s,
    ]);
    assert!(rec.status.success(), "{}", text(&rec));
    assert!(text(&rec).starts_with("recorded "), "{}", text(&rec));
    let inspect = run(&["inspect", cap_s]);
    let i = text(&inspect);
    assert!(inspect.status.success(), "{i}");
    // The recording starts at a group: its first frame is a keyframe.
    let first = i
        .lines()
        .find(|l| l.contains("keyframe") || l.contains("delta"))
        .unwrap();
    assert!(first.contains("keyframe"), "{i}");
    let _ = server.kill();
    let _ = server.wait();
}

#[test]
fn demo_relay_fans_out_and_checks_every_mirror() {
    let dir = scratch("demo");
    let Some((_relay, bin)) = relay(&dir) else {
        return;
    };
    let out = run(&[
        "demo",
        "--relay",
        "--relay-bin",
        bin.to_str().unwrap(),
        "--seconds",
        "2",
        "--clients",
        "2",
        "--images",
        "0",
    ]);
    let t = text(&out);
    assert!(out.status.success(), "{t}");
    assert!(t.contains("mirrors             2 of 2 equal"), "{t}");
}

#[test]
fn bad_relay_options_are_refused_with_what_is_wrong() {
    for (args, says) in [
        (
            vec![
                "serve",
                "--publish",
                "http://127.0.0.1:1/",
                "--relay-fingerprint",
                "00",
            ],
            "https://",
        ),
        (
            vec!["serve", "--publish", "https://127.0.0.1:1/"],
            "--relay-fingerprint",
        ),
        (
            vec![
                "serve",
                "--publish",
                "https://127.0.0.1:1/",
                "--relay-fingerprint",
                &"ab".repeat(32),
                "--group-seconds",
                "0",
            ],
            "--group-seconds",
        ),
        (
            vec!["view", "--subscribe", "https://127.0.0.1:1/psao/default"],
            "--fingerprint",
        ),
        (
            vec![
                "view",
                "--subscribe",
                "https://127.0.0.1:1/",
                "--fingerprint",
                &"ab".repeat(32),
            ],
            "empty",
        ),
        (
            vec![
                "record",
                "--subscribe",
                "https://127.0.0.1:1/x",
                "--fingerprint",
                &"ab".repeat(32),
                "--out",
                "/dev/null",
            ],
            "--seconds",
        ),
    ] {
        let out = run(&args);
        let t = text(&out);
        assert!(!out.status.success(), "{args:?} succeeded: {t}");
        assert!(t.contains(says), "{args:?} does not say {says:?}: {t}");
        assert!(!t.contains("panicked"), "{args:?}: {t}");
    }
}

//! `psao serve --web` as a user runs it: bad options fail before the scene
//! is prepared, naming what is wrong; and a real Chromium, driven headless
//! by `tests/browser/drive.mjs` (puppeteer-core), joins the page: mirrors
//! in sync with digests matched, a late join, a lost frame answered by a
//! keyframe, bad control bytes closed with the native codes, and the
//! page's AO against the CPU reconstruction of the same mirror.
//!
//! The browser test needs Chromium (`$PSAO_CHROMIUM`, or
//! /usr/bin/chromium), Node with `tests/browser/node_modules` (`npm ci`
//! there) and the wasm module (`scripts/build-web.sh`); without them it
//! says it skips, unless `PSAO_REQUIRE_BROWSER` is set.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const PSAO: &str = env!("CARGO_BIN_EXE_psao");

/// The browser tests run one at a time (each drives a Chromium on
/// SwiftShader: two at once on 2 cores would only slow each other).
static ONE_BROWSER: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn fails_with(args: &[&str], needle: &str) {
    let out = Command::new(PSAO).args(args).output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!out.status.success(), "{args:?} succeeded: {text}");
    assert!(text.contains(needle), "{args:?}: {text}");
}

#[test]
fn bad_web_options_name_what_is_wrong() {
    fails_with(
        &[
            "serve",
            "--web",
            "--web-cert-hours",
            "400",
            "--seconds",
            "1",
        ],
        "14 days",
    );
    fails_with(&["serve", "--web-port", "4443"], "--web");
    fails_with(
        &[
            "serve",
            "--bind",
            "127.0.0.1:0",
            "--web",
            "--web-port",
            "0",
            "--web-pkg",
            "/nonexistent/pkg",
            "--seconds",
            "1",
        ],
        "scripts/build-web.sh",
    );
}

/// What the browser test needs, or why it cannot run.
fn browser_setup() -> Result<(PathBuf, PathBuf), String> {
    let chromium = std::env::var_os("PSAO_CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    if !chromium.is_file() {
        return Err(format!("no Chromium at {}", chromium.display()));
    }
    let modules = root().join("tests/browser/node_modules/puppeteer-core");
    if !modules.is_dir() {
        return Err("no tests/browser/node_modules (run npm ci there)".into());
    }
    let pkg = root().join("target/psao-web/pkg");
    if !pkg.join("psao_wasm_bg.wasm").is_file() {
        return Err("no wasm module (run scripts/build-web.sh)".into());
    }
    Ok((chromium, pkg))
}

/// What the browser tests need; `None` (said) when it is missing and
/// `PSAO_REQUIRE_BROWSER` is not set.
fn browser_or_skip() -> Option<(PathBuf, PathBuf)> {
    match browser_setup() {
        Ok(s) => Some(s),
        Err(why) => {
            assert!(
                std::env::var_os("PSAO_REQUIRE_BROWSER").is_none(),
                "PSAO_REQUIRE_BROWSER is set: {why}"
            );
            eprintln!("skipped: {why}");
            None
        }
    }
}

#[test]
fn a_real_chromium_follows_the_stream() {
    let _one = ONE_BROWSER.lock().unwrap_or_else(|e| e.into_inner());
    let Some((chromium, pkg)) = browser_or_skip() else {
        return;
    };
    let WebServer {
        child: mut server,
        page,
        spki,
        drain,
    } = web_server(&pkg, 0, 240);
    let shots = std::env::var_os("PSAO_SCREENSHOT_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_TARGET_TMPDIR")));
    // WebGPU (SwiftShader in headless Chromium), then the CPU fallback.
    let mut reports = Vec::new();
    for (mode, flag) in [("webgpu", None), ("cpu", Some("--cpu"))] {
        let shot = shots.join(format!("browser-client-{mode}.png"));
        let driver = Command::new("node")
            .arg(root().join("tests/browser/drive.mjs"))
            .args(["--url", &format!("https://{page}/"), "--spki", &spki])
            .arg("--chromium")
            .arg(&chromium)
            .arg("--screenshot")
            .arg(&shot)
            .args(flag)
            .stderr(Stdio::inherit())
            .output()
            .unwrap();
        let report = String::from_utf8_lossy(&driver.stdout).to_string();
        eprintln!("driver ({mode}): {report}");
        reports.push((mode, driver.status.success(), report, shot));
    }
    let _ = server.kill();
    let _ = server.wait();
    let _ = drain.join();
    for (mode, success, report, shot) in reports {
        assert!(success, "the browser checks failed ({mode}): {report}");
        let compact: String = report.split_whitespace().collect();
        assert!(compact.starts_with("{\"ok\":true"), "{mode}: {report}");
        let expected = if mode == "cpu" { "CPU" } else { "WebGPU" };
        assert!(
            compact.contains(&format!("\"mode\":\"{expected}")),
            "{mode}: {report}"
        );
        assert!(shot.is_file(), "no screenshot at {}", shot.display());
    }
}

/// A `psao serve --web` running: its page's address and certificate's
/// SPKI hash as it printed them, and the thread reading the rest of its
/// output (a full pipe would stall it).
struct WebServer {
    child: std::process::Child,
    page: String,
    spki: String,
    drain: std::thread::JoinHandle<()>,
}

/// Starts `psao serve --web` on `web_port` (0: any) for `seconds`, until it
/// printed its page and certificate.
fn web_server(pkg: &Path, web_port: u16, seconds: u32) -> WebServer {
    let mut child = Command::new(PSAO)
        .args(["serve", "--bind", "127.0.0.1:0", "--web", "--web-port"])
        .arg(web_port.to_string())
        .arg("--web-pkg")
        .arg(pkg)
        .args(["--seconds", &seconds.to_string()])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let (mut page, mut spki) = (None, None);
    let started = Instant::now();
    let mut line = String::new();
    while page.is_none() || spki.is_none() {
        line.clear();
        if out.read_line(&mut line).unwrap() == 0 || started.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("the server did not print its page and certificate");
        }
        eprint!("server: {line}");
        if let Some(rest) = line.split("the page on ").nth(1) {
            page = rest.split_whitespace().next().map(str::to_string);
        }
        if let Some(rest) = line.split("--ignore-certificate-errors-spki-list=").nth(1) {
            spki = rest.trim().split(')').next().map(str::to_string);
        }
    }
    let drain = std::thread::spawn(move || for _ in out.lines().map_while(Result::ok) {});
    WebServer {
        child,
        page: page.unwrap_or_default(),
        spki: spki.unwrap_or_default(),
        drain,
    }
}

#[test]
fn the_page_reconnects_to_a_new_server_on_the_same_port() {
    let _one = ONE_BROWSER.lock().unwrap_or_else(|e| e.into_inner());
    let Some((chromium, pkg)) = browser_or_skip() else {
        return;
    };
    // The first server stops by itself (a clean shutdown: the page reads
    // server_shutdown); the second takes its ports, with a new certificate.
    let first = web_server(&pkg, 0, 20);
    let (mut first, page, drain) = (first.child, first.page, first.drain);
    let port: u16 = page.rsplit(':').next().unwrap().parse().unwrap();
    let driver = Command::new("node")
        .arg(root().join("tests/browser/reconnect.mjs"))
        .args(["--url", &format!("https://{page}/")])
        .arg("--chromium")
        .arg(&chromium)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let _ = first.wait();
    let _ = drain.join();
    let second = web_server(&pkg, port, 120);
    let (mut second, drain) = (second.child, second.drain);
    let out = driver.wait_with_output().unwrap();
    let _ = second.kill();
    let _ = second.wait();
    let _ = drain.join();
    let report = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(out.status.success(), "the page did not reconnect: {report}");
    assert!(report.contains("\"ok\":true"), "{report}");
}

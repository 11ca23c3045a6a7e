//! The real `moq-relay` as processes on loopback, for the MoQ tests:
//! psao-moq's [`LocalRelay`] (a relay, or a second clustered with it, all
//! serving one [`RelayCert`] so that a subscriber pins one fingerprint),
//! with the tests' policy for a missing binary.
//!
//! The binary is `$PSAO_MOQ_RELAY`, or `moq-relay` on the `PATH` (CI
//! installs the pinned version with `cargo install moq-relay --version
//! 0.17.10`). Where it is missing, [`start`] returns `None` and the tests
//! say they skip, unless `PSAO_REQUIRE_RELAY` is set: then they fail.

use std::path::PathBuf;

pub use psao_moq::net::{LocalRelay, RelayCert};

/// A directory of its own under the temporary directory, for one test's
/// certificate and relay logs; removed when dropped (declare it before
/// the relays, so they go first).
pub struct Scratch(PathBuf);

impl std::ops::Deref for Scratch {
    type Target = std::path::Path;
    fn deref(&self) -> &std::path::Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A [`Scratch`] directory named after `name`.
pub fn scratch_dir(name: &str) -> Scratch {
    static NEXT: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
    Scratch(std::env::temp_dir().join(format!("psao-moq-{name}-{}-{n}", std::process::id())))
}

/// A fresh certificate for a test's relays.
///
/// # Panics
/// When it cannot be written.
pub fn cert(dir: &std::path::Path) -> RelayCert {
    RelayCert::generate(dir).expect("a relay certificate")
}

/// Starts relay `name` serving `cert` (clustered with `peer`), its log in
/// `dir`; `None` when there is no binary and none is required.
///
/// # Panics
/// When it does not come up, or is required and missing.
pub fn start(
    name: &str,
    dir: &std::path::Path,
    cert: &RelayCert,
    peer: Option<&LocalRelay>,
) -> Option<LocalRelay> {
    let Some(bin) = psao_moq::net::find_relay_binary() else {
        assert!(
            std::env::var_os("PSAO_REQUIRE_RELAY").is_none(),
            "PSAO_REQUIRE_RELAY is set and no moq-relay was found (set PSAO_MOQ_RELAY or put it on the PATH)"
        );
        eprintln!("skipped: no moq-relay (set PSAO_MOQ_RELAY or put it on the PATH)");
        return None;
    };
    match LocalRelay::start(&bin, cert, peer, dir.join(format!("relay-{name}.log"))) {
        Ok(r) => Some(r),
        Err(e) => panic!("{e}"),
    }
}

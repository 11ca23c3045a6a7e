//! # psao-web
//!
//! What `psao serve --web` needs beside the server's WebTransport endpoint
//! (psao-proto's `ServerHandle::listen_web`, spec/session.md 9):
//! - [`cert`]: a self-signed ECDSA P-256 certificate valid for less than
//!   the 14 days a browser accepts by its hash (`serverCertificateHashes`),
//!   and a [`cert::Rotation`] that replaces it before it expires;
//! - [`site`]: the files a page loads: the page itself (embedded from
//!   `page/` at build time), the wasm module (built by
//!   `scripts/build-web.sh`), psao-gpu's reconstruction WGSL, the scene's
//!   glTF, and `config.json` (the WebTransport URL and the current
//!   certificate's hash);
//! - [`https`]: an HTTPS server for them (hyper over tokio-rustls), whose
//!   certificate is replaced with the WebTransport endpoint's.
//!
//! docs/browser.md tells a user how to open the page, and what works in
//! which browser.

pub mod cert;
pub mod https;
pub mod site;

pub use cert::{Rotation, WebCertificate};
pub use https::HttpsServer;
pub use site::{PageConfig, SceneClock, Site, SiteError};

//! The files of the page and what it is told: everything is read or made
//! once when the site is built, so a request only looks a path up.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, RwLock};

use bytes::Bytes;

include!(concat!(env!("OUT_DIR"), "/page_files.rs"));

/// psao-gpu's reconstruction (the very file its `RECONSTRUCT_WGSL`
/// includes; psao-web reads it without building wgpu), served at
/// `/reconstruct.wgsl` for the page's shaders to include.
pub const RECONSTRUCT_WGSL: &str = include_str!("../../psao-gpu/src/shaders/reconstruct.wgsl");

/// The wasm-bindgen files `scripts/build-web.sh` writes, served under
/// `/pkg/`.
pub const PKG_FILES: [&str; 2] = ["psao_wasm.js", "psao_wasm_bg.wasm"];

/// The largest file the site loads from disk (the wasm module is about
/// 250 kB).
pub const MAX_PKG_FILE_BYTES: u64 = 32 << 20;

/// What the page is told in `/config.json`.
#[derive(Clone, Debug, PartialEq)]
pub struct PageConfig {
    /// The WebTransport session's URL (spec/session.md 9.1), e.g.
    /// `https://127.0.0.1:4443/psao`.
    pub url: String,
    /// The scene's name.
    pub scene: String,
    /// The server's frame rate.
    pub frame_rate: u16,
    /// The first camera: eye, target, vertical field of view (radians).
    pub camera: ([f32; 3], [f32; 3], f32),
}

/// Why the site could not be built.
#[derive(Debug, thiserror::Error)]
pub enum SiteError {
    /// A file of the wasm module is missing or unreadable.
    #[error(
        "{path}: {reason} (the page's wasm module is built by scripts/build-web.sh; or pass --web-pkg DIR)"
    )]
    Pkg {
        /// The file.
        path: String,
        /// Why.
        reason: String,
    },
}

/// The server's scene time in seconds, read at each request of
/// `/config.json` (a page poses skinned meshes by it).
pub type SceneClock = Arc<dyn Fn() -> f64 + Send + Sync>;

/// The page's files, the module, the geometry and the config.
pub struct Site {
    files: HashMap<String, (&'static str, Bytes)>,
    page: PageConfig,
    fingerprint: RwLock<String>,
    clock: RwLock<Option<SceneClock>>,
}

impl std::fmt::Debug for Site {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Site")
            .field("paths", &self.paths())
            .field("page", &self.page)
            .finish()
    }
}

/// The content type of a file name.
fn content_type(name: &str) -> &'static str {
    match name.rsplit('.').next() {
        Some("html") => "text/html; charset=utf-8",
        Some("js") | Some("mjs") => "text/javascript; charset=utf-8",
        Some("wasm") => "application/wasm",
        Some("wgsl") => "text/plain; charset=utf-8",
        Some("json") => "application/json",
        Some("glb") => "model/gltf-binary",
        Some("css") => "text/css; charset=utf-8",
        _ => "application/octet-stream",
    }
}

impl Site {
    /// The site: the embedded page at `/` and `/<file>`, the module from
    /// `pkg_dir` at `/pkg/<file>`, [`RECONSTRUCT_WGSL`] at
    /// `/reconstruct.wgsl`, `glb` at `/scene.glb`, and `/config.json` with
    /// `fingerprint` (hex) as the certificate to pin.
    pub fn new(
        pkg_dir: &Path,
        glb: Vec<u8>,
        page: PageConfig,
        fingerprint: &str,
    ) -> Result<Arc<Site>, SiteError> {
        let mut files = HashMap::new();
        for (name, bytes) in PAGE {
            files.insert(
                format!("/{name}"),
                (content_type(name), Bytes::from_static(bytes)),
            );
        }
        if let Some(index) = files.get("/index.html").cloned() {
            files.insert("/".into(), index);
        }
        for name in PKG_FILES {
            let path = pkg_dir.join(name);
            let err = |reason: String| SiteError::Pkg {
                path: path.display().to_string(),
                reason,
            };
            let len = std::fs::metadata(&path)
                .map_err(|e| err(e.to_string()))?
                .len();
            if len > MAX_PKG_FILE_BYTES {
                return Err(err(format!("{len} bytes, above {MAX_PKG_FILE_BYTES}")));
            }
            let bytes = std::fs::read(&path).map_err(|e| err(e.to_string()))?;
            files.insert(format!("/pkg/{name}"), (content_type(name), bytes.into()));
        }
        files.insert(
            "/reconstruct.wgsl".into(),
            (
                content_type("x.wgsl"),
                Bytes::from_static(RECONSTRUCT_WGSL.as_bytes()),
            ),
        );
        files.insert("/scene.glb".into(), (content_type("x.glb"), glb.into()));
        Ok(Arc::new(Site {
            files,
            page,
            fingerprint: RwLock::new(fingerprint.to_string()),
            clock: RwLock::new(None),
        }))
    }

    /// The content type and bytes served at `path` (without a query).
    pub fn get(&self, path: &str) -> Option<(&'static str, Bytes)> {
        if path == "/config.json" {
            let fingerprint = self
                .fingerprint
                .read()
                .unwrap_or_else(|e| e.into_inner())
                .clone();
            let time = self
                .clock
                .read()
                .unwrap_or_else(|e| e.into_inner())
                .as_ref()
                .map_or(0.0, |c| c());
            return Some((
                content_type(path),
                config_json(&self.page, &fingerprint, time),
            ));
        }
        self.files.get(path).cloned()
    }

    /// Tells pages loaded from now on to pin `fingerprint` (hex).
    pub fn set_fingerprint(&self, fingerprint: &str) {
        *self.fingerprint.write().unwrap_or_else(|e| e.into_inner()) = fingerprint.to_string();
    }

    /// Where `/config.json`'s `scene_time` comes from (without one, 0).
    pub fn set_clock(&self, clock: SceneClock) {
        *self.clock.write().unwrap_or_else(|e| e.into_inner()) = Some(clock);
    }

    /// The paths served.
    pub fn paths(&self) -> Vec<String> {
        let mut p: Vec<String> = self.files.keys().cloned().collect();
        p.push("/config.json".into());
        p.sort();
        p
    }
}

fn config_json(page: &PageConfig, fingerprint: &str, scene_time: f64) -> Bytes {
    let (eye, target, fov_y) = page.camera;
    let v = serde_json::json!({
        "url": page.url,
        "scene_time": scene_time,
        "certificate_hashes": [fingerprint],
        "scene": page.scene,
        "frame_rate": page.frame_rate,
        "camera": {"eye": eye, "target": target, "up": [0.0, 1.0, 0.0], "fov_y": fov_y},
    });
    Bytes::from(v.to_string())
}

/// Where `scripts/build-web.sh` puts the module for a `psao` binary
/// built in this workspace: `target/psao-web/pkg` beside the binary's
/// profile folder, else the same under the current folder.
pub fn default_pkg_dir() -> PathBuf {
    let built = std::env::current_exe()
        .ok()
        .and_then(|exe| Some(exe.parent()?.parent()?.join("psao-web").join("pkg")));
    match built {
        Some(dir) if dir.join(PKG_FILES[1]).is_file() => dir,
        _ => PathBuf::from("target/psao-web/pkg"),
    }
}

//! `psao serve --web`: the browser client beside the native server (issue
//! 19): the WebTransport endpoint (spec/session.md 9) on a UDP port and
//! the page over HTTPS on the same port number over TCP, both with one
//! short-lived P-256 certificate that is replaced before it expires.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use psao_proto::web::WEB_PATH;
use psao_proto::{Binding, ClientFigures, FrameSource, ServerHandle};
use psao_scene::Pipeline;
use psao_web::{HttpsServer, PageConfig, Rotation, Site, WebCertificate};

/// The options of the browser client.
#[derive(clap::Args, Clone, Debug)]
pub struct WebArgs {
    /// Also serve browsers: WebTransport (spec/session.md 9) on UDP and
    /// the page on HTTPS, both on --web-port; prints the URL to open.
    #[arg(long)]
    pub web: bool,
    /// The port of the WebTransport endpoint (UDP) and the page (TCP)
    /// [default: the --bind port plus 10].
    #[arg(long, requires = "web")]
    pub web_port: Option<u16>,
    /// The host name or address the page's WebTransport URL names
    /// [default: the --bind address, or 127.0.0.1 when it is unspecified].
    #[arg(long, requires = "web")]
    pub web_host: Option<String>,
    /// The folder of the page's wasm module (scripts/build-web.sh writes
    /// it) [default: target/psao-web/pkg beside the psao binary's folder,
    /// else under the current folder].
    #[arg(long, requires = "web")]
    pub web_pkg: Option<PathBuf>,
    /// Validity of each certificate, in hours (at most 335: browsers pin
    /// only certificates valid for no more than 14 days); a new one, for
    /// the same key, replaces it after 70% of that.
    #[arg(long, requires = "web", default_value_t = 240.0)]
    pub web_cert_hours: f64,
}

/// The page's pieces, made from the scene before the server takes it.
pub struct WebPlan {
    args: WebArgs,
    glb: Vec<u8>,
    camera: ([f32; 3], [f32; 3], f32),
    scene: String,
    rotation: Rotation,
    /// The pipeline's lead (it poses the scene this far ahead of its time).
    lead: f32,
}

/// What runs for the browsers while the server serves.
pub struct WebRunning {
    https: HttpsServer,
    site: Arc<Site>,
    rotation: tokio::task::JoinHandle<()>,
    certs: tokio::sync::mpsc::UnboundedReceiver<WebCertificate>,
}

impl Drop for WebRunning {
    fn drop(&mut self) {
        self.rotation.abort();
    }
}

impl WebArgs {
    /// The plan for `pipeline`'s scene, when --web is on; bad options fail
    /// here, before the server starts.
    pub fn plan(&self, pipeline: &Pipeline, scene: &str) -> anyhow::Result<Option<WebPlan>> {
        if !self.web {
            return Ok(None);
        }
        let hours = self.web_cert_hours;
        if !(hours.is_finite() && hours > 1.0 / 60.0 && hours < 336.0) {
            anyhow::bail!(
                "--web-cert-hours {hours}: must be above 1 minute and below 336 (14 days)"
            );
        }
        let valid_for = Duration::from_secs_f64(hours * 3600.0);
        let rotation = Rotation {
            valid_for,
            replace_after: valid_for.mul_f64(0.7),
        };
        rotation.check()?;
        let glb = psao_scene::export::glb::to_glb(pipeline.scene(), |i| {
            pipeline.table(i).is_some_and(|t| t.def().bind_space())
        })?;
        Ok(Some(WebPlan {
            args: self.clone(),
            glb,
            camera: first_camera(pipeline.scene()),
            scene: scene.to_string(),
            rotation,
            lead: pipeline.config().lead,
        }))
    }
}

/// The scene's camera at time 0, or one looking at the scene's bounds
/// from above one corner.
fn first_camera(scene: &psao_scene::Scene) -> ([f32; 3], [f32; 3], f32) {
    if let Some(path) = &scene.camera {
        let c = path.at(0.0);
        return (c.eye.to_array(), c.target.to_array(), c.fov_y);
    }
    let pose = scene.pose(0.0);
    let (mut lo, mut hi) = (glam::Vec3::splat(f32::MAX), glam::Vec3::splat(f32::MIN));
    for (i, inst) in scene.instances.iter().enumerate() {
        if let Some((a, b)) = scene.meshes[inst.mesh].bounds() {
            let (a, b) = psao_scene::transformed_bounds(&pose.instances[i], (a, b));
            (lo, hi) = (lo.min(a), hi.max(b));
        }
    }
    if lo.x > hi.x {
        return ([3.0, 2.0, 3.0], [0.0; 3], 0.9);
    }
    let (centre, size) = ((lo + hi) * 0.5, (hi - lo).length().max(1e-3));
    let eye = centre + glam::Vec3::new(0.6, 0.5, 0.6) * size;
    (eye.to_array(), centre.to_array(), 0.9)
}

impl WebPlan {
    /// Starts the WebTransport endpoint and the HTTPS server beside
    /// `server`; prints the URL to open and the certificate.
    pub async fn start<S: FrameSource>(
        self,
        server: &mut ServerHandle<S>,
        rate: u16,
    ) -> anyhow::Result<WebRunning> {
        let bind = server.local_addr();
        let port = match self.args.web_port {
            Some(p) => p,
            None => bind.port().checked_add(10).ok_or_else(|| {
                anyhow::anyhow!(
                    "--bind port {} + 10 is not a port: pass --web-port",
                    bind.port()
                )
            })?,
        };
        let at = SocketAddr::new(bind.ip(), port);
        let host = match &self.args.web_host {
            Some(h) => h.clone(),
            None if bind.ip().is_unspecified() => Ipv4Addr::LOCALHOST.to_string(),
            None => match bind.ip() {
                IpAddr::V6(v6) => format!("[{v6}]"),
                ip => ip.to_string(),
            },
        };
        let cert = WebCertificate::generate(self.rotation.valid_for)?;
        let web = server.listen_web(at, &cert.identity)?;
        let pkg = self
            .args
            .web_pkg
            .clone()
            .unwrap_or_else(psao_web::site::default_pkg_dir);
        let page = PageConfig {
            url: format!("https://{host}:{}{WEB_PATH}", web.port()),
            scene: self.scene,
            frame_rate: rate,
            camera: self.camera,
        };
        let site = Site::new(&pkg, self.glb, page, &cert.fingerprint_hex())?;
        let frames = server.frames_stepped();
        let (rate_s, lead) = (f64::from(rate), f64::from(self.lead));
        site.set_clock(Arc::new(move || frames() as f64 / rate_s + lead));
        let https = HttpsServer::start(
            SocketAddr::new(bind.ip(), web.port()),
            &cert.identity,
            site.clone(),
        )
        .await?;
        let (tx, certs) = tokio::sync::mpsc::unbounded_channel();
        let rotation = self.rotation.spawn(&cert, move |c| {
            let _ = tx.send(c);
        })?;
        println!(
            "WebTransport on {web} (UDP), the page on {} (TCP)",
            https.local_addr()
        );
        print_certificate(&cert);
        println!(
            "open https://{host}:{}/ in Chromium, Edge, Firefox or Safari (docs/browser.md)",
            https.local_addr().port()
        );
        Ok(WebRunning {
            https,
            site,
            rotation,
            certs,
        })
    }
}

fn print_certificate(cert: &WebCertificate) {
    println!(
        "web certificate SHA-256 {} (P-256, valid until {} s from now; Chromium without a warning: --ignore-certificate-errors-spki-list={})",
        cert.fingerprint_hex(),
        cert.not_after
            .duration_since(std::time::SystemTime::now())
            .map_or(0, |d| d.as_secs()),
        cert.spki_sha256
    );
}

impl WebRunning {
    /// Waits for the next certificate and installs it everywhere: the
    /// WebTransport endpoint, the HTTPS server and the page's config. Both
    /// servers' configurations are made first, so a failure changes
    /// nothing (it is reported, the current certificate stays, and the
    /// next rotation tries again; it is valid well past it).
    pub async fn next_certificate<S: FrameSource>(&mut self, server: &ServerHandle<S>) {
        let Some(cert) = self.certs.recv().await else {
            return std::future::pending().await;
        };
        let installed = HttpsServer::prepare(&cert.identity)
            .map_err(anyhow::Error::from)
            .and_then(|prepared| {
                server.set_web_identity(&cert.identity)?;
                self.https.install(prepared);
                Ok(())
            });
        match installed {
            Ok(()) => {
                self.site.set_fingerprint(&cert.fingerprint_hex());
                println!(
                    "certificate replaced: new sessions and pages use it; open ones keep theirs"
                );
                print_certificate(&cert);
            }
            Err(e) => {
                tracing::warn!(
                    "the new certificate could not be installed (the current one stays): {e}"
                );
            }
        }
    }
}

/// Native against WebTransport clients, side by side: clients, frame
/// records written, record bytes and UDP bytes per frame, mean frame age
/// (from a frame's broadcast to its ACK).
pub fn binding_summary(figures: &[ClientFigures]) -> String {
    let mut parts = Vec::new();
    for (binding, name) in [
        (Binding::Native, "native"),
        (Binding::WebTransport, "WebTransport"),
    ] {
        let c: Vec<&ClientFigures> = figures.iter().filter(|f| f.binding == binding).collect();
        if c.is_empty() {
            continue;
        }
        let frames: u64 = c.iter().map(|f| f.frames).sum();
        let per = |x: u64| x as f64 / frames.max(1) as f64;
        parts.push(format!(
            "{name}: {} clients, {frames} frames, {:.0} record bytes/frame, {:.0} UDP bytes/frame, frame age {:.1} ms",
            c.len(),
            per(c.iter().map(|f| f.record_bytes).sum()),
            per(c.iter().map(|f| f.udp_sent).sum()),
            1e3 * c.iter().map(|f| f.frame_age).sum::<f64>() / c.len() as f64,
        ));
    }
    parts.join(" | ")
}

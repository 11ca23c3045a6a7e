//! What the bench measures, as data: the methods, one row of figures per
//! configuration, where the error lies, a frame's shared inputs and a
//! scene's results. `measure` fills them, `images`, `charts` and `report`
//! read them.

use psao_eval::{GBuffer, PosedScene, View};

/// Which method a row measures.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Method {
    /// PSAO at a density (points kept per unit area, the paper's N) and
    /// server rate.
    Psao {
        /// Density.
        density: f32,
        /// Server rate, Hz.
        rate: u16,
        /// Whether the server traces within a ray budget
        /// ([`Settings::budget`](super::measure::Settings::budget)).
        budget: bool,
    },
    /// Per-pixel ray-traced AO with this many rays per pixel.
    Rtao {
        /// Rays per pixel.
        rays: u32,
    },
    /// Scalable Ambient Obscurance.
    Sao,
}

impl Method {
    /// Short name as in the paper's tables.
    pub fn label(&self) -> String {
        match self {
            Method::Psao {
                density,
                rate,
                budget: false,
            } => format!("PSAO-{density} @{rate} Hz"),
            Method::Psao { density, rate, .. } => format!("PSAO-{density} @{rate} Hz budget"),
            Method::Rtao { rays } => format!("RTAO-{rays}spp"),
            Method::Sao => "SAO".into(),
        }
    }
}

/// One configuration's figures on one scene (means over the frames).
#[derive(Clone, Debug)]
pub struct Row {
    /// The method.
    pub method: Method,
    /// Server milliseconds per tick (PSAO only).
    pub server_ms: Option<f64>,
    /// Client milliseconds per frame for the AO pass.
    pub client_ms: f64,
    /// Megabits per second at the server rate (PSAO only).
    pub mbit_s: Option<f64>,
    /// Root mean square error over all frames' pixels.
    pub rmse: f64,
    /// PSNR of the pooled mean square error, peak 1.
    pub psnr: f64,
    /// Mean SSIM over frames.
    pub ssim: f64,
    /// Mean FLIP of the composited image over frames.
    pub flip: f64,
    /// Points the server holds (PSAO only).
    pub points: Option<usize>,
    /// Server setup seconds: points, layout, first trace and keyframe
    /// (PSAO only).
    pub setup_s: Option<f64>,
    /// Keyframe bytes (PSAO only).
    pub keyframe_bytes: Option<usize>,
    /// Points the server's tables hold no slot for at the end of the run:
    /// their cell or bucket was full, or they left their grid (PSAO only).
    pub dropped: Option<u64>,
    /// Covered pixels the client had no data for, over all frames.
    pub unknown_px: usize,
    /// PSAO: the part of `client_ms` spent decoding frames. RTAO: the
    /// per-frame BVH build a client would need for a moving scene (not in
    /// `client_ms`).
    pub extra_ms: Option<f64>,
    /// Where the squared error lies.
    pub breakdown: Breakdown,
    /// PSAO: the longest any point waited for the ray budget, in ticks,
    /// over the measured frames and the server ticks.
    pub worst_wait: Option<u32>,
    /// PSAO: the rays its server cast a tick, on average over every tick
    /// it stepped (the frames' path and the server ticks; with a budget
    /// in the run, every server steps tick by tick).
    pub rays_per_tick: Option<f64>,
    /// PSAO: of the server ticks timed (`server_ms`), how many took
    /// longer than the period, how many were timed, and the longest in
    /// milliseconds.
    pub ticks_over: Option<(u32, u32, f64)>,
}

/// Where a method's squared error lies, over all frames.
#[derive(Clone, Debug, Default)]
pub struct Breakdown {
    /// Per instance seen, its share of the squared error, largest first.
    pub by_instance: Vec<(u32, f64)>,
    /// Share of the squared error in pixels the method left open (AO at
    /// least 0.999) where the reference is dark (below 0.9).
    pub open_where_dark: f64,
    /// Share of the squared error in pixels the method made dark where
    /// the reference is open: the reference above [`OPEN`], the method at
    /// least [`DARKER`] below it (blocks of buried points' AO, say).
    pub dark_where_open: f64,
    /// Share of covered pixels that are dark where the reference is open
    /// (as `dark_where_open`).
    pub dark_where_open_px: f64,
    /// PSAO: why the pixels counted in `open_where_dark` were left open,
    /// each cause's squared error a share of the total.
    pub open_causes: Vec<(&'static str, f64)>,
}

/// A reference at least this bright counts as open for
/// [`Breakdown::dark_where_open`].
pub const OPEN: f32 = 0.85;

/// How much darker than an open reference a pixel must be to count in
/// [`Breakdown::dark_where_open`].
pub const DARKER: f32 = 0.4;

/// One frame's inputs, shared by every method.
pub struct Frame {
    /// Scene time.
    pub time: f32,
    /// The view.
    pub view: View,
    /// The G-buffer.
    pub gbuffer: GBuffer,
    /// The reference AO image.
    pub reference: Vec<f32>,
    /// The composited reference, 8-bit sRGB, for FLIP.
    pub composite: Vec<u8>,
    /// The geometry at this time (for RTAO).
    pub posed: PosedScene,
    /// Milliseconds to pose the scene and build its BVH (what a per-pixel
    /// RTAO client of a moving scene pays each frame).
    pub bvh_ms: f64,
}

/// The images of the frames saved (`--image-frames`), for their files and
/// side-by-side pictures; no other frame's images are kept.
pub struct Showcase {
    /// One entry per saved frame, by ascending frame index.
    pub frames: Vec<Shown>,
}

impl Showcase {
    /// Adds `label`'s AO image of frame `frame` (dropped if that frame is
    /// not saved).
    pub fn add(&mut self, frame: usize, label: String, ao: Vec<f32>) {
        self.add_with_causes(frame, label, ao, Vec::new());
    }

    /// As [`add`](Self::add), with the PSAO image's open-cause map
    /// ([`Shown::open_causes`]).
    pub fn add_with_causes(&mut self, frame: usize, label: String, ao: Vec<f32>, causes: Vec<u8>) {
        if let Some(shown) = self.frames.iter_mut().find(|s| s.frame == frame) {
            shown.images.push((label, ao));
            if !causes.is_empty() {
                shown.open_causes = causes;
            }
        }
    }
}

/// One saved frame's images.
pub struct Shown {
    /// Index of the frame among the measured frames (0-based).
    pub frame: usize,
    /// (label, AO image) per method shown, in table order; the reference
    /// is the frame's own ([`Frame::reference`]).
    pub images: Vec<(String, Vec<f32>)>,
    /// Per pixel, why the shown PSAO configuration left it open where the
    /// reference is dark ([`psao_eval::OpenCause`] as its index + 1), 0
    /// elsewhere; empty until that configuration is measured.
    pub open_causes: Vec<u8>,
}

/// Everything measured on one scene.
pub struct SceneResult {
    /// Scene name.
    pub name: String,
    /// Rows in table order.
    pub rows: Vec<Row>,
    /// Frames, in time order.
    pub frames: Vec<Frame>,
    /// The shown methods' images of the saved frames.
    pub showcase: Showcase,
    /// Mean fraction of pixels covered by geometry.
    pub coverage: f64,
    /// Triangles in the scene.
    pub triangles: usize,
    /// Seconds to trace the reference, all frames.
    pub reference_s: f64,
    /// Per instance, what kind it is ("static", "moving" or "skinned",
    /// and "alpha-masked").
    pub kinds: Vec<String>,
}

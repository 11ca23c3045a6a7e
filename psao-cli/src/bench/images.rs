//! Images of `psao bench`: the composited frame FLIP compares, the AO and
//! G-buffer files of each saved frame (`--image-frames`), and the
//! side-by-side picture.

use std::path::Path;
use std::sync::Once;

use anyhow::Context as _;
use glam::Vec3;
use image::{ImageBuffer, Luma, Rgb, Rgb32FImage};
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};
use psao_eval::{GBuffer, NO_INSTANCE, error_map};

use super::model::{Frame, SceneResult, Shown};

/// DejaVu Sans (see assets/README.md): text in charts and pictures needs no
/// system font.
static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// Registers the embedded font as plotters' "sans-serif" (once).
pub fn register_fonts() -> anyhow::Result<()> {
    static ONCE: Once = Once::new();
    let mut result = Ok(());
    ONCE.call_once(|| {
        result = register_font("sans-serif", FontStyle::Normal, FONT)
            .map_err(|_| anyhow::anyhow!("the embedded font is not a valid TrueType font"));
    });
    result
}

/// Error maps are scaled by this before display (an error of 0.25 is
/// white).
const ERROR_GAIN: f32 = 4.0;

/// The light of the composited image.
fn light() -> Vec3 {
    Vec3::new(0.4, 1.0, 0.3).normalize()
}

/// The composited image FLIP compares, 8-bit sRGB: a grey material lit by
/// a sky term and a sun term, both scaled by AO (so AO differences show
/// everywhere, not only in shadow), `0.8 (0.3 + 0.7 max(0, n.l)) AO`;
/// pixels with no geometry show a constant sky.
pub fn composite(g: &GBuffer, ao: &[f32]) -> Vec<u8> {
    let l = light();
    let mut out = Vec::with_capacity(g.pixels() * 3);
    for ((&id, n), &a) in g.instance.iter().zip(&g.normal).zip(ao) {
        let rgb = if id == NO_INSTANCE {
            [0.55, 0.65, 0.8]
        } else {
            let v = 0.8 * (0.3 + 0.7 * n.dot(l).max(0.0)) * a.clamp(0.0, 1.0);
            [v, v, v]
        };
        out.extend(rgb.map(to_srgb8));
    }
    out
}

/// Linear [0, 1] to an 8-bit sRGB code.
fn to_srgb8(v: f32) -> u8 {
    let v = v.clamp(0.0, 1.0);
    let s = if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

/// Mean FLIP between the frame's composited reference and the same
/// composite with `test` as AO (at FLIP's default 67 pixels per degree).
#[cfg(feature = "flip")]
pub fn flip_mean(frame: &Frame, test: &[f32]) -> f64 {
    let (w, h) = (frame.gbuffer.width, frame.gbuffer.height);
    let reference = nv_flip::FlipImageRgb8::with_data(w, h, &frame.composite);
    let test = nv_flip::FlipImageRgb8::with_data(w, h, &composite(&frame.gbuffer, test));
    let map = nv_flip::flip(reference, test, nv_flip::DEFAULT_PIXELS_PER_DEGREE);
    nv_flip::FlipPool::from_image(&map).mean() as f64
}

/// Without the `flip` feature there is no FLIP: NaN, printed as `NaN`.
#[cfg(not(feature = "flip"))]
pub fn flip_mean(_frame: &Frame, _test: &[f32]) -> f64 {
    f64::NAN
}

/// The file-name stem of a saved frame's files: the scene's name for
/// frame 0 (the names the bench always wrote: `default-frame.png`,
/// `default-ao-sao.png`), `<scene>-f<k>` for frame k (`default-f3-frame.png`).
pub fn frame_stem(scene: &str, frame: usize) -> String {
    if frame == 0 {
        scene.to_string()
    } else {
        format!("{scene}-f{frame}")
    }
}

/// Writes each saved frame's files (see [`frame_stem`] for their names):
/// the reference and each shown method's AO as 16-bit PNG, the reference
/// AO as float EXR, the G-buffer as EXR (position, normal, and depth /
/// instance id / coverage), and the side-by-side picture.
pub fn write_scene_images(out: &Path, r: &SceneResult) -> anyhow::Result<()> {
    for shown in &r.showcase.frames {
        let f = r
            .frames
            .get(shown.frame)
            .with_context(|| format!("frame {} was not measured", shown.frame))?;
        write_frame_images(out, &frame_stem(&r.name, shown.frame), f, shown)?;
    }
    Ok(())
}

/// Writes one saved frame's files, named `<stem>-...`.
fn write_frame_images(out: &Path, stem: &str, f: &Frame, shown: &Shown) -> anyhow::Result<()> {
    let (w, h) = (f.gbuffer.width, f.gbuffer.height);
    for (label, img) in shown_images(f, shown) {
        let file = out.join(format!("{stem}-ao-{}.png", slug(label)));
        ao_png16(img, w, h)
            .save(&file)
            .with_context(|| file.display().to_string())?;
    }
    let exr = |file: String, px: &dyn Fn(usize) -> [f32; 3]| -> anyhow::Result<()> {
        let mut img = Rgb32FImage::new(w, h);
        for (k, p) in img.pixels_mut().enumerate() {
            *p = Rgb(px(k));
        }
        let path = out.join(file);
        img.save(&path).with_context(|| path.display().to_string())
    };
    let g = &f.gbuffer;
    exr(format!("{stem}-ao-reference.exr"), &|k| [f.reference[k]; 3])?;
    exr(format!("{stem}-gbuffer-position.exr"), &|k| {
        g.position[k].to_array()
    })?;
    exr(format!("{stem}-gbuffer-normal.exr"), &|k| {
        g.normal[k].to_array()
    })?;
    exr(format!("{stem}-gbuffer-depth-instance.exr"), &|k| {
        let hit = g.instance[k] != NO_INSTANCE;
        [
            if hit { g.depth[k] } else { -1.0 },
            if hit { g.instance[k] as f32 } else { -1.0 },
            hit as u8 as f32,
        ]
    })?;
    if !shown.open_causes.is_empty() {
        open_causes_png(f, &shown.open_causes)
            .save(out.join(format!("{stem}-open-causes.png")))
            .with_context(|| format!("{stem}-open-causes.png"))?;
    }
    side_by_side(&out.join(format!("{stem}-frame.png")), f, shown)
}

/// Colours of the open causes, in [`psao_eval::OpenCause`]'s order:
/// instance unknown magenta, no point red, normal orange, distance yellow,
/// direction cyan, points open blue.
pub const OPEN_CAUSE_COLOURS: [[u8; 3]; 6] = [
    [255, 0, 255],
    [255, 0, 0],
    [255, 140, 0],
    [255, 255, 0],
    [0, 255, 255],
    [40, 90, 255],
];

/// The reference AO, dimmed, with each pixel left open where the reference
/// is dark painted in its cause's colour ([`OPEN_CAUSE_COLOURS`]).
fn open_causes_png(f: &Frame, causes: &[u8]) -> image::RgbImage {
    let (w, h) = (f.gbuffer.width, f.gbuffer.height);
    image::RgbImage::from_fn(w, h, |x, y| {
        let k = (y * w + x) as usize;
        match causes.get(k).copied().unwrap_or(0) {
            0 => {
                let v = (f.reference[k].clamp(0.0, 1.0) * 160.0) as u8;
                Rgb([v, v, v])
            }
            c => Rgb(OPEN_CAUSE_COLOURS[(c as usize - 1).min(5)]),
        }
    })
}

/// The images of a saved frame with their labels: the reference first,
/// then the shown methods.
fn shown_images<'a>(f: &'a Frame, shown: &'a Shown) -> Vec<(&'a str, &'a [f32])> {
    std::iter::once(("reference", f.reference.as_slice()))
        .chain(
            shown
                .images
                .iter()
                .map(|(label, img)| (label.as_str(), img.as_slice())),
        )
        .collect()
}

/// A file-name-safe form of a label.
pub fn slug(label: &str) -> String {
    let s: String = label
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '-'
            }
        })
        .collect();
    s.split('-')
        .filter(|p| !p.is_empty())
        .collect::<Vec<_>>()
        .join("-")
}

/// AO as a 16-bit greyscale image (0 = fully occluded, 65535 = open).
pub fn ao_png16(ao: &[f32], w: u32, h: u32) -> ImageBuffer<Luma<u16>, Vec<u16>> {
    ImageBuffer::from_fn(w, h, |x, y| {
        let v = ao[(y * w + x) as usize].clamp(0.0, 1.0);
        Luma([(v * 65535.0 + 0.5) as u16])
    })
}

/// The side-by-side picture of a saved frame: the shown methods' AO in
/// the top row, their absolute error against the reference (x4) in the
/// bottom row, labelled.
fn side_by_side(path: &Path, f: &Frame, shown: &Shown) -> anyhow::Result<()> {
    register_fonts()?;
    let (w, h) = (f.gbuffer.width as usize, f.gbuffer.height as usize);
    let shown = shown_images(f, shown);
    let label_h = 22usize;
    let (cols, rows) = (shown.len(), 2usize);
    let (cw, ch) = (cols * w, rows * (h + label_h));
    let mut buf = vec![255u8; cw * ch * 3];
    let put = |buf: &mut Vec<u8>, x0: usize, y0: usize, px: &dyn Fn(usize) -> [u8; 3]| {
        for y in 0..h {
            for x in 0..w {
                let o = ((y0 + y) * cw + x0 + x) * 3;
                buf[o..o + 3].copy_from_slice(&px(y * w + x));
            }
        }
    };
    for (c, (_, img)) in shown.iter().enumerate() {
        put(&mut buf, c * w, label_h, &|k| [to_srgb8(img[k]); 3]);
        if c > 0 {
            let err = error_map(&f.reference, img);
            put(&mut buf, c * w, 2 * label_h + h, &|k| {
                heat(err[k] * ERROR_GAIN)
            });
        } else {
            put(&mut buf, 0, 2 * label_h + h, &|k| {
                f.composite[3 * k..3 * k + 3].try_into().unwrap_or([0; 3])
            });
        }
    }
    {
        let root = BitMapBackend::with_buffer(&mut buf, (cw as u32, ch as u32)).into_drawing_area();
        let style = ("sans-serif", 15).into_font().color(&BLACK);
        for (c, (label, _)) in shown.iter().enumerate() {
            let x = (c * w + 4) as i32;
            root.draw_text(label, &style, (x, 4))?;
            let below = if c == 0 {
                "reference, composited".to_string()
            } else {
                format!("error x{ERROR_GAIN}")
            };
            root.draw_text(&below, &style, (x, (label_h + h + 4) as i32))?;
        }
        root.present()?;
    }
    image::RgbImage::from_raw(cw as u32, ch as u32, buf)
        .context("picture buffer has the wrong size")?
        .save(path)
        .with_context(|| path.display().to_string())
}

/// A black-red-yellow-white ramp for error maps (input clamped to [0, 1]).
fn heat(v: f32) -> [u8; 3] {
    let v = v.clamp(0.0, 1.0);
    let r = (v * 3.0).min(1.0);
    let g = (v * 3.0 - 1.0).clamp(0.0, 1.0);
    let b = (v * 3.0 - 2.0).clamp(0.0, 1.0);
    [r, g, b].map(|c| (c * 255.0 + 0.5) as u8)
}

//! Why the PSAO client left a pixel open: for each pixel it shows open
//! where the reference is dark, the first of eq. 3's tests that every
//! candidate point failed, or that the points it weighed hold open AO
//! themselves. The bench prints this beside "where the squared error lies".

use psao_codec::{Mirror, WeightParams, for_each_candidate, weight};

use crate::gbuffer::GBuffer;
use crate::pixel_ao::pixel_local;

/// A client value at least this high counts as open.
pub const SHOWN_OPEN: f32 = 0.999;
/// A reference below this counts as dark.
pub const REFERENCE_DARK: f32 = 0.9;

/// Why pixels were left open, as squared error and pixel counts per cause
/// (pixels shown open, at least [`SHOWN_OPEN`], where the reference is
/// below [`REFERENCE_DARK`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OpenReasons {
    /// Pixels whose instance the mirror does not hold (or holds without a
    /// transform).
    pub unknown: Cause,
    /// No point at all in the 2x2x2 cells around the pixel.
    pub no_points: Cause,
    /// Points there, none facing within T_n of the pixel's normal.
    pub normal: Cause,
    /// Points facing the right way, none within twice the radius.
    pub distance: Cause,
    /// Points facing the right way and within twice the radius, every one
    /// off the pixel's tangent plane (the direction test, T_d).
    pub direction: Cause,
    /// Points passed the tests, and the AO they hold is open: the point
    /// set does not see the darkness the pixel sees.
    pub points_open: Cause,
}

/// Squared error and pixels of one cause.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Cause {
    /// Summed squared error of the pixels.
    pub sse: f64,
    /// Number of pixels.
    pub pixels: u64,
}

impl Cause {
    fn add(&mut self, e: f64) {
        self.sse += e;
        self.pixels += 1;
    }
}

impl OpenReasons {
    /// The causes with their names, in the order of the tests.
    pub fn causes(&self) -> [(&'static str, Cause); 6] {
        [
            ("instance unknown", self.unknown),
            ("no point in the cells", self.no_points),
            ("no point facing the same way", self.normal),
            ("no point within 2r", self.distance),
            ("every point off the tangent plane", self.direction),
            ("points open themselves", self.points_open),
        ]
    }

    /// Adds another image's counts.
    pub fn merge(&mut self, o: &OpenReasons) {
        for (a, b) in [
            (&mut self.unknown, o.unknown),
            (&mut self.no_points, o.no_points),
            (&mut self.normal, o.normal),
            (&mut self.distance, o.distance),
            (&mut self.direction, o.direction),
            (&mut self.points_open, o.points_open),
        ] {
            a.sse += b.sse;
            a.pixels += b.pixels;
        }
    }
}

/// Why one pixel was left open.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OpenCause {
    /// See [`OpenReasons::unknown`].
    Unknown,
    /// See [`OpenReasons::no_points`].
    NoPoints,
    /// See [`OpenReasons::normal`].
    Normal,
    /// See [`OpenReasons::distance`].
    Distance,
    /// See [`OpenReasons::direction`].
    Direction,
    /// See [`OpenReasons::points_open`].
    PointsOpen,
}

impl OpenReasons {
    fn of(&mut self, cause: OpenCause) -> &mut Cause {
        match cause {
            OpenCause::Unknown => &mut self.unknown,
            OpenCause::NoPoints => &mut self.no_points,
            OpenCause::Normal => &mut self.normal,
            OpenCause::Distance => &mut self.distance,
            OpenCause::Direction => &mut self.direction,
            OpenCause::PointsOpen => &mut self.points_open,
        }
    }
}

/// Why covered pixel `k` of `g` would reconstruct as open from `mirror`:
/// the first of eq. 3's tests (with the second pass's radius 2r) that
/// every candidate point fails, or [`OpenCause::PointsOpen`] when some
/// pass. `None` for a pixel that sees nothing.
pub fn open_cause(mirror: &Mirror, g: &GBuffer, k: usize) -> Option<OpenCause> {
    if g.instance.get(k).is_none_or(|&id| id == crate::NO_INSTANCE) {
        return None;
    }
    let Some((inst, (x, n))) = pixel_local(mirror, g, k) else {
        return Some(OpenCause::Unknown);
    };
    let params = WeightParams::of(inst.def());
    let wide = WeightParams {
        radius: 2.0 * params.radius,
        ..params
    };
    let (mut any, mut facing, mut near, mut weighed) = (false, false, false, false);
    for_each_candidate(inst, x, |p, n_p, _| {
        any = true;
        if n_p.dot(n) > params.t_n {
            facing = true;
            if p.distance(x) < wide.radius {
                near = true;
                weighed |= weight(p, n_p, x, n, &wide) > 0.0;
            }
        }
    });
    Some(match (any, facing, near, weighed) {
        (false, ..) => OpenCause::NoPoints,
        (true, false, ..) => OpenCause::Normal,
        (true, true, false, _) => OpenCause::Distance,
        (true, true, true, false) => OpenCause::Direction,
        _ => OpenCause::PointsOpen,
    })
}

/// Classifies the pixels of `test` (the client's image of `mirror` on `g`)
/// left open where `reference` is dark. Images shorter than the G-buffer
/// are read as far as they go.
pub fn open_reasons(mirror: &Mirror, g: &GBuffer, reference: &[f32], test: &[f32]) -> OpenReasons {
    let mut out = OpenReasons::default();
    for (k, (&r, &t)) in reference.iter().zip(test).enumerate().take(g.pixels()) {
        if t < SHOWN_OPEN || r >= REFERENCE_DARK {
            continue;
        }
        if let Some(cause) = open_cause(mirror, g, k) {
            out.of(cause).add(((t - r) as f64).powi(2));
        }
    }
    out
}

//! Grid layout (paper 3.2): cell size and dims from an instance's local
//! bounds and point density, hash table sized as the paper does.

use glam::{UVec3, Vec3};
use psao_codec::{InstanceDef, Limits, POINT_FORMAT_PACKED32, key_fits};

use crate::error::{SceneError, check_param};
use crate::precision::f32_spacing;

/// Choices for [`layout`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayoutParams {
    /// Points a cell crossed by a flat surface should hold on average
    /// (slots are `cell_capacity`; the paper's 7).
    pub points_per_cell: f32,
    /// Slots per cell.
    pub cell_capacity: u8,
    /// Entries per bucket.
    pub bucket_capacity: u8,
    /// Empty cells added around the bounds on every side (room for motion).
    pub margin_cells: u32,
    /// Normal threshold T_n.
    pub t_n: f32,
    /// Direction threshold T_d.
    pub t_d: f32,
    /// Whether a full cell continues in an overflow chain
    /// (spec/wire-format.md 7.4: no point is dropped below `17 *
    /// cell_capacity` in a cell) rather than dropping its extra points
    /// (false: for clients that cannot decode chains, and the baseline).
    pub overflow: bool,
}

impl Default for LayoutParams {
    fn default() -> Self {
        LayoutParams {
            points_per_cell: 4.0,
            cell_capacity: 7,
            bucket_capacity: 8,
            margin_cells: 1,
            t_n: 0.1,
            t_d: 0.7,
            overflow: true,
        }
    }
}

/// Lays out the grid of one instance: `bounds` are its local bounds
/// (without margin cells, padded by four f32 spacings so that points
/// rounded just outside a face stay in the grid),
/// `area` its surface area (both sides counted for a double-sided mesh),
/// `points` how many points it holds, `radius` their Poisson radius.
///
/// The cell edge `c` makes a flat surface put `points_per_cell` points in a
/// cell it crosses (`density * c^2`), and is at least `2 * radius` so the
/// 2x2x2 neighbourhood covers the interpolation radius. The table holds
/// `4 x expected cells / 8` buckets (rounded up to a power of two), as in
/// the paper; the pool holds twice the expected cells.
pub fn layout(
    instance: usize,
    bounds: (Vec3, Vec3),
    area: f32,
    points: usize,
    radius: f32,
    p: &LayoutParams,
) -> Result<InstanceDef, SceneError> {
    check_param(
        "points_per_cell",
        p.points_per_cell as f64,
        0.01,
        1e6,
        "in [0.01, 1e6]",
    )?;
    check_param(
        "cell_capacity",
        p.cell_capacity as f64,
        1.0,
        8.0,
        "in 1..=8",
    )?;
    check_param(
        "bucket_capacity",
        p.bucket_capacity as f64,
        1.0,
        16.0,
        "in 1..=16",
    )?;
    check_param(
        "margin_cells",
        p.margin_cells as f64,
        0.0,
        1e3,
        "at most 1000",
    )?;
    check_param("radius", radius as f64, 1e-30, 1e30, "finite and positive")?;
    check_param("area", area as f64, 0.0, 1e30, "finite and not negative")?;
    if !bounds.0.is_finite() || !bounds.1.is_finite() {
        return Err(SceneError::Parameter {
            name: "bounds",
            value: f64::NAN,
            rule: "finite",
        });
    }
    // A point on a face of the bounds can round an f32 spacing or two
    // outside it (its barycentric weights sum to 1 only within rounding).
    // Margin cells hold such points; without them, pad the bounds by four
    // spacings at the largest coordinate so that they stay in the grid.
    let pad = if p.margin_cells == 0 {
        4.0 * f32_spacing(bounds.0.abs().max(bounds.1.abs()).max_element())
    } else {
        0.0
    };
    let bounds = (bounds.0 - pad, bounds.1 + pad);
    let extent = (bounds.1 - bounds.0).max(Vec3::ZERO);
    let density = points.max(1) as f32 / area.max(f32::MIN_POSITIVE);
    // No finer than 10^6 cells along the longest side (the key rule allows
    // far fewer cells in total anyway); the loop below coarsens further.
    let floor = extent.max_element() * 1e-6;
    let mut c = (p.points_per_cell / density)
        .sqrt()
        .max(2.0 * radius)
        .max(floor);
    if !c.is_finite() || c <= 0.0 {
        c = extent.max_element().max(1e-3);
    }
    let margin = p.margin_cells as f32;
    let mut dims;
    let mut tries = 0;
    loop {
        let d = (extent / c).floor() + 1.0 + 2.0 * margin;
        dims = UVec3::new(d.x as u32, d.y as u32, d.z as u32).max(UVec3::ONE);
        // Odd Dx and Dy make eq. 1's strides along y and z (17 Dx and
        // 31 Dx Dy) odd, so that `key mod T` (T a power of two) runs through
        // every bucket along each axis: with even ones a row of cells
        // along z reaches only T / 2^k buckets (a 32 x 32 x 139 grid's
        // columns: 1 in 8), and a long shape fills them.
        let odd = UVec3::new(dims.x | 1, dims.y | 1, dims.z);
        if d.max_element() < u32::MAX as f32 && key_fits(odd) {
            dims = odd;
            break;
        }
        if d.max_element() < u32::MAX as f32 && key_fits(dims) {
            break;
        }
        c *= 1.25;
        tries += 1;
        if tries > 200 {
            return Err(SceneError::GridTooLarge { instance });
        }
    }
    let expected_cells = ((area as f64 / (c as f64 * c as f64)) * 1.5)
        .ceil()
        .max(1.0) as u64;
    let table_log2 = table_log2_for(expected_cells, p.bucket_capacity);
    let total_cells = dims.x as u64 * dims.y as u64 * dims.z as u64;
    let cell_pool = (2 * expected_cells).clamp(16, total_cells.max(16));
    // Receivers with default limits must accept the instance.
    let limits = Limits::default();
    if table_log2 > limits.max_table_log2 as u32 || cell_pool > limits.max_cell_pool as u64 {
        return Err(SceneError::GridTooLarge { instance });
    }
    let (table_log2, cell_pool) = (table_log2 as u8, cell_pool as u32);
    let def = InstanceDef {
        origin: bounds.0 - Vec3::splat(margin * c),
        cell_size: Vec3::splat(c),
        dims,
        table_log2,
        bucket_capacity: p.bucket_capacity,
        cell_capacity: p.cell_capacity,
        cell_pool,
        point_format: POINT_FORMAT_PACKED32,
        overflow: p.overflow,
        radius,
        t_n: p.t_n,
        t_d: p.t_d,
    };
    def.validate()
        .map_err(|error| SceneError::Grid { instance, error })?;
    Ok(def)
}

/// Grows a laid-out grid's table and pool to hold `positions` (instance
/// points where the grid stores them) when the area estimate of [`layout`]
/// falls short: on a folded or crowded mesh (a skin's bind pose, a
/// model's overlapping parts) more cells are occupied, and with
/// [`InstanceDef::overflow`] crowded cells take links of their chains, so
/// buckets fill and points are dropped. The cells the points need (each
/// occupied cell, and with chains `ceil(n / cell_capacity)` for a cell of
/// `n` points) are counted, a quarter is added for motion, and the table
/// (`4 x cells / bucket_capacity` entries, a power of two) and the pool
/// (twice the cells) are sized as [`layout`] sizes them, never smaller
/// than it did and within the default receiver limits. Where the points'
/// keys and links would still overfill a bucket, the table doubles, up to
/// four times.
pub fn fit_to_points(def: InstanceDef, positions: &[Vec3]) -> InstanceDef {
    let mut per_cell: std::collections::HashMap<u32, u32> = Default::default();
    for &p in positions {
        if let Some(c) = def.cell_of(p) {
            *per_cell.entry(def.key(c)).or_default() += 1;
        }
    }
    // Pool cells a grid cell of n points takes: its links, up to the
    // chain's end (points past it are dropped anyway).
    let cap = def.cell_capacity as u64;
    let links = |n: u32| (n as u64).div_ceil(cap).min(def.max_links() as u64 + 1);
    let needed: u64 = per_cell.values().map(|&n| links(n)).sum();
    let cells = needed + needed / 4;
    let limits = Limits::default();
    let table_log2 =
        table_log2_for(cells, def.bucket_capacity).min(limits.max_table_log2 as u32) as u8;
    let cell_pool = (2 * cells).min(limits.max_cell_pool as u64) as u32;
    let mut grown = InstanceDef {
        table_log2: def.table_log2.max(table_log2),
        cell_pool: def.cell_pool.max(cell_pool),
        ..def
    };
    // Where the points' own keys and links would overfill a bucket, the
    // table doubles (a few times at most, within the limits): eq. 1's
    // `key mod T` clusters on some grids whatever the load.
    for _ in 0..4 {
        let mut load: std::collections::HashMap<u32, u32> = Default::default();
        for (&key, &n) in &per_cell {
            for link in 0..links(n) as u8 {
                *load.entry(grown.bucket_of_link(key, link)).or_default() += 1;
            }
        }
        let crowded = load.values().any(|&n| n > grown.bucket_capacity as u32);
        let larger = InstanceDef {
            table_log2: grown.table_log2 + 1,
            ..grown
        };
        if !crowded || larger.table_log2 > limits.max_table_log2 || larger.validate().is_err() {
            break;
        }
        grown = larger;
    }
    if grown.validate().is_ok() { grown } else { def }
}

/// The paper's table size for `cells` expected cells: `4 x cells /
/// bucket_capacity` buckets, rounded up to a power of two (its log2).
fn table_log2_for(cells: u64, bucket_capacity: u8) -> u32 {
    let buckets = (4 * cells).div_ceil(bucket_capacity as u64).max(1);
    64 - (buckets - 1).leading_zeros()
}

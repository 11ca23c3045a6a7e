//! A synthetic server stream for benchmarks and the codec demo: a 16 m x
//! 16 m floor and a wall covered with points, a 1 m box sliding across the
//! floor, AO darkening around the box plus a slow wave drifting over the
//! whole grid. Each step updates points with the paper's thresholds.

use glam::{UVec3, Vec3};
use psao_codec::{
    Compression, Encoder, EncoderConfig, GridTable, InstanceDef, POINT_FORMAT_PACKED32, Thresholds,
};

/// Deterministic xorshift generator.
pub struct Rng(u64);

impl Rng {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Rng {
        Rng(seed.max(1))
    }

    /// Uniform in [0, 1).
    pub fn next_f32(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// The scene and its table.
pub struct Synthetic {
    /// The server's table.
    pub table: GridTable,
    rest: Vec<Vec3>,
    normals: Vec<Vec3>,
    on_box: Vec<bool>,
    /// Frame counter.
    pub frame: u32,
}

/// Points per square metre.
pub const DENSITY: f32 = 48.0;

/// The grid: 68 x 18 x 68 cells of 0.25 m, 4096 buckets of 8, cells of 7.
pub fn def() -> InstanceDef {
    InstanceDef {
        origin: Vec3::splat(-0.5),
        cell_size: Vec3::splat(0.25),
        dims: UVec3::new(68, 18, 68),
        table_log2: 12,
        bucket_capacity: 8,
        cell_capacity: 7,
        cell_pool: 8192,
        point_format: POINT_FORMAT_PACKED32,
        overflow: false,
        radius: 0.12,
        t_n: 0.1,
        t_d: 0.7,
    }
}

impl Synthetic {
    /// Builds the scene (deterministic for a seed) and sets every point once.
    pub fn new(seed: u64) -> Synthetic {
        let mut rng = Rng::new(seed);
        let mut rest = Vec::new();
        let mut normals = Vec::new();
        let mut on_box = Vec::new();
        // Jittered (stratified) samples: about as even as the paper's
        // Poisson-disk elimination, so cells rarely overflow.
        let mut area =
            |rest: &mut Vec<Vec3>, origin: Vec3, u: Vec3, v: Vec3, n: Vec3, is_box: bool| {
                let nu = (u.length() * DENSITY.sqrt()).round().max(1.0) as usize;
                let nv = (v.length() * DENSITY.sqrt()).round().max(1.0) as usize;
                for i in 0..nu {
                    for j in 0..nv {
                        let a = (i as f32 + rng.next_f32()) / nu as f32;
                        let b = (j as f32 + rng.next_f32()) / nv as f32;
                        rest.push(origin + u * a + v * b);
                        normals.push(n);
                        on_box.push(is_box);
                    }
                }
            };
        area(
            &mut rest,
            Vec3::new(0.0, 0.02, 0.0),
            Vec3::X * 16.0,
            Vec3::Z * 16.0,
            Vec3::Y,
            false,
        );
        area(
            &mut rest,
            Vec3::new(0.02, 0.0, 0.0),
            Vec3::Y * 3.5,
            Vec3::Z * 16.0,
            Vec3::X,
            false,
        );
        // The box, centred at the origin; moved each frame.
        let h = 0.5;
        for (n, u, v) in [
            (Vec3::Y, Vec3::X, Vec3::Z),
            (Vec3::X, Vec3::Y, Vec3::Z),
            (Vec3::NEG_X, Vec3::Y, Vec3::Z),
            (Vec3::Z, Vec3::X, Vec3::Y),
            (Vec3::NEG_Z, Vec3::X, Vec3::Y),
        ] {
            area(&mut rest, n * h - (u + v) * h, u, v, n, true);
        }
        let table = GridTable::new(1, def(), rest.len() as u32).expect("valid grid");
        let mut s = Synthetic {
            table,
            rest,
            normals,
            on_box,
            frame: 0,
        };
        for i in 0..s.rest.len() {
            let (p, n, ao) = s.point(i);
            s.table.set_point(i as u32, p, n, ao).expect("id in range");
        }
        s
    }

    /// Number of points.
    pub fn points(&self) -> usize {
        self.rest.len()
    }

    fn box_centre(&self) -> Vec3 {
        let t = self.frame as f32 / 60.0;
        Vec3::new(3.0 + t % 10.0, 0.52, 8.0 + (t * 0.7).sin() * 3.0)
    }

    /// Position, normal and AO of point `i` at the current frame.
    pub fn point(&self, i: usize) -> (Vec3, Vec3, f32) {
        let c = self.box_centre();
        let p = if self.on_box[i] {
            self.rest[i] + c
        } else {
            self.rest[i]
        };
        let d = (p - c).length();
        let wave = 0.12 * (0.04 * self.frame as f32 + p.x * 0.35 + p.z * 0.2).sin();
        let wall = 0.25 * (-p.x * 2.0).exp();
        let near_box = if self.on_box[i] {
            0.0
        } else {
            0.6 * (-(d * d) / 0.6).exp()
        };
        (
            p,
            self.normals[i],
            (0.8 + wave - wall - near_box).clamp(0.0, 1.0),
        )
    }

    /// Advances one frame and updates every point whose change passes the
    /// thresholds. Returns how many were updated.
    pub fn step(&mut self, thresholds: &Thresholds) -> usize {
        self.frame += 1;
        let mut updated = 0;
        for i in 0..self.rest.len() {
            let (p, n, ao) = self.point(i);
            if self
                .table
                .update_point(i as u32, p, n, ao, thresholds)
                .expect("id in range")
            {
                updated += 1;
            }
        }
        updated
    }
}

/// The codec bench's stream, encoded: the keyframe of [`Synthetic::new`]`(7)`
/// after its first updates, then one delta per [`Synthetic::step`] with
/// the paper's thresholds (empty deltas left out). The codec's
/// `codec_throughput`, psao-ffi's `c_boundary` and psao-wasm's
/// `bench_stream` measure this stream.
pub struct BenchStream {
    /// The keyframe.
    pub keyframe: Vec<u8>,
    /// The deltas, in order.
    pub deltas: Vec<Vec<u8>>,
    /// Points carried by the deltas.
    pub points: u64,
}

/// The frames the codec benches run over.
pub const BENCH_FRAMES: usize = 120;

impl BenchStream {
    /// Encodes [`BENCH_FRAMES`] steps of the bench stream with `compression`
    /// (`zstd_level` for zstd), without CRCs. Panics if the codec was built
    /// without `compression` (a benchmark's setup, not untrusted input).
    pub fn encode(compression: Compression, zstd_level: i32) -> BenchStream {
        let mut s = Synthetic::new(7);
        s.table.take_dirty();
        let mut enc = Encoder::new(EncoderConfig {
            compression,
            zstd_level,
            checksum: false,
            ..Default::default()
        });
        let mut kf = enc.keyframe();
        kf.snapshot(&s.table).expect("no pending changes");
        let keyframe = kf
            .finish()
            .expect("encode")
            .expect("keyframe")
            .bytes
            .to_vec();
        let th = Thresholds::default();
        let (mut deltas, mut points) = (Vec::new(), 0u64);
        for _ in 0..BENCH_FRAMES {
            s.step(&th);
            let mut d = enc.delta();
            d.changes(&mut s.table);
            if let Some(f) = d.finish().expect("encode") {
                points += f.stats.points as u64;
                deltas.push(f.bytes.to_vec());
            }
        }
        BenchStream {
            keyframe,
            deltas,
            points,
        }
    }
}

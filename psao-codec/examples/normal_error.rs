//! Measures the worst angle between unit normals and their decoded 8-bit
//! octahedral code over a dense Fibonacci sphere plus jittered axes.
use glam::Vec3;
use psao_codec::wire::point::{decode_normal, encode_normal};

fn main() {
    let n = 4_000_000u32;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let (mut worst, mut sum) = (0f64, 0f64);
    let mut worst_at = Vec3::ZERO;
    for i in 0..n {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let r = (1.0 - z * z).sqrt();
        let phi = golden * i as f64;
        let v = Vec3::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32);
        let d = decode_normal(encode_normal(v)).dot(v).clamp(-1.0, 1.0) as f64;
        let a = d.acos().to_degrees();
        sum += a;
        if a > worst {
            worst = a;
            worst_at = v;
        }
    }
    println!(
        "samples {n}: max angle {worst:.3} deg at {worst_at:?}, mean {:.3} deg",
        sum / n as f64
    );
}

//! Writes the codec bench's stream (the test kit's synthetic scene, 120
//! frames, the paper's thresholds: what `psao-codec`'s `codec_throughput`
//! and psao-ffi's `c_boundary` measure) as capture files (spec/capture.md),
//! one per compression, for `decode_capture` natively and
//! `tests/node/decode_capture.mjs` in WebAssembly (`scripts/wasm-bench.sh`
//! runs both; BENCHMARKS.md). Frames are 1/60 s apart.
//!
//! `cargo run --release -p psao-wasm --example bench_stream -- DIR`
//! writes `DIR/bench-none.cap`, `DIR/bench-lz4.cap`, `DIR/bench-zstd3.cap`.

use std::io::BufWriter;
use std::path::PathBuf;

use psao_codec::Compression;
use psao_proto::capture::CaptureWriter;
use psao_tests::synthetic::BenchStream;

fn main() {
    let dir = PathBuf::from(
        std::env::args()
            .nth(1)
            .expect("usage: bench_stream DIR (the folder the captures go to)"),
    );
    std::fs::create_dir_all(&dir).expect("the output folder");
    for (name, compression, level) in [
        ("none", Compression::None, 0),
        ("lz4", Compression::Lz4, 0),
        ("zstd3", Compression::Zstd, 3),
    ] {
        let s = BenchStream::encode(compression, level);
        let path = dir.join(format!("bench-{name}.cap"));
        let file = std::fs::File::create(&path).expect("the capture file");
        let mut w = CaptureWriter::new(BufWriter::new(file)).expect("the header");
        let mut bytes = 0;
        for (i, f) in std::iter::once(&s.keyframe).chain(&s.deltas).enumerate() {
            w.write(i as u64 * 1_000_000 / 60, f).expect("a record");
            bytes += f.len();
        }
        w.finish().expect("written");
        println!(
            "{}: {} frames, {bytes} bytes, {} points in the deltas",
            path.display(),
            s.deltas.len() + 1,
            s.points
        );
    }
}

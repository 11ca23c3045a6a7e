//! Decode+apply of a capture file (spec/capture.md) through the bindings,
//! natively: the native half of the wasm-against-native comparison
//! (`tests/node/decode_capture.mjs` is the WebAssembly half; BENCHMARKS.md).
//! Each repetition decodes every frame into a fresh decoder.
//!
//! `cargo run --release -p psao-wasm --example decode_capture -- FILE [REPS]`

use std::time::Instant;

use psao_proto::capture::CaptureReader;
use psao_wasm::WasmDecoder;

fn main() {
    let mut args = std::env::args().skip(1);
    let path = args.next().expect("usage: decode_capture FILE [REPS]");
    let reps: usize = args.next().map_or(20, |r| r.parse().expect("REPS"));
    let file = std::fs::File::open(&path).expect("the capture file");
    let mut reader =
        CaptureReader::new(std::io::BufReader::new(file), 64 << 20).expect("a capture");
    let mut frames = Vec::new();
    while let Some(r) = reader.next_record() {
        frames.push(r.expect("a record").frame);
    }
    let bytes: usize = frames.iter().map(|f| f.len()).sum();
    let mut best = f64::MAX;
    let mut total = 0.0;
    for _ in 0..reps {
        let mut d = WasmDecoder::with_default_limits();
        let t = Instant::now();
        for f in &frames {
            d.receive(f).expect("the frame applies");
        }
        let s = t.elapsed().as_secs_f64();
        best = best.min(s);
        total += s;
        assert!(d.digest().is_some());
    }
    println!(
        "native: {} frames, {bytes} bytes; best {:.3} ms, mean {:.3} ms per pass ({:.2} us per frame, {:.0} MB/s at best)",
        frames.len(),
        best * 1e3,
        total / reps as f64 * 1e3,
        best * 1e6 / frames.len() as f64,
        bytes as f64 / best / 1e6
    );
}

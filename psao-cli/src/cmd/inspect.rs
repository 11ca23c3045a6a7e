//! `psao inspect`: decodes a capture file (spec/capture.md) frame by frame
//! and prints what each frame is and does to a mirror.

use std::io::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;
use psao_codec::wire::FrameHeader;
use psao_codec::{Decoder, Event, Limits};
use psao_proto::capture::CaptureReader;

/// Arguments of `psao inspect`.
#[derive(clap::Args)]
pub struct Args {
    /// The capture file.
    file: PathBuf,
    /// Print only the summary.
    #[arg(long)]
    quiet: bool,
}

/// Decodes the file and prints a line per frame and a summary. Output
/// errors are returned, not panicked on: a reader that closes the pipe
/// early (`psao inspect FILE | head`) ends the command quietly (see
/// `main`'s broken-pipe rule).
pub fn run(args: Args) -> anyhow::Result<()> {
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let path = &args.file;
    let file = std::fs::File::open(path).with_context(|| path.display().to_string())?;
    let limits = Limits::default();
    let reader = CaptureReader::new(std::io::BufReader::new(file), limits.max_frame_bytes)
        .with_context(|| path.display().to_string())?;
    let mut decoder = Decoder::new(limits);
    let (mut n, mut keyframes, mut bytes, mut failed) = (0u64, 0u64, 0u64, 0u64);
    let mut last_time = 0;
    for record in reader {
        let r = record.with_context(|| path.display().to_string())?;
        n += 1;
        bytes += r.frame.len() as u64;
        last_time = r.time_us;
        let header = FrameHeader::parse(&r.frame);
        let outcome = match decoder.receive(&r.frame) {
            Ok(Event::Applied { sequence, keyframe }) => {
                keyframes += keyframe as u64;
                format!("applied, mirror at {sequence}")
            }
            Ok(Event::Stale { .. }) => "stale".to_string(),
            Ok(Event::NeedKeyframe { have, .. }) => {
                format!("needs a keyframe (mirror at {have:?})")
            }
            Ok(other) => format!("{other:?}"),
            Err(e) => {
                failed += 1;
                format!("error: {e}")
            }
        };
        if !args.quiet {
            match header {
                Ok(h) => writeln!(
                    out,
                    "#{n:<6} {:9.3} ms {:7} bytes  {} seq {:<6} base {:<6} {:?} {} messages  -> {outcome}",
                    r.time_us as f64 / 1e3,
                    r.frame.len(),
                    if h.keyframe { "keyframe" } else { "delta   " },
                    h.sequence,
                    h.base_sequence,
                    h.compression,
                    h.message_count,
                ),
                Err(e) => writeln!(
                    out,
                    "#{n:<6} {:9.3} ms {:7} bytes  bad header: {e}",
                    r.time_us as f64 / 1e3,
                    r.frame.len()
                ),
            }?;
        }
    }
    let instances = decoder.mirror().instances().count();
    writeln!(
        out,
        "{}: {n} frames ({keyframes} keyframes, {failed} failed), {bytes} bytes over {:.3} s; mirror at sequence {:?} with {instances} instances",
        path.display(),
        last_time as f64 / 1e6,
        decoder.mirror().sequence()
    )?;
    out.flush()?;
    Ok(())
}

//! `psao`: the PSAO command line. `main` parses, sets up logging and
//! dispatches; each subcommand lives in its own module under [`cmd`] (or
//! [`bench`](mod@bench)) with its arguments and its `run`.
//!
//! - `psao demo`: server and client in one process over loopback QUIC on
//!   the embedded default scene, with a live status line and a summary;
//! - `psao serve`: a server for clients elsewhere;
//! - `psao view`: a headless client;
//! - `psao record`: a client that writes what it receives to a capture
//!   file (spec/capture.md);
//! - `psao inspect`: decodes a capture file frame by frame;
//! - `psao conformance client`: the conformance kit, driving a server
//!   under test through the spec's cases;
//! - `psao bench`: accuracy against run time (PSAO, per-pixel RTAO, SAO
//!   against a ray-traced reference), with a CSV, a markdown table, charts
//!   and a side-by-side image.

mod bench;
mod cmd;
mod memory;

use std::process::ExitCode;

use anyhow::Context as _;
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "psao",
    version,
    about = "Point-based split ambient occlusion: server, client and demo"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Server and clients in one process over loopback QUIC, on the
    /// embedded default scene; prints live figures and a summary.
    Demo(cmd::demo::Args),
    /// Serve a scene to clients.
    Serve(cmd::serve::Args),
    /// Connect to a server and keep a mirror in sync, printing figures.
    View(cmd::view::Args),
    /// Connect to a server and write every frame received to a capture
    /// file (spec/capture.md).
    Record(cmd::record::Args),
    /// Accuracy against run time: PSAO at several densities and server
    /// rates, per-pixel RTAO and SAO against a per-pixel ray-traced
    /// reference; writes bench.csv, bench.md, charts and images.
    Bench(bench::BenchArgs),
    /// Decode a capture file frame by frame and print what each frame is
    /// and does to a mirror.
    Inspect(cmd::inspect::Args),
    /// The conformance kit (spec/session.md): `psao conformance client
    /// --connect ADDR --fingerprint HEX` drives a server under test
    /// through the spec's cases and reports each.
    Conformance(cmd::conformance::Args),
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                // moq-net warns of every subscription a relay ends as a
                // broadcast closes: only its errors by default.
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn,moq_net=error")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Demo(args) => on_runtime(cmd::demo::run(args)),
        Command::Serve(args) => on_runtime(cmd::serve::run(args)),
        Command::View(args) => on_runtime(cmd::view::run(args)),
        Command::Record(args) => on_runtime(cmd::record::run(args)),
        Command::Bench(args) => bench::run(args),
        Command::Inspect(args) => cmd::inspect::run(args),
        Command::Conformance(args) => on_runtime(cmd::conformance::run(args)),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        // The reader of our output went away (`psao inspect FILE | head`):
        // nothing is wrong, and there is no one left to tell.
        Err(e) if is_broken_pipe(&e) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Whether an error comes from writing to a closed pipe.
fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// Runs a networked subcommand on a multi-threaded tokio runtime.
fn on_runtime(task: impl Future<Output = anyhow::Result<()>>) -> anyhow::Result<()> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the runtime")?
        .block_on(task)
}

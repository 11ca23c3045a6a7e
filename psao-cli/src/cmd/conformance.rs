//! `psao conformance`: the conformance kit of psao-conformance from the
//! command line. `psao conformance client --connect ADDR --fingerprint
//! HEX` plays the client: it drives the server under test through the
//! cases of spec/session.md and prints a line per case and a summary.

use std::path::PathBuf;

use anyhow::Context as _;
use psao_conformance::probe::Target;
use psao_conformance::server_cases;

use crate::cmd::common::ServerArgs;

/// Arguments of `psao conformance`.
#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    mode: Mode,
}

#[derive(clap::Subcommand)]
enum Mode {
    /// Play the client: drive a server under test through the spec's
    /// cases (handshake variants, malformed and oversized uplink, the rate
    /// limit, keyframe requests of every reason, moves, cameras, digests,
    /// closing), one connection per case.
    Client(ClientArgs),
}

/// Arguments of `psao conformance client`.
#[derive(clap::Args)]
struct ClientArgs {
    #[command(flatten)]
    server: ServerArgs,
    /// Run only the cases whose id starts with this (e.g. `uplink.`).
    #[arg(long, default_value = "")]
    cases: String,
    /// Write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write the report as JUnit XML here.
    #[arg(long)]
    junit: Option<PathBuf>,
    /// List the cases and exit.
    #[arg(long)]
    list: bool,
}

/// Runs the kit; an error (exit 1) when a case failed.
pub async fn run(args: Args) -> anyhow::Result<()> {
    let Mode::Client(a) = args.mode;
    if a.list {
        for c in server_cases::cases() {
            println!("{} ({}): {}", c.id, c.section, c.title);
        }
        return Ok(());
    }
    let target = Target {
        addr: a.server.connect,
        trust: a.server.trust()?,
        server_name: a.server.name.clone(),
    };
    let report = server_cases::run(&target, &a.cases).await;
    if report.cases.is_empty() {
        anyhow::bail!("no case id starts with `{}` (see --list)", a.cases);
    }
    for c in &report.cases {
        println!("{}", c.line());
    }
    println!("{}", report.summary());
    if let Some(p) = &a.json {
        std::fs::write(p, report.to_json()).with_context(|| p.display().to_string())?;
    }
    if let Some(p) = &a.junit {
        std::fs::write(p, report.to_junit("psao-conformance client"))
            .with_context(|| p.display().to_string())?;
    }
    if !report.ok() {
        anyhow::bail!("{} against {}", report.summary(), report.target);
    }
    Ok(())
}

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
    /// Play the server: wait for one client under test and take it through
    /// a late join, a gap, a corrupt frame, a resynchronization with
    /// NOTICE 2, every NOTICE code, a frame at its exact max_frame_bytes, a
    /// wrong DIGEST and shutdown, checking
    /// what it sends back. Prints the certificate fingerprint to pin.
    Server(ServerModeArgs),
}

/// Arguments of `psao conformance server`.
#[derive(clap::Args)]
struct ServerModeArgs {
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1:4433")]
    bind: std::net::SocketAddr,
    /// Seconds to wait for the client under test.
    #[arg(long, default_value_t = 60)]
    wait: u64,
    #[command(flatten)]
    out: Outputs,
}

/// Where reports go besides stdout.
#[derive(clap::Args)]
struct Outputs {
    /// Write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write the report as JUnit XML here.
    #[arg(long)]
    junit: Option<PathBuf>,
}

impl Outputs {
    /// Prints the report, writes the files, and fails if a case failed.
    fn finish(&self, report: &psao_conformance::Report, suite: &str) -> anyhow::Result<()> {
        for c in &report.cases {
            println!("{}", c.line());
        }
        println!("{}", report.summary());
        if let Some(p) = &self.json {
            std::fs::write(p, report.to_json()).with_context(|| p.display().to_string())?;
        }
        if let Some(p) = &self.junit {
            std::fs::write(p, report.to_junit(suite)).with_context(|| p.display().to_string())?;
        }
        if !report.ok() {
            anyhow::bail!("{} against {}", report.summary(), report.target);
        }
        Ok(())
    }
}

/// Arguments of `psao conformance client`.
#[derive(clap::Args)]
struct ClientArgs {
    #[command(flatten)]
    server: ServerArgs,
    /// Run only the cases whose id starts with this (e.g. `uplink.`).
    #[arg(long, default_value = "")]
    cases: String,
    #[command(flatten)]
    out: Outputs,
    /// List the cases and exit.
    #[arg(long)]
    list: bool,
}

/// Runs the kit; an error (exit 1) when a case failed.
pub async fn run(args: Args) -> anyhow::Result<()> {
    let a = match args.mode {
        Mode::Client(a) => a,
        Mode::Server(a) => return run_server(a).await,
    };
    if a.list {
        for c in server_cases::cases() {
            println!("{} ({}): {}", c.id, c.section, c.title);
        }
        return Ok(());
    }
    let target = Target {
        addr: a.server.addr()?,
        trust: a.server.trust()?,
        server_name: a.server.name.clone(),
    };
    let report = server_cases::run(&target, &a.cases).await;
    if report.cases.is_empty() {
        anyhow::bail!("no case id starts with `{}` (see --list)", a.cases);
    }
    a.out.finish(&report, "psao-conformance client")
}

/// `psao conformance server`: one client under test, the scripted session.
async fn run_server(a: ServerModeArgs) -> anyhow::Result<()> {
    let identity = psao_proto::Identity::self_signed()?;
    let config = psao_proto::tls::server_config(&identity, std::time::Duration::from_secs(10))?;
    let endpoint = quinn::Endpoint::server(config, a.bind)
        .with_context(|| format!("cannot listen on {}", a.bind))?;
    let fp = psao_proto::tls::fingerprint_hex(&psao_proto::tls::fingerprint(&identity.chain[0]));
    println!("conformance server on {}", endpoint.local_addr()?);
    println!("certificate SHA-256 {fp}");
    println!("waiting {} s for the client under test", a.wait);
    let report =
        psao_conformance::client_cases::run(&endpoint, std::time::Duration::from_secs(a.wait))
            .await;
    endpoint.wait_idle().await;
    a.out.finish(&report, "psao-conformance server")
}

//! A UDP relay for testing clients and servers over a bad network on
//! loopback: it forwards datagrams between one client and a server,
//! dropping some, delaying each by a random amount (which reorders them),
//! and can cut the link entirely (a client that vanishes without closing).

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use tokio::net::UdpSocket;

/// How the relay mistreats datagrams.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Impairment {
    /// Probability of dropping a datagram, in [0, 1].
    pub drop: f64,
    /// Delay of every datagram.
    pub delay: Duration,
    /// Extra delay, uniform in [0, jitter): datagrams overtake each other.
    pub jitter: Duration,
    /// Seed of the random choices.
    pub seed: u64,
}

impl Default for Impairment {
    fn default() -> Self {
        Impairment {
            drop: 0.0,
            delay: Duration::ZERO,
            jitter: Duration::ZERO,
            seed: 1,
        }
    }
}

/// A running relay.
#[derive(Debug)]
pub struct Relay {
    addr: SocketAddr,
    cut: Arc<AtomicBool>,
    cut_down: Arc<AtomicBool>,
    dropped: Arc<AtomicU64>,
    forwarded: Arc<AtomicU64>,
    tasks: Vec<tokio::task::JoinHandle<()>>,
}

impl Relay {
    /// Starts a relay on 127.0.0.1 forwarding to `server`.
    pub async fn start(server: SocketAddr, imp: Impairment) -> std::io::Result<Relay> {
        let front = Arc::new(UdpSocket::bind("127.0.0.1:0").await?);
        let back = Arc::new(UdpSocket::bind("127.0.0.1:0").await?);
        back.connect(server).await?;
        let addr = front.local_addr()?;
        let cut = Arc::new(AtomicBool::new(false));
        let cut_down = Arc::new(AtomicBool::new(false));
        let dropped = Arc::new(AtomicU64::new(0));
        let forwarded = Arc::new(AtomicU64::new(0));
        let client: Arc<tokio::sync::Mutex<Option<SocketAddr>>> = Default::default();
        let mut tasks = Vec::new();
        for upstream in [true, false] {
            let (front, back, cut, cut_down, dropped, forwarded, client) = (
                front.clone(),
                back.clone(),
                cut.clone(),
                cut_down.clone(),
                dropped.clone(),
                forwarded.clone(),
                client.clone(),
            );
            tasks.push(tokio::spawn(async move {
                let mut rng = imp.seed ^ if upstream { 0x9E37_79B9 } else { 0x85EB_CA6B };
                let mut buf = vec![0u8; 65_536];
                loop {
                    let n = if upstream {
                        match front.recv_from(&mut buf).await {
                            Ok((n, from)) => {
                                *client.lock().await = Some(from);
                                n
                            }
                            Err(_) => continue,
                        }
                    } else {
                        match back.recv(&mut buf).await {
                            Ok(n) => n,
                            Err(_) => continue,
                        }
                    };
                    let r = next(&mut rng);
                    let blocked = cut.load(Ordering::Relaxed)
                        || (!upstream && cut_down.load(Ordering::Relaxed));
                    if blocked || r < imp.drop {
                        dropped.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    forwarded.fetch_add(1, Ordering::Relaxed);
                    let wait = imp.delay + imp.jitter.mul_f64(next(&mut rng));
                    let data = buf[..n].to_vec();
                    let (front, back, client) = (front.clone(), back.clone(), client.clone());
                    tokio::spawn(async move {
                        if !wait.is_zero() {
                            tokio::time::sleep(wait).await;
                        }
                        if upstream {
                            let _ = back.send(&data).await;
                        } else if let Some(to) = *client.lock().await {
                            let _ = front.send_to(&data, to).await;
                        }
                    });
                }
            }));
        }
        Ok(Relay {
            addr,
            cut,
            cut_down,
            dropped,
            forwarded,
            tasks,
        })
    }

    /// Where clients connect to.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Drops everything from now on (or forwards again).
    pub fn cut(&self, cut: bool) {
        self.cut.store(cut, Ordering::Relaxed);
    }

    /// Drops what the server sends from now on (or forwards it again),
    /// while the client's datagrams still reach the server.
    pub fn cut_downstream(&self, cut: bool) {
        self.cut_down.store(cut, Ordering::Relaxed);
    }

    /// Datagrams dropped so far.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Datagrams forwarded so far.
    pub fn forwarded(&self) -> u64 {
        self.forwarded.load(Ordering::Relaxed)
    }
}

impl Drop for Relay {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}

/// A uniform number in [0, 1) (xorshift64*).
fn next(s: &mut u64) -> f64 {
    *s ^= *s >> 12;
    *s ^= *s << 25;
    *s ^= *s >> 27;
    (s.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
}

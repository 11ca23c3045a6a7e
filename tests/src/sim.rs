//! A simulated link on a virtual clock, for driving the sans-IO session
//! cores without sockets (as quinn-proto's tests drive a `Pair`): what is
//! sent arrives after a latency plus a seeded random jitter (so units
//! overtake each other), some units are lost, and a unit occupies the
//! link for its length over the bandwidth. The same seed gives the same
//! run, byte for byte.

use std::collections::BinaryHeap;
use std::time::{Duration, Instant};

use bytes::Bytes;

/// A seeded pseudo-random source (SplitMix64): small, fast and the same on
/// every platform.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A source seeded with `seed`.
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// How a [`SimLink`] treats what it carries.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkModel {
    /// Delay of every unit.
    pub latency: Duration,
    /// Extra delay, uniform in [0, jitter): units overtake each other.
    pub jitter: Duration,
    /// Probability that a unit is lost, in [0, 1].
    pub loss: f64,
    /// Bytes per second the link carries.
    pub bandwidth: f64,
}

impl LinkModel {
    /// A reliable, ordered link (no jitter, no loss), like a QUIC stream.
    pub fn reliable(latency: Duration, bandwidth: f64) -> LinkModel {
        LinkModel {
            latency,
            jitter: Duration::ZERO,
            loss: 0.0,
            bandwidth,
        }
    }
}

#[derive(Debug, PartialEq, Eq)]
struct InFlight {
    at: Instant,
    /// Order of sending, to break ties in arrival time.
    n: u64,
    bytes: Bytes,
}

impl Ord for InFlight {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        // Earliest first out of a max-heap.
        (other.at, other.n).cmp(&(self.at, self.n))
    }
}

impl PartialOrd for InFlight {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

/// One direction of a simulated link.
#[derive(Debug)]
pub struct SimLink {
    /// How it treats units now (change it to congest the link).
    pub model: LinkModel,
    rng: Rng,
    in_flight: BinaryHeap<InFlight>,
    /// When the link is free to take the next unit.
    free_at: Option<Instant>,
    sent: u64,
    /// Units lost so far.
    pub lost: u64,
    /// Units that arrived before one sent earlier.
    pub overtaken: u64,
    last_delivered: u64,
}

impl SimLink {
    /// A link with `model`, its randomness seeded with `seed`.
    pub fn new(model: LinkModel, seed: u64) -> SimLink {
        SimLink {
            model,
            rng: Rng::new(seed),
            in_flight: BinaryHeap::new(),
            free_at: None,
            sent: 0,
            lost: 0,
            overtaken: 0,
            last_delivered: 0,
        }
    }

    /// Whether the link can take a unit at `now` (the previous one has
    /// been put on the wire).
    pub fn is_free(&self, now: Instant) -> bool {
        self.free_at.is_none_or(|t| t <= now)
    }

    /// Sends `bytes` at `now`: it occupies the link for its length over the
    /// bandwidth, then is lost or arrives after the latency and jitter.
    pub fn send(&mut self, now: Instant, bytes: Bytes) {
        let start = self.free_at.map_or(now, |t| t.max(now));
        let wire = Duration::from_secs_f64(bytes.len() as f64 / self.model.bandwidth);
        self.free_at = Some(start + wire);
        self.sent += 1;
        if self.rng.unit() < self.model.loss {
            self.lost += 1;
            return;
        }
        let jitter = self.model.jitter.mul_f64(self.rng.unit());
        self.in_flight.push(InFlight {
            at: start + wire + self.model.latency + jitter,
            n: self.sent,
            bytes,
        });
    }

    /// What has arrived by `now`, in order of arrival.
    pub fn deliver(&mut self, now: Instant) -> Vec<Bytes> {
        let mut out = Vec::new();
        while self.in_flight.peek().is_some_and(|u| u.at <= now) {
            let Some(u) = self.in_flight.pop() else { break };
            if u.n < self.last_delivered {
                self.overtaken += 1;
            }
            self.last_delivered = self.last_delivered.max(u.n);
            out.push(u.bytes);
        }
        out
    }

    /// Whether nothing is in flight.
    pub fn is_idle(&self) -> bool {
        self.in_flight.is_empty()
    }
}

// The session's transport: a WasmSession (the protocol and the mirror, in
// Rust) wired to a WebTransport session (spec/session.md sections 2-4 over
// HTTP/3). The client opens one bidirectional stream, the control stream;
// the server opens one unidirectional stream, the frame stream. Bytes read
// go into the WasmSession; what it queues to send goes out on the control
// stream. A SessionClose it throws closes the WebTransport session with
// that code and reason.

// Error codes of spec/session.md section 7.
export const NO_ERROR = 0x00;
export const PROTOCOL_VIOLATION = 0x01;
export const SERVER_SHUTDOWN = 0x07;
export const INTERNAL_ERROR = 0x09;

// The counters of WasmSession.stats().
export const STAT_NAMES = ["applied", "keyframes", "failed", "stale", "requests", "bytes", "digests_matched", "digest_mismatches", "digests_dropped"];

// How long a client waits for the server's close after the server's
// control stream ended (spec/session.md 9.3).
const CLOSE_GRACE_MS = 1000;

// How often the mirror asks for digests (DIGEST_REQUEST.every).
const DIGEST_EVERY = 30;

export class SessionLink {
  // `session`: a WasmSession; `SessionClose`: the class it throws;
  // `config`: config.json ({url, certificate_hashes, ...}).
  constructor(session, SessionClose, config) {
    this.session = session;
    this.SessionClose = SessionClose;
    this.config = config;
    this.wt = null;
    this.writer = null; // the control stream's writer
    this.closed = null; // {closeCode, reason, by: "client" | "server" | "transport"} once closed
    this.closing = null; // what this client closed with, before `closed` settles
    this.error = null; // a client-side failure, as text
    this.digestsRequested = null; // request_digests' answer, once welcomed
    this.frameBytes = 0; // bytes read from the frame stream
    this.lastFrameAt = null; // performance.now() when frame bytes last arrived
    this.rttMs = null; // WebTransport's smoothed RTT, where the browser reports it
    this.frozen = false; // set by freeze(): frames are no longer read
    this.framesFinished = false; // the server finished the frame stream
    this.welcomed = new Promise((resolve, reject) => {
      this.resolveWelcomed = resolve;
      this.rejectWelcomed = reject;
    });
    this.welcomed.catch(() => {}); // a close before WELCOME is recorded in `closed`
  }

  // Opens the WebTransport session and starts the stream loops. Resolves
  // once they run; `welcomed` resolves on WELCOME.
  async start() {
    try {
      this.wt = await connect(this.config);
    } catch (first) {
      // The server may have replaced its certificate since config.json was
      // read (spec/session.md 9.1): read it again, and try once more if it
      // names another.
      const fresh = await fetch("/config.json", { cache: "no-store" })
        .then((r) => (r.ok ? r.json() : null))
        .catch(() => null);
      const changed = fresh && JSON.stringify(fresh.certificate_hashes) !== JSON.stringify(this.config.certificate_hashes);
      if (!changed) {
        this.settle({ closeCode: null, reason: `could not connect: ${first?.message ?? first}` });
        throw first;
      }
      this.config = { ...this.config, certificate_hashes: fresh.certificate_hashes, url: fresh.url };
      try {
        this.wt = await connect(this.config);
      } catch (second) {
        this.settle({ closeCode: null, reason: `could not connect: ${second?.message ?? second}` });
        throw second;
      }
    }
    this.wt.closed.then(
      (info) => this.settle({ closeCode: info.closeCode, reason: info.reason }),
      (err) => this.settle({ closeCode: null, reason: `${err?.name ?? "Error"}: ${err?.message ?? err}` }),
    );
    const control = await this.wt.createBidirectionalStream();
    this.writer = control.writable.getWriter();
    this.flush(); // HELLO, queued when the WasmSession was made
    this.readControl(control.readable.getReader());
    this.acceptStreams();
    // Should the session queue a message on its own clock (spec/session.md
    // 3.5: a KEYFRAME_REQUEST repeated after 2 s without frames), it goes
    // out without waiting for input.
    this.timer = setInterval(() => {
      this.flush();
      this.readRtt();
    }, 250);
    addEventListener("pagehide", () => this.close(NO_ERROR, "page closed"));
  }

  // The session's smoothed RTT, from WebTransport.getStats() (Chromium
  // reports it; elsewhere it stays unknown).
  readRtt() {
    this.wt
      ?.getStats?.()
      .then((st) => {
        const rtt = st?.smoothedRtt;
        if (typeof rtt === "number" && Number.isFinite(rtt)) this.rttMs = rtt;
      })
      .catch(() => {});
  }

  // The age of the mirror's newest frame: since its bytes arrived, plus
  // half the RTT for its way from the server (null before a frame).
  frameAgeMs() {
    if (this.lastFrameAt === null) return null;
    return performance.now() - this.lastFrameAt + (this.rttMs ?? 0) / 2;
  }

  // Records how the session ended (once) and fails `welcomed` if pending.
  // An end without a close code (the connection closed under the session)
  // reads as server_shutdown after the frame stream finished, else as
  // internal_error (spec/session.md 9.3).
  settle(info) {
    if (this.closed) return;
    const by = this.closing ? "client" : info.closeCode === null ? "transport" : "server";
    if (info.closeCode === null && !this.closing) {
      info = this.framesFinished
        ? { closeCode: SERVER_SHUTDOWN, reason: `the server shut down (${info.reason})` }
        : { closeCode: INTERNAL_ERROR, reason: `the connection was lost (${info.reason})` };
    }
    this.closed = { ...info, by };
    clearInterval(this.timer);
    this.rejectWelcomed(new Error(`session closed before WELCOME: ${info.closeCode} ${info.reason}`));
  }

  // Closes the WebTransport session with a spec/session.md code.
  close(closeCode, reason) {
    if (this.closing || this.closed || !this.wt) return;
    this.closing = { closeCode, reason };
    try {
      this.wt.close({ closeCode, reason: reason.slice(0, 256) });
    } catch (e) {
      this.settle({ closeCode, reason: `${reason} (close failed: ${e})` });
    }
  }

  // Writes what the WasmSession queued (HELLO, ACK, KEYFRAME_REQUEST,
  // DIGEST_REQUEST) to the control stream. Writes keep their order.
  flush() {
    if (!this.writer || this.closing || this.closed) return;
    for (let bytes = this.session.take_transmit(); bytes && bytes.length; bytes = this.session.take_transmit()) {
      this.write(bytes);
    }
  }

  write(bytes) {
    this.writer.write(bytes).catch(() => {}); // a failed write shows as a close
  }

  // Test hook: raw bytes on the control stream, bypassing the session.
  sendRaw(bytes) {
    this.write(new Uint8Array(bytes));
  }

  // Runs `step` (feeding the WasmSession) and sends what it queued; a
  // SessionClose it throws closes the session, anything else is a client
  // failure (internal_error).
  feed(step) {
    if (this.closing || this.closed) return false;
    try {
      step();
    } catch (e) {
      if (e instanceof this.SessionClose || (typeof e?.code === "number" && typeof e?.reason === "string")) {
        this.close(e.code, e.reason);
      } else {
        this.error = `${e?.stack ?? e}`;
        this.close(INTERNAL_ERROR, `client failure: ${e?.message ?? e}`);
      }
      return false;
    }
    this.flush();
    return true;
  }

  async readControl(reader) {
    try {
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        if (!this.feed(() => this.session.on_control(value))) return;
        if (this.digestsRequested === null && this.session.welcomed()) {
          // Once welcomed: ask for digests, so the mirror is checked.
          this.digestsRequested = this.session.request_digests(DIGEST_EVERY);
          this.flush();
          this.resolveWelcomed();
        }
      }
      // spec/session.md 2.1: finishing the control stream ends the session.
      this.closeUnlessClosing(PROTOCOL_VIOLATION, "the server finished the control stream");
    } catch (e) {
      if (e?.source === "stream") this.closeUnlessClosing(PROTOCOL_VIOLATION, "the server reset the control stream");
      // Otherwise the session closed: `closed` says how.
    }
  }

  // A server that closes the session may end its streams before its close
  // arrives (spec/session.md 9.3): wait for it a moment, and close with
  // `code` only if it does not come.
  closeUnlessClosing(code, reason) {
    setTimeout(() => this.close(code, reason), CLOSE_GRACE_MS);
  }

  // Takes the server's first unidirectional stream as the frame stream;
  // any other stream the server opens is a protocol violation.
  async acceptStreams() {
    const refuse = async (streams, what) => {
      try {
        const { done } = await streams.getReader().read();
        if (!done) this.close(PROTOCOL_VIOLATION, `the server opened a ${what}`);
      } catch {
        // the session closed
      }
    };
    refuse(this.wt.incomingBidirectionalStreams, "bidirectional stream");
    const uni = this.wt.incomingUnidirectionalStreams.getReader();
    try {
      const { value: stream, done } = await uni.read();
      if (done) return;
      this.readFrames(stream.getReader());
      const { done: end } = await uni.read();
      if (!end) this.close(PROTOCOL_VIOLATION, "the server opened a second unidirectional stream");
    } catch {
      // the session closed
    }
  }

  async readFrames(reader) {
    try {
      for (;;) {
        const { value, done } = await reader.read();
        // A finished frame stream means the server is shutting down: the
        // close follows (spec/session.md 2.1, 5.3).
        if (done) {
          this.framesFinished = true;
          return;
        }
        if (this.frozen) await new Promise(() => {}); // freeze(): read no more
        this.frameBytes += value.byteLength;
        this.lastFrameAt = performance.now();
        if (!this.feed(() => this.session.on_frames(value))) return;
      }
    } catch {
      // the session closed, or the server reset the stream (then it closes)
    }
  }

  // Stops feeding frames to the mirror, for good (a test hook).
  freeze() {
    this.frozen = true;
  }
}

// The session's counters as a plain object: stats() returns a wasm-bindgen
// object whose fields are getters on its prototype, which neither JSON nor
// spreading sees. The agreed names, and any other getter it has.
export function plainStats(session) {
  const s = session.stats();
  const getters = Object.entries(Object.getOwnPropertyDescriptors(Object.getPrototypeOf(s)))
    .filter(([, d]) => d.get)
    .map(([name]) => name);
  const out = {};
  for (const k of new Set([...STAT_NAMES, ...getters])) out[k] = Number(s[k]);
  s.free?.();
  return out;
}

// A WebTransport session to config.url pinning config's certificate
// hashes, once it is ready.
async function connect(config) {
  const hashes = config.certificate_hashes.map((h) => ({ algorithm: "sha-256", value: hexToBytes(h) }));
  const wt = new WebTransport(config.url, { serverCertificateHashes: hashes });
  wt.closed.catch(() => {}); // a session that never got ready rejects here too
  await wt.ready;
  return wt;
}

function hexToBytes(hex) {
  if (!/^([0-9a-fA-F]{2})+$/.test(hex)) throw new Error(`bad certificate hash ${hex}`);
  return new Uint8Array(hex.match(/../g).map((b) => parseInt(b, 16)));
}

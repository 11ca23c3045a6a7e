// The live text overlay: frame rate and bit rate of the stream, the frame
// age (since the newest frame arrived, plus half the RTT where the browser
// reports it), the mirror's sequence and sync, the rendering mode, and how
// the session ended.

export class Overlay {
  constructor(element) {
    this.element = element;
    this.sample = null; // {t, applied, bytes}: the rates' last sample
    this.rates = { fps: 0, mbps: 0 };
  }

  // `s`: main.js's state() ({welcomed, in_sync, sequence, stats, mode,
  // closed, error}) with `frameBytes`, the bytes read from the frame stream.
  update(s, frameBytes) {
    const now = performance.now();
    const applied = s.stats?.applied ?? 0;
    if (!this.sample) this.sample = { t: now, applied, bytes: frameBytes };
    const dt = (now - this.sample.t) / 1000;
    if (dt >= 1) {
      this.rates = { fps: (applied - this.sample.applied) / dt, mbps: ((frameBytes - this.sample.bytes) * 8) / dt / 1e6 };
      this.sample = { t: now, applied, bytes: frameBytes };
    }
    const age = s.frozen
      ? "- (stopped: the test compares this frame)"
      : s.frame_age_ms === null || s.frame_age_ms === undefined
        ? "none yet"
        : `${s.frame_age_ms.toFixed(0)} ms${s.rtt_ms === null ? " (RTT unknown)" : ""}`;
    const items = [
      ["mode", s.mode],
      ["session", s.closed ? "closed" : s.welcomed ? "welcomed" : "connecting"],
      ["frames/s", this.rates.fps.toFixed(1)],
      ["Mbit/s", this.rates.mbps.toFixed(2)],
      ["frame age", age],
      ["sequence", s.sequence ?? "-"],
      ["in sync", s.in_sync ? "yes" : "no"],
      ["digests", s.stats ? `${s.stats.digests_matched} matched, ${s.stats.digest_mismatches} mismatched` : "-"],
      ["render", s.render_ms === null ? "-" : `${s.render_ms.toFixed(0)} ms`],
    ];
    if (s.closed) items.push(["closed", `code ${s.closed.closeCode ?? "none"} by ${s.closed.by}: ${s.closed.reason}`]);
    if (s.error) items.push(["error", s.error]);
    this.element.replaceChildren(
      ...items.map(([label, value]) => {
        const item = document.createElement("span");
        const name = document.createElement("b");
        name.textContent = label;
        item.append(name, ` ${value}`);
        return item;
      }),
    );
  }
}

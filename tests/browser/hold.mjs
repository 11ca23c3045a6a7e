// A benchmark helper, not a check: opens K tabs of the browser client
// (psao serve --web) in one headless Chromium, waits until every one is in
// sync, holds them N seconds, and prints what each measured over the hold
// (frames applied, frame record bytes, digests) as one JSON object.
// scripts/web-bench.sh runs it beside native clients of the same server.
//
//   node tests/browser/hold.mjs --url https://127.0.0.1:PORT/ --spki B64 \
//     [--chromium /usr/bin/chromium] [--pages K] [--seconds N] [--cpu]

import { launch } from "./chromium.mjs";

const args = { url: null, spki: null, chromium: "/usr/bin/chromium", pages: 2, seconds: 20, cpu: false };
const argv = process.argv.slice(2);
for (let i = 0; i < argv.length; i++) {
  const a = argv[i];
  if (a === "--cpu") args.cpu = true;
  else if (["--url", "--spki", "--chromium", "--pages", "--seconds"].includes(a) && i + 1 < argv.length) args[a.slice(2)] = argv[++i];
  else {
    process.stderr.write(`unknown argument ${a}\n`);
    process.exit(2);
  }
}
if (!args.url || !args.spki) {
  process.stderr.write("--url and --spki are required\n");
  process.exit(2);
}
const log = (m) => process.stderr.write(`[hold] ${m}\n`);
const { browser } = await launch(args.chromium, args.spki);
const url = new URL(args.url);
url.searchParams.set("view", "fixed");
if (args.cpu) url.searchParams.set("cpu", "1");
const state = (p) => p.evaluate(() => window.psaoTest.state());
let out;
try {
  const pages = [];
  for (let k = 0; k < Number(args.pages); k++) {
    const p = await browser.newPage();
    await p.goto(url.href, { waitUntil: "load" });
    await p.waitForFunction(() => window.psaoTest?.state().in_sync, { timeout: 60_000, polling: 200 });
    pages.push(p);
  }
  log(`${pages.length} pages in sync; holding ${args.seconds} s`);
  const before = await Promise.all(pages.map(state));
  await new Promise((r) => setTimeout(r, Number(args.seconds) * 1000));
  const after = await Promise.all(pages.map(state));
  out = {
    mode: after[0].mode,
    seconds: Number(args.seconds),
    pages: after.map((s, k) => ({
      frames: s.stats.applied - before[k].stats.applied,
      record_bytes: s.stats.bytes - before[k].stats.bytes,
      digests_matched: s.stats.digests_matched - before[k].stats.digests_matched,
      digest_mismatches: s.stats.digest_mismatches,
      in_sync: s.in_sync,
      render_ms: s.render_ms,
    })),
  };
} finally {
  await browser.close().catch(() => {});
}
process.stdout.write(JSON.stringify(out) + "\n");

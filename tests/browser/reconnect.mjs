// The browser client reconnects: opens the page, waits until it is in
// sync, then (while the harness stops the server and starts a new one on
// the same ports, with a new certificate) waits until the page has closed
// its first session with the server's code, joined the new server and is
// in sync again with a digest matched. Prints one JSON object; exits 1 on
// failure. psao-cli/tests/web_cli.rs runs it.
//
//   node tests/browser/reconnect.mjs --url https://127.0.0.1:PORT/ [--chromium PATH]
//
// The page's certificate changes with the server, so Chromium is started
// with --ignore-certificate-errors (for the HTTPS page only: WebTransport
// pins the hash config.json names).

import puppeteer from "puppeteer-core";
import { WEBGPU_FLAGS } from "./chromium.mjs";

const args = { url: null, chromium: "/usr/bin/chromium" };
const argv = process.argv.slice(2);
for (let i = 0; i + 1 < argv.length; i += 2) args[argv[i].replace(/^--/, "")] = argv[i + 1];
if (!args.url) {
  process.stderr.write("--url is required\n");
  process.exit(2);
}
const log = (m) => process.stderr.write(`[reconnect] ${m}\n`);
const result = { ok: false, first_close: null, reconnects: 0, state: null, failure: null };
const flags = ["--ignore-certificate-errors", ...WEBGPU_FLAGS];
if (process.getuid?.() === 0) flags.push("--no-sandbox");
const browser = await puppeteer.launch({ executablePath: args.chromium, headless: true, args: [...flags] });
try {
  const page = await browser.newPage();
  const url = new URL(args.url);
  url.searchParams.set("view", "fixed");
  await page.goto(url.href, { waitUntil: "load" });
  await page.waitForFunction(() => window.psaoTest?.state().in_sync, { timeout: 60_000, polling: 200 });
  log("in sync with the first server");
  const deadline = Date.now() + 90_000;
  for (;;) {
    const s = await page.evaluate(() => window.psaoTest.state());
    if (s.closed && !result.first_close) {
      result.first_close = s.closed;
      log(`first session closed: ${JSON.stringify(s.closed)}`);
    }
    result.reconnects = s.reconnects;
    result.state = s;
    if (s.reconnects >= 1 && !s.closed && s.in_sync && s.stats?.digests_matched >= 1) break;
    if (Date.now() > deadline) throw new Error(`not in sync again: ${JSON.stringify(s)}`);
    await new Promise((r) => setTimeout(r, 100));
  }
  if (result.first_close?.closeCode !== 7) throw new Error(`the first session closed with ${JSON.stringify(result.first_close)}, not server_shutdown`);
  result.ok = true;
  log("in sync with the second server");
} catch (e) {
  result.failure = e?.message ?? String(e);
  log(`FAILED: ${result.failure}`);
} finally {
  await browser.close().catch(() => {});
}
process.stdout.write(JSON.stringify(result) + "\n");
process.exit(result.ok ? 0 : 1);

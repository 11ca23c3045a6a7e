// Drives the psao browser client (psao-web/page, served by `psao serve --web`)
// in headless Chromium and checks it end to end. Prints one JSON object with
// every measured value and `ok` on stdout, progress on stderr; exits 1 when a
// check fails. See README.md.
//
//   node tests/browser/drive.mjs --url https://127.0.0.1:PORT/ --spki <base64 SPKI sha256> \
//     --chromium /usr/bin/chromium --screenshot docs/browser-client.png [--cpu]

import { mkdirSync } from "node:fs";
import { dirname } from "node:path";
import { launch } from "./chromium.mjs";

// spec/session.md section 7.
const PROTOCOL_VIOLATION = 0x01;
const MESSAGE_TOO_LARGE = 0x04;


const JOIN_TIMEOUT_MS = 60_000;
const STEP_TIMEOUT_MS = 30_000;
const LATE_JOIN_DELAY_MS = 3_000;
const MAX_OVER_TOLERANCE = 0.01; // of hit pixels

const args = parseArgs(process.argv.slice(2));
const result = { ok: false, url: args.url, cpu: args.cpu, flags: null, chromium: null, checks: {}, failures: [], console_errors: [] };
const log = (msg) => process.stderr.write(`[drive] ${msg}\n`);
let browser = null;

try {
  await run();
} catch (e) {
  result.failures.push(`aborted: ${e?.message ?? e}`);
  log(`aborted: ${e?.stack ?? e}`);
} finally {
  await browser?.close().catch(() => {});
}
result.ok = result.failures.length === 0;
process.stdout.write(JSON.stringify(result, null, 2) + "\n");
process.exit(result.ok ? 0 : 1);

async function run() {
  let flags;
  ({ browser, flags } = await launch(args.chromium, args.spki));
  result.flags = flags;
  result.chromium = await browser.version();
  log(`${result.chromium} with ${flags.join(" ")}`);
  const pageUrl = new URL(args.url);
  pageUrl.searchParams.set("view", "fixed");
  if (args.cpu) pageUrl.searchParams.set("cpu", "1");
  const expectedMode = args.cpu ? /^CPU fallback/ : /^WebGPU$/;

  // 1. Page A joins and is in sync, with digests checked.
  const openedA = Date.now();
  const a = await openPage("A", pageUrl);
  const joinA = check("join_a", async (v) => {
    const s = await waitState(a, "A in sync with 2 digests matched", JOIN_TIMEOUT_MS, inSyncWith(2));
    Object.assign(v, { ms: s.at - openedA, mode: s.mode, adapter: s.adapter, state: s });
    expect(expectedMode.test(s.mode), `A's mode is "${s.mode}", expected ${expectedMode}`);
    expect(s.digests_requested === true, `request_digests(30) answered ${s.digests_requested}`);
  });

  // 2. Page B joins 3 s after A opened (while A may still be joining) and
  // gets there too.
  await sleep(openedA + LATE_JOIN_DELAY_MS - Date.now());
  const openedB = Date.now();
  const b = await openPage("B", pageUrl);
  await joinA;
  await check("late_join_b", async (v) => {
    v.opened_after_a_ms = openedB - openedA;
    const s = await waitState(b, "B in sync with 2 digests matched", JOIN_TIMEOUT_MS, inSyncWith(2));
    Object.assign(v, { ms: s.at - openedB, state: s });
  });
  await b.close();

  // 3. A loses a frame: it asks for a keyframe and is in sync again, with a
  // digest matched after that.
  await check("lost_frame", async (v) => {
    const before = await stateOf(a);
    v.before = before.stats;
    const dropped = Date.now();
    await a.evaluate(() => window.psaoTest.dropNextFrame());
    const asked = await waitState(a, "A's KEYFRAME_REQUEST", STEP_TIMEOUT_MS, (s) => s.stats.requests > before.stats.requests);
    v.request_ms = asked.at - dropped;
    const back = await waitState(a, "A in sync again with a further digest", STEP_TIMEOUT_MS, (s) =>
      s.in_sync && s.stats.digests_matched > asked.stats.digests_matched && s.stats.digest_mismatches === 0);
    Object.assign(v, { resync_ms: back.at - dropped, after: back.stats, keyframes_applied: back.stats.keyframes - before.stats.keyframes });
  });

  // 4. Bad input closes the session with the spec's codes.
  for (const [name, bytes, code] of [
    ["unknown_type", [1, 0, 0x7f], PROTOCOL_VIOLATION], // length 1, type 0x7f
    ["too_large", [0xff, 0xff], MESSAGE_TOO_LARGE], // length 65535
  ]) {
    await check(name, async (v) => {
      Object.assign(v, { sent: bytes, expected_code: code });
      const page = await openPage(name, pageUrl);
      try {
        await waitState(page, `${name}: welcomed`, JOIN_TIMEOUT_MS, (s) => s.welcomed);
        const sent = Date.now();
        await page.evaluate((raw) => window.psaoTest.sendRaw(raw), bytes);
        const s = await waitState(page, `${name}: closed`, STEP_TIMEOUT_MS, (st) => st.closed !== null, { closedIsFailure: false });
        Object.assign(v, { closed: s.closed, close_ms: s.at - sent });
        expect(s.closed.closeCode === code, `closeCode ${s.closed.closeCode} (${s.closed.reason}), expected ${code}`);
        expect(s.closed.by === "server", `closed by ${s.closed.by}, expected the server`);
      } finally {
        await page.close();
      }
    });
  }

  // 5. AO: the GPU's per-pixel AO against the wasm's on the same G-buffer,
  // a screenshot, and an AO view that is not uniform.
  await check("ao", async (v) => {
    await a.bringToFront();
    const cmp = await a.evaluate(async () => {
      await window.psaoTest.freeze();
      return window.psaoTest.compareCpu();
    });
    const ao = await a.evaluate(async () => {
      const v = await window.psaoTest.aoValues();
      let [below, min, max] = [0, Infinity, -Infinity];
      for (const x of v) [below, min, max] = [below + (x < 0.9), Math.min(min, x), Math.max(max, x)];
      return { count: v.length, below, min, max };
    });
    mkdirSync(dirname(args.screenshot), { recursive: true });
    // The canvas (both views) with the overlay under it.
    await (await a.$("#stage")).screenshot({ path: args.screenshot });
    const overFraction = cmp.hit ? cmp.over_tolerance / cmp.hit : 1;
    Object.assign(v, cmp, { over_fraction: overFraction, ao_values: ao, screenshot: args.screenshot, state: await stateOf(a) });
    expect(cmp.hit > 0, "no pixel hits the scene");
    expect(overFraction <= MAX_OVER_TOLERANCE, `${cmp.over_tolerance} of ${cmp.hit} hit pixels differ by more than 1/255`);
    expect(cmp.hit_below_0_9 > 0 && cmp.hit_above_0_9 > 0, `AO view uniform: ${cmp.hit_below_0_9} hit pixels below 0.9, ${cmp.hit_above_0_9} above`);
    expect(ao.count === cmp.pixels && ao.below === cmp.hit_below_0_9, `aoValues disagrees with compareCpu: ${JSON.stringify(ao)}`);
  });
}

// Opens the client in a new tab and waits for its test hooks.
async function openPage(name, url) {
  log(`${name}: opening ${url}`);
  const page = await browser.newPage();
  page.on("console", (m) => {
    if (m.type() === "error") result.console_errors.push(`${name}: ${m.text()}`);
  });
  page.on("pageerror", (e) => result.console_errors.push(`${name}: ${e.message}`));
  await page.goto(url.href, { waitUntil: "load", timeout: STEP_TIMEOUT_MS });
  await page.waitForFunction(() => window.psaoTest, { timeout: STEP_TIMEOUT_MS });
  page.psaoName = name;
  return page;
}

async function stateOf(page) {
  const s = await page.evaluate(() => window.psaoTest.state());
  s.at = Date.now();
  return s;
}

// Polls the page's state until `done(state)`; fails on timeout, on a page
// error, or (unless told otherwise) when the session closes.
async function waitState(page, what, timeoutMs, done, { closedIsFailure = true } = {}) {
  log(`${page.psaoName}: waiting for ${what}`);
  const deadline = Date.now() + timeoutMs;
  for (;;) {
    const s = await stateOf(page);
    if (s.error) throw new Error(`${what}: page error: ${s.error}`);
    if (s.stats && done(s)) return s;
    if (closedIsFailure && s.closed) throw new Error(`${what}: session closed: ${JSON.stringify(s.closed)}`);
    if (Date.now() > deadline) throw new Error(`${what}: timed out after ${timeoutMs} ms; last state ${JSON.stringify(s)}`);
    await sleep(200);
  }
}

function inSyncWith(digests) {
  return (s) => s.in_sync && s.stats.digests_matched >= digests && s.stats.digest_mismatches === 0;
}

// Runs one named check. `body(values)` fills `values` with what it
// measures, which goes into result.checks[name] whether it passes or not.
async function check(name, body) {
  log(`check ${name}`);
  const started = Date.now();
  const values = {};
  try {
    await body(values);
    result.checks[name] = { ok: true, ...values, check_ms: Date.now() - started };
    log(`check ${name}: ok`);
  } catch (e) {
    result.checks[name] = { ok: false, error: e?.message ?? String(e), ...values, check_ms: Date.now() - started };
    result.failures.push(`${name}: ${e?.message ?? e}`);
    log(`check ${name}: FAILED: ${e?.message ?? e}`);
  }
}

function expect(condition, message) {
  if (!condition) throw new Error(message);
}

function sleep(ms) {
  return new Promise((resolve) => setTimeout(resolve, Math.max(0, ms)));
}

function parseArgs(argv) {
  const out = { url: null, spki: null, chromium: "/usr/bin/chromium", screenshot: "docs/browser-client.png", cpu: false };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    if (a === "--cpu") out.cpu = true;
    else if (["--url", "--spki", "--chromium", "--screenshot"].includes(a) && i + 1 < argv.length) out[a.slice(2)] = argv[++i];
    else usage(`unknown argument ${a}`);
  }
  if (!out.url || !out.spki) usage("--url and --spki are required");
  return out;
}

function usage(message) {
  process.stderr.write(`${message}\nusage: node drive.mjs --url https://127.0.0.1:PORT/ --spki <base64 sha256 of the SPKI> [--chromium PATH] [--screenshot PATH] [--cpu]\n`);
  process.exit(2);
}

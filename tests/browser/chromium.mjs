// Headless Chromium for the browser client's checks (drive.mjs) and its
// benchmark (hold.mjs), through puppeteer-core.

import puppeteer from "puppeteer-core";

// What makes WebGPU work in headless Chromium (156, Linux) without a GPU or
// a display: Dawn's Vulkan backend on SwiftShader, Chromium's own CPU
// Vulkan (Mesa's lavapipe is not offered as an adapter). Without Vulkan or
// the SwiftShader Vulkan requestAdapter() fails; --disable-vulkan-surface
// would keep the adapter but leave the WebGPU canvas out of screenshots
// (white).
export const WEBGPU_FLAGS = [
  "--enable-unsafe-webgpu",
  "--enable-features=Vulkan",
  "--use-vulkan=swiftshader",
  "--use-webgpu-adapter=swiftshader",
  "--use-angle=swiftshader",
];

// Launches `executable` headless, trusting the page's self-signed
// certificate by `spki` (base64 of its SubjectPublicKeyInfo's SHA-256, as
// psao serve --web prints it). Returns { browser, flags }.
export async function launch(executable, spki) {
  const flags = [`--ignore-certificate-errors-spki-list=${spki}`, ...WEBGPU_FLAGS];
  if (process.getuid?.() === 0) flags.push("--no-sandbox"); // Chromium refuses root with its sandbox
  // (A copy: puppeteer takes --enable-features out of the array it is given.)
  const browser = await puppeteer.launch({ executablePath: executable, headless: true, args: [...flags] });
  return { browser, flags };
}

// Opens N dashboard pages in one headless Chromium for S seconds and prints, as JSON,
// every page's latencies from a batch merged to its image shown (ms).
//   node bench/dashboard_pages.mjs URL N SECONDS
// Needs tests/dashboard's playwright-core (npm ci there) and /usr/bin/chromium.
import { createRequire } from "module";
const require = createRequire(new URL("../tests/dashboard/package.json", import.meta.url));
const { chromium } = require("playwright-core");

const [url, n, seconds] = [process.argv[2], Number(process.argv[3]), Number(process.argv[4])];
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  args: ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
    "--disable-component-update", "--disable-sync"],
});
const pages = [];
for (let i = 0; i < n; i++) {
  const page = await browser.newPage({ viewport: { width: 1400, height: 900 } });
  await page.goto(url);
  pages.push(page);
}
await new Promise((ok) => setTimeout(ok, seconds * 1000));
const latencies = [];
for (const p of pages) latencies.push(...(await p.evaluate(() => window.tilefarmLatencies || [])));
await browser.close();
console.log(JSON.stringify({ pages: n, latencies_ms: latencies }));

// Drives the dashboard in headless Chromium (Debian's /usr/bin/chromium, through
// playwright-core), as tests/tests/dashboard.rs asks:
//   node drive.mjs URL JOB_NAME SCREENSHOT.png
// It waits for the job and two workers to be listed, for the live image to change
// between two updates, writes a screenshot, shows the noise and samples views (each
// must differ from the image, with its legend), then presses the job's cancel button and
// waits for the page to show it cancelled. Prints one JSON line; exits non-zero on failure.
import { chromium } from "playwright-core";

const [url, jobName, shot] = process.argv.slice(2);
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  args: ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
    "--disable-component-update", "--disable-sync"],
});
try {
  const page = await browser.newPage({ viewport: { width: 1400, height: 900 } });
  await page.goto(url);
  const row = page.locator("#jobs tr.job", { hasText: jobName });
  await row.waitFor({ timeout: 60000 });
  await page.waitForFunction(() => document.querySelectorAll("#workers tr.worker").length >= 2, null, { timeout: 60000 });

  // Two updates of the image that differ.
  const version = async () => Number((await page.locator("#live").getAttribute("data-version")) || "0");
  await page.waitForFunction(() => Number(document.getElementById("live").dataset.version || "0") >= 1, null, { timeout: 60000 });
  const first = await page.locator("#live").screenshot();
  const v1 = await version();
  let second = first, v2 = v1;
  const until = Date.now() + 60000;
  while (Buffer.compare(first, second) === 0) {
    if (Date.now() > until) throw new Error("the live image did not change");
    await page.waitForFunction((v) => Number(document.getElementById("live").dataset.version || "0") > v, v2, { timeout: 60000 });
    v2 = await version();
    second = await page.locator("#live").screenshot();
  }
  const latencies = await page.evaluate(() => window.tilefarmLatencies || []);
  await page.screenshot({ path: shot, fullPage: true });

  // The noise and samples-per-pixel views: each shows its legend and an image unlike
  // the beauty image's (screenshots beside the main one).
  const views = {};
  for (const view of ["noise", "samples"]) {
    await page.selectOption("#viewsel", view);
    await page.locator(`#legend[data-view="${view}"]`).waitFor({ timeout: 30000 });
    const v = await version();
    await page.waitForFunction((v) => Number(document.getElementById("live").dataset.version || "0") > v, v, { timeout: 30000 });
    const shown = await page.locator("#live").screenshot({ path: shot.replace(/\.png$/, `-${view}.png`) });
    if (Buffer.compare(shown, second) === 0) throw new Error(`the ${view} view shows the beauty image`);
    views[view] = (await page.locator("#legend").textContent()).trim();
  }
  await page.selectOption("#viewsel", "beauty");

  await row.locator('button[data-action="cancel"]').click();
  await page.locator("#jobs tr.job", { hasText: jobName }).filter({ hasText: "cancelled" }).waitFor({ timeout: 30000 });
  console.log(JSON.stringify({ ok: true, versions: [v1, v2], views, latencies_ms: latencies }));
} finally {
  await browser.close();
}

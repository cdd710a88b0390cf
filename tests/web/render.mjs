// Headless Chromium (Debian's chromium, WebGL through SwiftShader) renders test jobs with the
// three.js importer (tests/export/test_export_gltf.py).
// Usage: node render.mjs BASE_URL OUT_DIR JOB.json...  (modules from $USDAHD_WEB_MODULES)
// For each job writes OUT_DIR/<job stem>.f32 (RGBA float32, row 0 at the bottom), <stem>.ids.f32
// (the node id pass) and prints one
// JSON object {job: {patched, renderer} | {error}}.
import { createRequire } from 'module';
import fs from 'fs';
import path from 'path';

const require = createRequire(path.join(process.env.USDAHD_WEB_MODULES || '.', 'noop.js'));
const puppeteer = require('puppeteer-core');

const [base, outDir, ...jobs] = process.argv.slice(2);
const browser = await puppeteer.launch({
  executablePath: process.env.USDAHD_CHROMIUM || '/usr/bin/chromium',
  headless: true,
  args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
    '--ignore-gpu-blocklist', '--disable-dev-shm-usage'],
});
const report = {};
try {
  for (const job of jobs) {
    const page = await browser.newPage();
    const log = [];
    page.on('console', (m) => log.push(`${m.type()}: ${m.text()}`));
    page.on('pageerror', (e) => log.push(`pageerror: ${e}`));
    await page.goto(`${base}/page.html?job=${encodeURIComponent(job)}`);
    await page.waitForFunction('window.usdahdResult !== undefined', { timeout: 90000 });
    const r = await page.evaluate('window.usdahdResult');
    if (r.error) {
      report[job] = { error: r.error, log };
    } else {
      const stem = path.basename(job, '.json');
      fs.writeFileSync(path.join(outDir, `${stem}.f32`), Buffer.from(r.pixels, 'base64'));
      fs.writeFileSync(path.join(outDir, `${stem}.ids.f32`), Buffer.from(r.ids, 'base64'));
      report[job] = { patched: r.patched, renderer: r.renderer, log };
    }
    await page.close();
  }
} finally {
  await browser.close();
}
console.log(JSON.stringify(report, null, 1));

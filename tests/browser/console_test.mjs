// The console in a real browser: Debian's headless chromium driven by
// playwright-core, against a nimbusd on loopback that this script starts
// and stops. Usage: node console_test.mjs NIMBUSD SOURCE_DIR [SCREENSHOT]
import { spawn } from 'node:child_process';
import { mkdtempSync, readFileSync, writeFileSync, chmodSync, existsSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { chromium } from 'playwright-core';

const [nimbusd, sourceDir, screenshot] = process.argv.slice(2);
const HOSTILE = '<img src=x onerror=alert(1)>';
const OWNER = '<img/src=x/onerror=alert(2)>';
const TOKEN = 'console-test-token-0123456789abcdef';

function check(ok, what) {
  if (!ok) throw new Error(`FAILED: ${what}`);
  console.log(`ok: ${what}`);
}

async function waitFor(what, fn, tries = 600, ms = 100) {
  for (let i = 0; i < tries; ++i) {
    const v = await fn();
    if (v) return v;
    await new Promise((r) => setTimeout(r, ms));
  }
  throw new Error(`FAILED: never saw ${what}`);
}

function startNimbusd(dir) {
  const tokens = join(dir, 'tokens');
  writeFileSync(tokens, `${TOKEN} ${OWNER}\n`);
  chmodSync(tokens, 0o600);
  const child = spawn(nimbusd, ['--listen', '127.0.0.1:0', '--port-file', join(dir, 'port'),
    '--http', '127.0.0.1:0', '--http-port-file', join(dir, 'http_port'), '--data-dir', join(dir, 'data'),
    '--auth-tokens', tokens, '--workers', '2', '--threads-per-job', '1', '--min-free-disk-mib', '0',
    '--log-level', 'warn'], { stdio: 'inherit' });
  return child;
}

// A spec the console submits: the tetrahedron at 48³, run until cancelled,
// its first map named with markup.
function spec() {
  const s = JSON.parse(readFileSync(join(sourceDir, 'examples/sierpinski_tetrahedron.json'), 'utf8'));
  s.grid.resolution = [48];
  s.chaos_game.iterations = String(2 ** 38);
  s.chaos_game.ifs.maps[0].name = HOSTILE;
  return JSON.stringify(s, null, 1);
}

const dir = mkdtempSync(join(tmpdir(), 'nimbus-console-'));
const server = startNimbusd(dir);
let browser;
try {
  const port = await waitFor('nimbusd listening', () =>
    existsSync(join(dir, 'port')) && Number(readFileSync(join(dir, 'http_port'), 'utf8')));
  const base = `http://127.0.0.1:${port}/`;
  browser = await chromium.launch({
    executablePath: '/usr/bin/chromium', headless: true,
    args: ['--no-sandbox', '--enable-unsafe-swiftshader', '--use-angle=swiftshader',
      '--disable-background-networking', '--disable-component-update', '--disable-sync',
      '--no-first-run', '--disable-quic'],
  });
  const page = await browser.newPage({ viewport: { width: 1280, height: 1000 } });
  let alerted = false;
  page.on('dialog', async (d) => { alerted = true; await d.dismiss(); });
  page.on('pageerror', (e) => console.log(`page error: ${e.message}`));
  await page.goto(base);
  await page.fill('#token', TOKEN);
  await page.click('#token-form button');
  check((await page.textContent('#token-state')) === 'token set', 'token entered once');

  // Submit through the form; the console opens the job's page.
  const submit = async () => {
    await page.goto(`${base}#/submit`);
    await page.fill('#spec-text', spec());
    await page.click('#submit');
    await page.waitForURL(/#\/job\//);
    return decodeURIComponent(page.url().split('#/job/')[1]);
  };
  const first = await submit();
  check(first.startsWith('j-'), `submitted ${first}`);

  // The preview picture changes at least twice while the job runs.
  const seen = new Set();
  await waitFor('three preview pictures', async () => {
    const s = await page.getAttribute('#preview-img', 'data-sequence');
    if (s) seen.add(s);
    return seen.size >= 3;
  });
  check(seen.size >= 3, `preview picture changed twice (sequences ${[...seen].join(', ')})`);
  const shown = await page.evaluate(() =>
    performance.getEntriesByName('nimbus-preview-shown').map((m) => m.duration).sort((a, b) => a - b));
  if (shown.length)
    console.log(`preview event to picture shown: median ${shown[shown.length >> 1].toFixed(1)} ms, max ${shown[shown.length - 1].toFixed(1)} ms over ${shown.length}`);

  // The 3D view drew something other than its black background.
  const lit = await waitFor('a drawn 3D view', () => page.evaluate(() => {
    const c = document.getElementById('volume');
    if (!c || !c.dataset.sequence) return 0;
    const copy = document.createElement('canvas');
    copy.width = c.width; copy.height = c.height;
    const ctx = copy.getContext('2d');
    ctx.drawImage(c, 0, 0);
    const px = ctx.getImageData(0, 0, c.width, c.height).data;
    let n = 0;
    for (let i = 0; i < px.length; i += 4) if (px[i] + px[i + 1] + px[i + 2] > 30) ++n;
    return n;
  }));
  check(lit > 500, `3D canvas drew ${lit} non-background pixels`);

  // The markup in the spec shows as text.
  const specText = await page.textContent('#spec');
  check(specText.includes(HOSTILE), 'map name shown as text in the spec');
  if (screenshot) await page.screenshot({ path: screenshot, fullPage: false });

  // The list shows the job, its owner as text, live.
  await page.goto(`${base}#/jobs`);
  const row = `#jobs tr[data-id="${first}"]`;
  await page.waitForSelector(row);
  check((await page.textContent(`${row} .state`)) === 'RUNNING', 'job listed as RUNNING');
  const ownerCell = await page.textContent(`${row} td:nth-child(3)`);
  check(ownerCell === OWNER, 'owner shown as text');
  check((await page.$$('#jobs img')).length === 0, 'no markup from user strings in the list');
  const before = await page.textContent(`${row} small`);
  await waitFor('a live progress update', async () => (await page.textContent(`${row} small`)) !== before);
  check(true, 'list updates without reloading');

  // A second job, cancelled from its page.
  const second = await submit();
  await page.waitForSelector('#job-state');
  await waitFor('second job running', async () => (await page.textContent('#job-state')) === 'RUNNING');
  await page.click('#cancel');
  await waitFor('second job cancelled', async () => (await page.textContent('#job-state')) === 'CANCELLED');
  check(true, `cancelled ${second} from the console`);

  // Workers page: the registry lists this server's replica, alive.
  await page.goto(`${base}#/workers`);
  await page.waitForSelector('#workers tbody tr');
  const rows = await page.$$eval('#workers tbody tr', (trs) => trs.map((tr) => tr.textContent));
  check(rows.length === 1 && rows[0].endsWith('alive'), `workers page lists this replica alive (${rows})`);
  check(!alerted, 'no script from user strings ran');
  // Stop the first job so the server exits at once.
  await page.evaluate(async (id) => {
    await fetch(`/api/v1/jobs/${id}/cancel`, { method: 'POST', headers: { Authorization: `Bearer ${localStorage.getItem('nimbus.token')}`, 'Content-Type': 'application/json' }, body: '{}' });
  }, first);
  console.log('console_test: all checks passed');
} finally {
  if (browser) await browser.close();
  server.kill('SIGTERM');
  await new Promise((r) => server.once('exit', r));
  rmSync(dir, { recursive: true, force: true });
}

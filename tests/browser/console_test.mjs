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

let watched = null;  // the page, for failure messages

async function waitFor(what, fn, tries = 600, ms = 100) {
  for (let i = 0; i < tries; ++i) {
    const v = await fn();
    if (v) return v;
    await new Promise((r) => setTimeout(r, ms));
  }
  // The console's status line usually says why.
  if (watched) console.log(`console status: ${await watched.textContent('#status').catch(() => '')}`);
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

// The JSON API called by the test itself, beside the browser.
async function api(base, method, path, body) {
  const res = await fetch(new URL(path, base), { method, headers: { Authorization: `Bearer ${TOKEN}`,
    ...(body ? { 'Content-Type': 'application/json' } : {}) }, body: body ? JSON.stringify(body) : undefined });
  return { status: res.status, json: await res.json().catch(() => null) };
}

// The job page's event log: [{ kind, fields: {name: text} }] in page order.
function events(page) {
  return page.$$eval('#events li', (lis) => lis.map((li) => ({ kind: li.dataset.kind,
    fields: Object.fromEntries([...li.querySelectorAll('.event-field')].map((f) =>
      [f.dataset.name, f.textContent.slice(f.dataset.name.length + 1)])) })));
}
async function eventKinds(page) { return (await events(page)).map((e) => e.kind); }

async function openJob(page, base, id) {
  await page.goto(`${base}#/job/${encodeURIComponent(id)}`);
  await page.waitForSelector('#job-state');
}

// Priority, cancel, retry, pin and delete on a job that stays QUEUED (both
// workers are busy with jobs that run until cancelled).
async function queueButtons(page, base) {
  const third = await submitFrom(page, base);
  await page.waitForSelector('#job-state');
  check((await page.textContent('#job-state')) === 'QUEUED', `${third} waits in the queue`);
  await waitFor('submitted in the log', async () => (await eventKinds(page))[0] === 'submitted');
  await page.fill('#priority', '87');
  await page.click('#set-priority');
  await waitFor('priority 87 on the page', async () => (await page.textContent('#job-priority')) === '87');
  check((await api(base, 'GET', `/api/v1/jobs/${third}`)).json.job.priority === 87, 'the store has priority 87');
  // A change by another client shows up live: the page's priority and its log.
  check((await api(base, 'POST', `/api/v1/jobs/${third}/priority`, { priority: 12 })).status === 200, 'priority 12 set through the API');
  await waitFor('priority 12 on the page', async () => (await page.textContent('#job-priority')) === '12');
  const prio = await waitFor('two priority events', async () => {
    const p = (await events(page)).filter((e) => e.kind === 'priority');
    return p.length >= 2 && p;
  });
  check(prio.map((e) => e.fields.priority).join() === '87,12' && prio[0].fields.by === OWNER,
    `priority events in order (${prio.map((e) => e.fields.priority)}) by the owner, without reloading`);
  await page.goto(`${base}#/jobs`);
  await waitFor('priority 12 in the list', async () =>
    (await page.textContent(`#jobs tr[data-id="${third}"] .priority`).catch(() => '')) === '12');
  check(true, 'the list shows priority 12');

  // Cancelled while queued, then retried from its page.
  await openJob(page, base, third);
  await page.click('#cancel');
  await waitFor('third job cancelled', async () => (await page.textContent('#job-state')) === 'CANCELLED');
  const kinds = await waitFor('cancel_requested in the log', async () => {
    const k = await eventKinds(page);
    return k.includes('cancel_requested') && k;
  });
  check(kinds.slice(0, 4).join() === 'submitted,priority,priority,cancel_requested', `queued job's log in order: ${kinds}`);
  await page.click('#retry');
  await page.waitForURL((u) => !u.hash.endsWith(third));
  const retry = decodeURIComponent(page.url().split('#/job/')[1]);
  check(retry !== third && retry.startsWith('j-'), `retried as ${retry}`);
  await waitFor('the retry of link', () => page.$(`#retried-from[href="#/job/${third}"]`));
  const stored = (await api(base, 'GET', `/api/v1/jobs/${retry}`)).json.job;
  check(stored.retriedFrom === third && stored.priority === 12, 'the store has the retry, its original and priority');
  await waitFor('retried_from on the submit event', async () =>
    (await events(page)).some((e) => e.kind === 'submitted' && e.fields.retried_from === third));
  await page.click('#retried-from');
  await page.waitForURL((u) => u.hash.endsWith(third));
  await waitFor('retried event naming the retry', async () =>
    (await events(page)).some((e) => e.kind === 'retried' && e.fields.retried_as === retry && e.fields.by === OWNER));
  await page.click(`#events a[href="#/job/${retry}"]`);
  await page.waitForURL((u) => u.hash.endsWith(retry));
  check(true, 'the original and its retry link to each other');
  await pinAndDelete(page, base, retry);
}

async function pinAndDelete(page, base, id) {
  await page.waitForSelector('#job-state');
  await waitFor('retry queued', async () => (await page.textContent('#job-state')) === 'QUEUED');
  check(await page.isDisabled('#delete'), 'delete is disabled while queued');
  await page.click('#cancel');
  await waitFor('retry cancelled', async () => (await page.textContent('#job-state')) === 'CANCELLED');
  await page.click('#pin');
  await waitFor('pinned on the page', () => page.$('#job-pinned'));
  check((await api(base, 'GET', `/api/v1/jobs/${id}`)).json.job.pinned === true, 'the store has the pin');
  await waitFor('pinned event', async () => (await eventKinds(page)).includes('pinned'));
  await page.click('#unpin');
  await waitFor('unpinned on the page', async () => !(await page.$('#job-pinned')));
  check((await api(base, 'GET', `/api/v1/jobs/${id}`)).json.job.pinned === false, 'the store has the unpin');
  await waitFor('unpinned event after pinned', async () => (await eventKinds(page)).join().endsWith('pinned,unpinned'));
  await page.click('#delete');
  await page.waitForURL(/#\/jobs$/);
  await page.waitForSelector('#jobs tr');
  check(!(await page.$(`#jobs tr[data-id="${id}"]`)), 'deleted job gone from the list');
  check((await api(base, 'GET', `/api/v1/jobs/${id}`)).status === 404, 'the store no longer has it');
}

// Submits spec() through the form; the console opens the job's page.
async function submitFrom(page, base) {
  await page.goto(`${base}#/submit`);
  await page.fill('#spec-text', spec());
  await page.click('#submit');
  await page.waitForURL(/#\/job\//);
  return decodeURIComponent(page.url().split('#/job/')[1]);
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
  watched = page;
  let alerted = false;
  page.on('dialog', async (d) => { alerted = true; await d.dismiss(); });
  page.on('pageerror', (e) => console.log(`page error: ${e.message}`));
  await page.goto(base);
  await page.fill('#token', TOKEN);
  await page.click('#token-form button');
  check((await page.textContent('#token-state')) === 'token set', 'token entered once');

  const submit = () => submitFrom(page, base);
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

  // A second job takes the other worker; a third then waits in the queue.
  const second = await submit();
  await page.waitForSelector('#job-state');
  await waitFor('second job running', async () => (await page.textContent('#job-state')) === 'RUNNING');
  await queueButtons(page, base);

  // The second job cancelled from its page; its event log follows live.
  await page.goto(`${base}#/job/${encodeURIComponent(second)}`);
  await waitFor('second job claimed in its log', async () => (await eventKinds(page)).includes('claimed'));
  await page.click('#cancel');
  await waitFor('second job cancelled', async () => (await page.textContent('#job-state')) === 'CANCELLED');
  check(true, `cancelled ${second} from the console`);
  // The worker records the end itself, so `cancelled` may precede the
  // service's `cancel_requested` by a heartbeat.
  const ends = await waitFor('cancel events in the log', async () => {
    const k = (await eventKinds(page)).filter((x) => x !== 'phase' && x !== 'warning');
    return k.length >= 4 && k;
  });
  check(ends.length === 4 && ends[0] === 'submitted' && ends[1] === 'claimed' &&
    [...ends.slice(2)].sort().join() === 'cancel_requested,cancelled',
  `second job's log in order, without reloading: ${ends.join(', ')}`);

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

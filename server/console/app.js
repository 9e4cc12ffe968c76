// The console's pages: #/jobs, #/job/ID, #/submit, #/workers.
import { call, fetchBlob, setToken, stream, token, ApiError } from './api.js';
import { clear, el, kindOf, progressBar, progressText, shortState } from './dom.js';
import { eventLog } from './events.js';
import { VolumeView } from './volume.js';

const main = document.getElementById('main');
const status = document.getElementById('status');
let leave = () => {};  // stops the current page's timers and streams
let features = [];
const kinds = new Map();  // job id -> kind (the list omits specs)

function say(text, isError = false) {
  status.textContent = text;
  status.className = isError ? 'error' : '';
}

function showError(e) { say(e instanceof ApiError ? `${e.status} ${e.code}: ${e.message}` : String(e), true); }

async function kindFor(job) {
  if (kinds.has(job.id)) return kinds.get(job.id);
  kinds.set(job.id, '');
  try { kinds.set(job.id, kindOf((await call('GET', `/api/v1/jobs/${encodeURIComponent(job.id)}`)).job)); } catch { /* shown blank */ }
  return kinds.get(job.id);
}

function jobRow(job) {
  const link = el('a', { href: `#/job/${encodeURIComponent(job.id)}`, class: 'job-name' }, job.name || job.id);
  return el('tr', { 'data-id': job.id },
    el('td', { class: `state state-${shortState(job.state)}` }, shortState(job.state)),
    el('td', {}, link), el('td', {}, job.owner), el('td', { class: 'kind' }, kinds.get(job.id) || ''),
    el('td', { class: 'priority' }, job.priority ?? ''),
    el('td', {}, progressBar(job.progress), el('small', {}, progressText(job.progress))),
    el('td', {}, job.worker));
}

function jobsPage() {
  const state = el('select', { id: 'filter-state' }, ['', 'QUEUED', 'RUNNING', 'SUCCEEDED', 'FAILED', 'CANCELLED']
    .map((s) => el('option', { value: s }, s || 'any state')));
  const owner = el('input', { id: 'filter-owner', placeholder: 'owner' });
  const kind = el('input', { id: 'filter-kind', placeholder: 'kind' });
  const search = el('input', { id: 'search', placeholder: 'search name or id' });
  const body = el('tbody', { id: 'jobs' });
  main.append(el('div', { class: 'filters' }, state, owner, kind, search),
    el('table', {}, el('thead', {}, el('tr', {}, ['State', 'Name', 'Owner', 'Kind', 'Priority', 'Progress', 'Worker'].map((h) => el('th', {}, h)))), body));
  let jobs = [];
  const render = () => {
    const q = search.value.toLowerCase();
    clear(body);
    for (const j of jobs) {
      if (owner.value && j.owner !== owner.value) continue;
      if (kind.value && !(kinds.get(j.id) || '').toLowerCase().includes(kind.value.toLowerCase())) continue;
      if (q && !`${j.name} ${j.id}`.toLowerCase().includes(q)) continue;
      body.append(jobRow(j));
    }
  };
  const refresh = async () => {
    try {
      const qs = state.value ? `?state=${state.value}&page_size=200` : '?page_size=200';
      jobs = (await call('GET', `/api/v1/jobs${qs}`)).jobs || [];
      await Promise.all(jobs.slice(0, 200).map(kindFor));
      render();
      say(`${jobs.length} jobs · updated ${new Date().toLocaleTimeString()}`);
    } catch (e) { showError(e); }
  };
  for (const f of [owner, kind, search]) f.addEventListener('input', render);
  state.addEventListener('change', refresh);
  refresh();
  const timer = setInterval(refresh, 1000);
  return () => clearInterval(timer);
}

function fileLinks(job) {
  const id = encodeURIComponent(job.id);
  const r = job.result || {};
  const links = [];
  if (r.fileName) links.push(el('li', {}, el('a', { href: '#', 'data-download': `/api/v1/jobs/${id}/result`, 'data-name': r.fileName }, r.fileName)));
  for (const f of r.files || [])
    links.push(el('li', {}, el('a', { href: '#', 'data-download': `/api/v1/jobs/${id}/files/${encodeURIComponent(f.fileName)}`, 'data-name': f.fileName }, f.fileName)));
  return links;
}

// Downloads go through fetch so that the bearer header goes with them.
async function download(path, name) {
  try {
    const blob = await (await fetchBlob(path)).blob();
    const a = el('a', { href: URL.createObjectURL(blob), download: name });
    a.click();
    setTimeout(() => URL.revokeObjectURL(a.href), 10000);
  } catch (e) { showError(e); }
}

// The job page's buttons; `act(method, path, body)` makes a call and shows
// the job it answers with. Each button is enabled only in the states its
// call accepts (see enableFor).
function actionButtons(path, act, showError) {
  const buttons = el('div', { id: 'actions' },
    el('button', { id: 'cancel', onclick: () => act('POST', `${path}/cancel`) }, 'Cancel'),
    el('button', { id: 'pin', onclick: () => act('POST', `${path}/pin`, { pinned: true }) }, 'Pin'),
    el('button', { id: 'unpin', onclick: () => act('POST', `${path}/pin`, { pinned: false }) }, 'Unpin'),
    el('button', { id: 'delete', onclick: async () => { if (await act('DELETE', path)) location.hash = '#/jobs'; } }, 'Delete'));
  // The queue's calls, where this server offers them (/api/v1/info).
  if (features.includes('retry'))
    buttons.append(el('button', { id: 'retry', onclick: async () => {
      try { const r = await call('POST', `${path}/retry`, {}); location.hash = `#/job/${encodeURIComponent(r.job.id)}`; } catch (e) { showError(e); }
    } }, 'Retry'));
  if (features.includes('priority')) {
    const level = el('input', { id: 'priority', type: 'number', min: 0, max: 100, step: 1, size: 4, 'aria-label': 'priority' });
    level.addEventListener('input', () => { level.dataset.edited = '1'; });
    buttons.append(level, el('button', { id: 'set-priority', onclick: async () => {
      if (await act('POST', `${path}/priority`, { priority: Number(level.value) })) delete level.dataset.edited;
    } }, 'Set priority'));
  }
  return buttons;
}

function enableFor(buttons, job) {
  const s = shortState(job.state);
  const terminal = ['SUCCEEDED', 'FAILED', 'CANCELLED'].includes(s);
  const on = { cancel: !terminal, pin: !job.pinned, unpin: !!job.pinned, delete: terminal,
    retry: s === 'FAILED' || s === 'CANCELLED', 'set-priority': s === 'QUEUED', priority: s === 'QUEUED' };
  for (const [id, enabled] of Object.entries(on)) {
    const b = buttons.querySelector(`#${id}`);
    if (b) b.disabled = !enabled;
  }
  const level = buttons.querySelector('#priority');
  if (level && !level.dataset.edited && document.activeElement !== level) level.value = job.priority ?? '';
}

function jobInfo(job) {
  const jobLink = (other, id) => el('a', { id, href: `#/job/${encodeURIComponent(other)}` }, other);
  return [el('span', { id: 'job-state', class: `state-${shortState(job.state)}` }, shortState(job.state)),
    ` · owner ${job.owner} · worker ${job.worker || '-'} · priority `,
    el('span', { id: 'job-priority' }, job.priority ?? ''),
    job.pinned ? [' · ', el('span', { id: 'job-pinned' }, 'pinned')] : [],
    job.retriedFrom ? [' · retry of ', jobLink(job.retriedFrom, 'retried-from')] : [],
    ' · ', progressBar(job.progress), ' ', progressText(job.progress),
    ...(job.error ? [el('p', { class: 'error' }, job.error)] : [])].flat();
}

function jobPage(id) {
  const path = `/api/v1/jobs/${encodeURIComponent(id)}`;
  const title = el('h2', { id: 'job-title' });
  const info = el('div', { id: 'job-info' });
  const img = el('img', { id: 'preview-img', alt: 'latest preview' });
  const canvas = el('canvas', { id: 'volume', width: 320, height: 320 });
  const seq = el('span', { id: 'preview-seq' });
  const warnings = el('ul', { id: 'warnings' });
  const files = el('ul', { id: 'files' });
  const spec = el('pre', { id: 'spec' });
  const log = features.includes('events') ? eventLog(path, showError) : null;
  const act = async (method, p, body) => {
    try {
      const r = await call(method, p, body ?? {});
      if (r.job) show(r.job);
      if (log) log.refresh();
      say(`${method} ${p}: done`);
      return true;
    } catch (e) { showError(e); return false; }
  };
  const buttons = actionButtons(path, act, showError);
  files.addEventListener('click', (e) => {
    const a = e.target.closest('a[data-download]');
    if (!a) return;
    e.preventDefault();
    download(a.dataset.download, a.dataset.name);
  });
  main.append(title, info, buttons,
    el('div', { class: 'views' }, el('figure', {}, img, el('figcaption', {}, 'Latest preview ', seq)),
      el('figure', {}, canvas, el('figcaption', {}, '3D view of the preview density (drag to turn)'))),
    el('h3', {}, 'Warnings'), warnings, el('h3', {}, 'Downloads'), files,
    ...(log ? [el('h3', {}, 'Events'), log.node] : []), el('h3', {}, 'Spec'), spec);
  let volume = null;
  try { volume = new VolumeView(canvas); } catch (e) { canvas.replaceWith(el('p', { class: 'error' }, e.message)); }
  function show(job) {
    title.textContent = job.name || job.id;
    clear(info);
    info.append(...jobInfo(job));
    enableFor(buttons, job);
    clear(warnings); warnings.append(...(job.warnings || []).map((w) => el('li', {}, w)));
    clear(files); files.append(...fileLinks(job));
  }
  const loadPreview = previewLoader(path, img, seq, canvas, volume);
  const abort = new AbortController();
  call('GET', path).then(({ job }) => {
    show(job);
    spec.textContent = JSON.stringify(job.spec, null, 2);
    // The whole log from the stream too: each source is complete and in
    // order, so the log shows every event once (eventLog's add).
    const events = log ? '&events=1' : '';
    return stream(`${path}/stream?preview_resolution=64&preview_interval=0.2${events}`, (name, data) => {
      if (name === 'job') show(data);
      else if (name === 'event' && log) log.add(data);
      else if (name === 'preview') {
        performance.mark(`nimbus-preview-${data.sequence}`);
        loadPreview(Number(data.sequence));
      }
    }, abort.signal);
  }).catch((e) => { if (e.name !== 'AbortError') showError(e); });
  return () => { abort.abort(); if (log) log.stop(); };
}

// Returns loadPreview(sequence): fetches the newest preview picture (and
// density, for the 3D view) until the one shown is at least `sequence`.
function previewLoader(path, img, seq, canvas, volume) {
  let lastSeq = 0, loading = false, want = 0;
  return async (sequence) => {
    want = Math.max(want, sequence);
    if (loading) return;
    loading = true;
    try {
      while (want > lastSeq) {
        const target = want;
        const png = await fetchBlob(`${path}/preview.png?resolution=64`);
        const got = Number(png.headers.get('X-Nimbus-Preview-Sequence'));
        const old = img.src;
        img.src = URL.createObjectURL(await png.blob());
        await img.decode().catch(() => {});
        if (old) URL.revokeObjectURL(old);
        // From the stream's announcement to the picture on screen.
        if (performance.getEntriesByName(`nimbus-preview-${got}`).length)
          performance.measure('nimbus-preview-shown', `nimbus-preview-${got}`);
        img.dataset.sequence = String(got);
        seq.textContent = `#${got}`;
        if (volume) {
          const raw = await fetchBlob(`${path}/preview.density?resolution=64`);
          const shape = raw.headers.get('X-Nimbus-Shape').split(',').map(Number);
          volume.setDensity(new Float32Array(await raw.arrayBuffer()), shape);
          canvas.dataset.sequence = raw.headers.get('X-Nimbus-Preview-Sequence');
        }
        lastSeq = Math.max(got, target);
      }
    } catch (e) { showError(e); } finally { loading = false; }
  };
}

function submitPage() {
  const text = el('textarea', { id: 'spec-text', rows: 18, cols: 80, placeholder: 'a spec in JSON (docs/spec_reference.md)' });
  const file = el('input', { id: 'spec-file', type: 'file', accept: '.json' });
  file.addEventListener('change', async () => { if (file.files[0]) text.value = await file.files[0].text(); });
  const submit = async () => {
    let spec;
    try { spec = JSON.parse(text.value); } catch (e) { return say(`spec: not JSON: ${e.message}`, true); }
    try {
      const { job } = await call('POST', '/api/v1/jobs', { spec });
      say(`submitted ${job.id}`);
      location.hash = `#/job/${encodeURIComponent(job.id)}`;
    } catch (e) { showError(e); }
  };
  main.append(el('h2', {}, 'Submit a job'), el('p', {}, file), text, el('p', {}, el('button', { id: 'submit', onclick: submit }, 'Submit')));
  return () => {};
}

function workersPage() {
  const box = el('div', { id: 'workers' });
  main.append(el('h2', {}, 'Workers'), box);
  call('GET', '/api/v1/workers').then((r) => {
    const head = ['Replica', 'Host', 'Version', 'Slots', 'Running', 'Last heartbeat', 'State'];
    box.append(el('table', {}, el('thead', {}, el('tr', {}, head.map((h) => el('th', {}, h)))),
      el('tbody', {}, (r.workers || []).map((w) => el('tr', {}, el('td', {}, w.replicaId), el('td', {}, w.host),
        el('td', {}, w.version), el('td', {}, w.workerSlots), el('td', {}, w.jobsRunning),
        el('td', {}, w.lastHeartbeat), el('td', {}, w.lost ? 'lost' : 'alive'))))));
  }).catch((e) => { box.append(el('p', {}, e.message)); });
  return () => {};
}

function route() {
  leave();
  clear(main);
  const hash = location.hash || '#/jobs';
  if (hash.startsWith('#/job/')) leave = jobPage(decodeURIComponent(hash.slice(6)));
  else if (hash === '#/submit') leave = submitPage();
  else if (hash === '#/workers') leave = workersPage();
  else leave = jobsPage();
}

document.getElementById('token-form').addEventListener('submit', (e) => {
  e.preventDefault();
  setToken(document.getElementById('token').value.trim());
  document.getElementById('token').value = '';
  document.getElementById('token-state').textContent = token() ? 'token set' : 'no token';
  route();
});
document.getElementById('token-state').textContent = token() ? 'token set' : 'no token';
window.addEventListener('hashchange', route);
call('GET', '/api/v1/info').then((r) => { features = r.features || []; }).catch(() => {}).finally(route);

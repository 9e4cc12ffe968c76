// A job page's event log: events the job's stream carries (add), and
// GET /api/v1/jobs/ID/events read page by page after the last seq shown,
// every second and on demand (refresh), for a stream that has ended or a
// server whose stream carries none. Events from any client or replica
// appear without reloading, each once, in seq order.
import { call } from './api.js';
import { el } from './dom.js';

// Fields naming another job link to its page; empty fields are left out.
const JOB_FIELDS = new Set(['retried_as', 'retried_from', 'cached_from']);

function eventItem(ev) {
  const fields = Object.entries(ev.fields || {}).filter(([, v]) => v !== '').sort(([a], [b]) => a.localeCompare(b));
  return el('li', { 'data-seq': ev.seq, 'data-kind': ev.kind },
    el('time', {}, ev.time || ''), ' ', el('b', { class: 'event-kind' }, ev.kind),
    fields.flatMap(([k, v]) => [' ', el('span', { class: 'event-field', 'data-name': k }, `${k}=`,
      JOB_FIELDS.has(k) ? el('a', { href: `#/job/${encodeURIComponent(v)}` }, v) : v)]));
}

// Returns { node, add, refresh, stop }: `node` is the list, `add(event)`
// shows one event (a JobEvent from the stream), `refresh()` reads new
// events now, `stop()` ends the polling. `onError` gets failures other than
// the job being gone.
export function eventLog(path, onError) {
  const node = el('ol', { id: 'events' });
  let last = 0, busy = false, again = false, stopped = false;
  // Events come in seq order from either source; one already shown is not
  // shown again.
  const add = (ev) => {
    if (stopped || Number(ev.seq) <= last) return;
    last = Number(ev.seq);
    node.append(eventItem(ev));
  };
  const read = async () => {
    for (;;) {
      const r = await call('GET', `${path}/events?page_size=500&after_seq=${last}`);
      const events = r.events || [];
      events.forEach(add);
      if (stopped || !Number(r.nextAfterSeq) || !events.length) return;
    }
  };
  const refresh = async () => {
    if (busy) { again = true; return; }
    busy = true;
    try {
      do { again = false; await read(); } while (again && !stopped);
    } catch (e) { if (e.status !== 404) onError(e); } finally { busy = false; }
  };
  const timer = setInterval(refresh, 1000);
  refresh();
  return { node, add, refresh, stop: () => { stopped = true; clearInterval(timer); } };
}

// Builds DOM nodes. Text always goes in as text nodes, never as HTML, so a
// job named <img src=x onerror=alert(1)> shows those characters.
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k.startsWith('on')) node.addEventListener(k.slice(2), v);
    else if (v !== undefined && v !== null && v !== false) node.setAttribute(k, v === true ? '' : String(v));
  }
  for (const c of children.flat()) {
    if (c === null || c === undefined || c === false) continue;
    node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return node;
}

export function clear(node) { while (node.firstChild) node.firstChild.remove(); }

export function shortState(s) { return (s || '').replace('JOB_STATE_', ''); }

export function kindOf(job) {
  const spec = job.spec || {};
  for (const k of ['chaosGame', 'setIfs', 'fractalField', 'jelly', 'explore']) if (spec[k]) return k;
  return job.kind || '';
}

export function progressText(p) {
  if (!p || !Number(p.total)) return '';
  const phase = (p.phase || '').replace('PROGRESS_PHASE_', '').toLowerCase();
  const rate = p.rate ? `${Number(p.rate).toExponential(2)} ${p.unit}/s` : '';
  const eta = p.etaSeconds ? `ETA ${Math.round(p.etaSeconds)} s` : '';
  const count = new Intl.NumberFormat('en', { notation: 'compact', maximumFractionDigits: 2 });
  const done = `${count.format(Number(p.done))}/${count.format(Number(p.total))} ${p.unit || ''}`;
  return [phase, done, rate, eta].filter(Boolean).join(' · ');
}

export function progressBar(p) {
  const frac = p && Number(p.total) ? Math.min(1, Number(p.done) / Number(p.total)) : 0;
  const fill = el('div');
  fill.style.width = `${(frac * 100).toFixed(1)}%`;  // CSSOM: allowed by the page's CSP
  return el('div', { class: 'bar', title: `${Math.round(frac * 100)} %` }, fill);
}

// The deltaz station's page: events from the station (server-sent: live, surface, status) drawn
// into the four panels, and the capture, session, comparison and plane-check requests. Text
// from the station is set as text; only the station's own SVG figures are inserted as markup.
'use strict';

const $ = (id) => document.getElementById(id);
const DOT_COLOURS = ['#1a9850', '#d73027']; // identified, not identified
// Latencies from a frame's read to its drawing on this page (ms), the newest last.
window.stationLatencies = [];

function setText(id, text, good) {
  const element = $(id);
  element.textContent = text;
  if (good !== undefined) {
    element.classList.toggle('ok', good);
    element.classList.toggle('bad', !good);
  }
}

function fixed(value, decimals) {
  return Number.isFinite(value) ? value.toFixed(decimals) : '–';
}

function row(table, cells, header) {
  const tr = document.createElement('tr');
  for (const cell of cells) {
    const td = document.createElement(header ? 'th' : 'td');
    if (cell instanceof Node) td.appendChild(cell); else td.textContent = cell;
    tr.appendChild(td);
  }
  table.appendChild(tr);
}

// Live: the frame, each dot circled in its state's colour, the counts.
const frameImage = new Image();
let pendingFrame = null;
frameImage.onload = () => {
  const f = pendingFrame;
  const canvas = $('live-canvas');
  if (canvas.width !== f.image_size[0]) canvas.width = f.image_size[0];
  if (canvas.height !== f.image_size[1]) canvas.height = f.image_size[1];
  const g = canvas.getContext('2d');
  g.drawImage(frameImage, 0, 0);
  g.lineWidth = 1.2;
  for (const [x, y, state] of f.dots) {
    g.strokeStyle = DOT_COLOURS[state];
    g.beginPath();
    g.arc(x, y, 3, 0, 2 * Math.PI);
    g.stroke();
  }
  const latency = Date.now() - f.read_ms;
  window.stationLatencies.push(latency);
  if (window.stationLatencies.length > 1000) window.stationLatencies.shift();
  setText('live-latency', `${latency.toFixed(0)} ms`);
};

function showLive(f) {
  setText('live-label', `${f.label} (#${f.seq})`);
  setText('live-fps', fixed(f.fps, 1));
  setText('live-dots', String(f.counts.dots));
  setText('live-points', String(f.counts.points));
  setText('live-not-identified', String(f.counts.not_identified));
  const notice = $('live-notice');
  notice.hidden = !f.notice;
  notice.textContent = f.notice || '';
  pendingFrame = f;
  frameImage.src = f.image;
}

// Surface: the station's figures and the measures with their σ.
function showSurface(s) {
  const message = $('surface-message');
  const note = $('surface-note');
  if (s.error) {
    note.hidden = true;
    $('surface-notes').replaceChildren();
    message.hidden = false;
    message.textContent = `no surface from the latest frames: ${s.error}`;
    return;
  }
  message.hidden = true;
  note.hidden = !s.analysis_note;
  note.textContent = s.analysis_note || '';
  $('surface-topography').innerHTML = s.topography_svg;
  $('surface-rotation').innerHTML = s.rotation_svg;
  $('surface').dataset.levels = String(s.levels);
  $('surface').dataset.leftOut = String(s.levels_left_out);
  const notes = $('surface-notes');
  notes.replaceChildren();
  for (const n of s.notes) {
    const li = document.createElement('li');
    li.textContent = n;
    notes.appendChild(li);
  }
  const table = $('surface-measures');
  table.replaceChildren();
  row(table, ['measure', 'value ± σ'], true);
  for (const [name, value, sigma, unit] of s.measures) {
    row(table, [name, `${fixed(value, 2)} ± ${fixed(sigma, 2)} ${unit}`]);
  }
  row(table, ['frames', `${s.frames} (the latest ${s.label})`]);
  row(table, ['points on the back', String(s.points)]);
  if (s.points_apart > 0) {
    row(table, ['points apart from it, left out (the arms, anything beside the subject)',
      String(s.points_apart)]);
  }
}

function showStatus(s) {
  setText('source-status', `source: ${s.source.text}`, s.source.ok);
  setText('device-status', `device: ${s.device.health.text}`, s.device.health.ok);
  setText('device-fingerprint', s.device.fingerprint || '–');
  setText('device-link-errors', String(s.device.link_errors));
  setText('device-resent', String(s.device.resent));
}

function connect() {
  const events = new EventSource('/events');
  events.addEventListener('live', (e) => showLive(JSON.parse(e.data)));
  events.addEventListener('surface', (e) => showSurface(JSON.parse(e.data)));
  events.addEventListener('status', (e) => showStatus(JSON.parse(e.data)));
  events.onopen = () => setText('connection', 'connected to the station', true);
  events.onerror = () => setText('connection', 'the station does not answer: trying again…', false);
}

async function request(url, body) {
  const options = body === undefined ? {} : {
    method: 'POST',
    headers: { 'Content-Type': 'application/json' },
    body: JSON.stringify(body),
  };
  const response = await fetch(url, options);
  const json = await response.json().catch(() => ({ error: `${response.status} ${response.statusText}` }));
  if (!response.ok) throw new Error(json.error || `${response.status}`);
  return json;
}

// Capture, sessions and their comparison.
async function loadSubjects() {
  const list = $('subjects');
  list.replaceChildren();
  for (const subject of await request('/api/subjects')) {
    const option = document.createElement('option');
    option.value = subject;
    list.appendChild(option);
  }
}

async function loadSessions(subject) {
  setText('sessions-subject', subject);
  const sessions = await request(`/api/subjects/${encodeURIComponent(subject)}/sessions`);
  const table = $('sessions');
  table.replaceChildren();
  row(table, ['session', 'posture', 'frames', 'points', 'largest rotation', 'report'], true);
  for (const s of sessions) {
    const link = document.createElement('a');
    link.href = `/sessions/${encodeURIComponent(subject)}/${encodeURIComponent(s.name)}/report.html`;
    link.target = '_blank';
    link.rel = 'noopener';
    link.textContent = 'report';
    const points = s.frames.reduce((n, f) => n + f.points, 0);
    const [r, sr] = s.rotation_max_deg;
    row(table, [s.name, s.posture, String(s.frames.length), String(points),
      `${fixed(r, 1)} ± ${fixed(sr, 1)}°`, link]);
  }
  for (const id of ['before', 'after']) {
    const select = $(id);
    select.replaceChildren();
    for (const s of sessions) {
      const option = document.createElement('option');
      option.value = option.textContent = s.name;
      select.appendChild(option);
    }
  }
  if (sessions.length > 1) $('before').selectedIndex = sessions.length - 2;
  $('after').selectedIndex = sessions.length - 1;
}

$('capture-form').addEventListener('submit', async (e) => {
  e.preventDefault();
  const subject = $('subject').value.trim();
  setText('capture-message', 'capturing…');
  try {
    const s = await request('/api/capture', { subject, posture: $('posture').value });
    const [r, sr] = s.rotation_max_deg;
    setText('capture-message', `saved session ${s.name} of ${s.subject}: ${s.frames.length} frames, `
      + `largest surface rotation ${fixed(r, 1)} ± ${fixed(sr, 1)}°`
      + (s.analysis_note ? `. ${s.analysis_note}` : ''), true);
    $('capture').dataset.session = s.name;
    await loadSubjects();
    await loadSessions(subject);
  } catch (error) {
    setText('capture-message', `not captured: ${error.message}`, false);
  }
});

$('subject').addEventListener('change', () => {
  const subject = $('subject').value.trim();
  if (subject) loadSessions(subject).catch((error) => setText('capture-message', error.message, false));
});

$('compare-form').addEventListener('submit', async (e) => {
  e.preventDefault();
  const subject = $('sessions-subject').textContent;
  const query = new URLSearchParams({ subject, before: $('before').value, after: $('after').value });
  try {
    const c = await request(`/api/compare?${query}`);
    const table = $('comparison');
    table.replaceChildren();
    row(table, ['measure', 'before', 'after', 'change ± σ', ''], true);
    for (const d of c.indices) {
      row(table, [d.name, fixed(d.before, 2), fixed(d.after, 2), `${fixed(d.change, 2)} ± ${fixed(d.sigma, 2)}`,
        d.exceeds_noise ? 'exceeds the noise' : 'within the noise']);
    }
    const beyond = c.levels.filter((l) => l.rotation_deg.exceeds_noise).length;
    setText('compare-message', `${c.before} → ${c.after}: surface rotation changed beyond the noise `
      + `(${fixed(c.threshold, 2)} σ) at ${beyond} of ${c.levels.length} levels`
      + c.notes.map((note) => `; ${note}`).join(''), true);
  } catch (error) {
    setText('compare-message', `no comparison: ${error.message}`, false);
  }
});

// Calibration: its facts, and the plane check.
async function loadCalibration() {
  const c = await request('/api/calibration');
  const facts = $('calibration-facts');
  facts.replaceChildren();
  const fact = (name, value) => {
    const dt = document.createElement('dt');
    dt.textContent = name;
    const dd = document.createElement('dd');
    dd.textContent = value;
    facts.append(dt, dd);
  };
  fact('fingerprint', c.fingerprint);
  fact('date', c.date || '–');
  fact('model', `${c.model}, ${c.rays} rays, ${c.frame}`);
  for (const [group, sigma] of Object.entries(c.sigma0_px)) {
    fact(`σ0 ${group}`, sigma === null ? '–' : `${fixed(sigma, 3)} px`);
  }
  const warnings = $('calibration-warnings');
  warnings.replaceChildren();
  for (const w of c.warnings.length ? c.warnings : ['no warnings']) {
    const li = document.createElement('li');
    li.textContent = w;
    warnings.appendChild(li);
  }
}

$('plane-button').addEventListener('click', async () => {
  setText('plane-verdict', 'checking…');
  try {
    const p = await request('/api/plane-check', {});
    setText('plane-verdict', p.verdict, p.holds);
  } catch (error) {
    setText('plane-verdict', `no verdict: ${error.message}`, false);
  }
});

connect();
loadSubjects().catch(() => {});
loadCalibration().catch((error) => setText('plane-verdict', `calibration: ${error.message}`, false));

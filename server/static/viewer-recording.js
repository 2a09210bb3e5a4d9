// Recording panel: start and stop a take, and the list of takes (REST /api/recordings,
// docs/recording.md). Recordings are people's motion: every call carries the token.
//
// The list is polled every 3 s, every second while a take is being recorded.

const TAKES_SHOWN = 8;

function el(id) {
  return document.getElementById(id);
}

function duration(s) {
  if (!Number.isFinite(s)) return '–';
  const m = Math.floor(s / 60);
  const sec = s - m * 60;
  return m > 0 ? `${m} min ${sec.toFixed(0)} s` : `${sec.toFixed(1)} s`;
}

function size(bytes) {
  if (!Number.isFinite(bytes)) return '–';
  if (bytes >= 1e6) return `${(bytes / 1e6).toFixed(1)} MB`;
  return `${Math.max(1, Math.round(bytes / 1e3))} kB`;
}

function detailOf(res) {
  const d = res.data && res.data.detail;
  return typeof d === 'string' ? d : `HTTP ${res.status}`;
}

/**
 * @param {object} o
 * @param {import('./skelfuse-client.js').ApiClient} o.api
 * @param {object} o.hook the viewer's test hook (recording* and takes* fields are written)
 * @returns {{poll: () => void}} poll() reads the list at once (after a new token)
 */
export function initRecording({ api, hook }) {
  const ui = {
    section: el('hud-recording'),
    summary: el('rec-summary'),
    name: el('rec-name'),
    start: el('rec-start'),
    stop: el('rec-stop'),
    status: el('rec-status'),
    table: el('rec-takes'),
    rows: el('rec-take-rows'),
    error: el('rec-error'),
  };
  Object.assign(hook, {
    recordingId: null, // the take being recorded, or null
    takesListed: 0, // takes in the last GET /api/recordings answer
    takeIds: [], // their ids, newest first
    recordingError: null, // the last refusal shown in the panel, or null
  });
  let running = null; // the entry of the take being recorded
  let busy = false;
  let timer = null;
  let listKey = '';

  function showError(text) {
    hook.recordingError = text || null;
    ui.error.hidden = !text;
    ui.error.textContent = text || '';
    if (text) ui.section.open = true;
  }

  function render(list) {
    running = list.find((r) => r && r.state === 'recording') || null;
    hook.recordingId = running ? running.id : null;
    hook.takesListed = list.length;
    hook.takeIds = list.map((r) => r.id);
    ui.start.disabled = busy || running !== null;
    ui.stop.disabled = busy || running === null;
    ui.name.disabled = running !== null;
    ui.summary.textContent = running
      ? `● recording ${duration(running.duration_s)}`
      : list.length
        ? `${list.length} take${list.length === 1 ? '' : 's'}`
        : 'no takes';
    ui.summary.classList.toggle('rec-live', running !== null);
    ui.status.textContent = running
      ? `recording ${running.id}: ${duration(running.duration_s)}, ${running.frames} frames, ${size(running.size_bytes)}`
      : '';
    const key = JSON.stringify(list.slice(0, TAKES_SHOWN).map((r) => [r.id, r.state, r.frames, r.size_bytes]));
    if (key === listKey) return;
    listKey = key;
    ui.table.hidden = list.length === 0;
    ui.rows.replaceChildren(...list.slice(0, TAKES_SHOWN).map(takeRow));
  }

  function takeRow(r) {
    const tr = document.createElement('tr');
    tr.dataset.id = r.id;
    const name = document.createElement('td');
    name.className = 'rec-take';
    name.textContent = r.name || r.id;
    name.title = [r.id, r.state, Array.isArray(r.sensors) ? r.sensors.join(', ') : '', r.error || '']
      .filter(Boolean)
      .join('\n');
    const cells = [duration(r.duration_s), Number.isFinite(r.frames) ? String(r.frames) : '–', size(r.size_bytes)];
    const tds = cells.map((text) => {
      const td = document.createElement('td');
      td.className = 'num';
      td.textContent = text;
      return td;
    });
    const act = document.createElement('td');
    if (r.state === 'recording') {
      act.textContent = '●';
      act.className = 'rec-live';
    } else {
      const b = document.createElement('button');
      b.type = 'button';
      b.textContent = '⤓';
      b.title = `download ${r.id}`;
      b.addEventListener('click', () => download(r.id));
      act.appendChild(b);
    }
    tr.append(name, ...tds, act);
    return tr;
  }

  async function download(id) {
    try {
      const r = await fetch(`/api/recordings/${encodeURIComponent(id)}/download`, { headers: api.headers() });
      if (!r.ok) {
        showError(`download: HTTP ${r.status}`);
        return;
      }
      const url = URL.createObjectURL(await r.blob());
      const a = document.createElement('a');
      a.href = url;
      a.download = `${id}.sfrec`;
      a.click();
      setTimeout(() => URL.revokeObjectURL(url), 10000);
    } catch (e) {
      showError(`download: ${e && e.message ? e.message : e}`);
    }
  }

  async function poll() {
    clearTimeout(timer);
    try {
      const r = await api.json('GET', '/api/recordings');
      if (r.ok && r.data && Array.isArray(r.data.recordings)) {
        render(r.data.recordings);
        if (hook.recordingError && hook.recordingError.startsWith('takes:')) showError('');
      } else if (r.status === 401) {
        showError('takes: this server needs the token to list or record takes');
      }
    } catch (e) {
      // transient (server restarting): the next poll retries
    } finally {
      timer = setTimeout(poll, running ? 1000 : 3000);
    }
  }

  async function act(fn) {
    if (busy) return;
    busy = true;
    ui.start.disabled = ui.stop.disabled = true;
    showError('');
    try {
      await fn();
    } catch (e) {
      showError(e && e.message ? e.message : String(e));
    } finally {
      busy = false;
      await poll();
    }
  }

  ui.start.addEventListener('click', () =>
    act(async () => {
      const name = ui.name.value.trim();
      const r = await api.json('POST', '/api/recordings', name ? { name } : {});
      if (!r.ok) showError(`record: ${detailOf(r)}`);
    }),
  );
  ui.stop.addEventListener('click', () =>
    act(async () => {
      if (!running) return;
      const r = await api.json('POST', `/api/recordings/${encodeURIComponent(running.id)}/stop`);
      if (!r.ok) showError(`stop: ${detailOf(r)}`);
      else ui.name.value = '';
    }),
  );
  poll();
  return { poll };
}

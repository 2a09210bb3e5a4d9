// skelfuse browser client: the live feed (WebSocket /ws/skeletons) and the REST API, as an ES
// module with no dependencies. The viewer uses it; any page can:
//
//   import { FeedClient, ApiClient } from 'http://server:8000/static/skelfuse-client.js';
//   const feed = new FeedClient({ token, onFrame: (f) => draw(f.persons) });
//   feed.start();
//
// The feed reconnects by itself with exponential backoff (250 ms doubling to 3 s, reset by the
// first message of a connection). A server started with --token refuses a feed without the right
// token during the handshake, which a browser only sees as a close (code 1006, no reason), the
// same as a server that is down. After a connection that never opened, the client asks an
// endpoint that needs the token (GET /api/persons): a 401 there means the token is missing or
// wrong, and the client reports the state "refused" and stops retrying until setToken() is called.
// Frames are plain objects as specified in docs/api.md; the typedefs below give their shape.

/**
 * @typedef {[number, number, number]} Point3 x, y, z in metres (world frame: +Y up, floor y = 0)
 */

/**
 * @typedef {object} SkeletonMessage  First message of a connection (also GET /api/skeleton).
 * @property {'skeleton'} type
 * @property {number} v protocol major version (1)
 * @property {string} name e.g. "kinect_v2_25"
 * @property {string[]} joints joint names, in index order
 * @property {number[]} parents parent index per joint, -1 for the root
 * @property {Array<[number, number]>} bones [parent, child] index pairs
 */

/**
 * @typedef {object} Person  A fused person.
 * @property {number} id stable while any sensor sees the person
 * @property {Array<Point3 | null>} joints one entry per joint, null where no sensor has it
 * @property {number[]} confidence per joint in [0, 1]: 1 − Π(1 − w_k) over the views' weights
 * @property {string[]} sources sensor ids fused into this person
 * @property {number[]} joint_sources per joint, bit k set when sources[k] carried ≥ 5 %
 * @property {string[]} [mirrored] sensors whose view was swapped back left/right
 */

/**
 * @typedef {object} RawBody  One sensor's own body (feed with raw=1), world frame.
 * @property {string} sensor sensor id
 * @property {string} tracking_id the SDK's body id, as a string
 * @property {Array<Point3 | null>} joints
 * @property {number[]} states per joint: 0 NotTracked, 1 Inferred, 2 Tracked
 */

/**
 * @typedef {object} FrameMessage  One fused frame (about 30 per second).
 * @property {'frame'} type
 * @property {number} v
 * @property {number} seq +1 per frame the server produced; gaps when a client falls behind
 * @property {number} t capture instant, Unix seconds on the server's clock
 * @property {number} t_sent when the server sent it, Unix seconds
 * @property {Person[]} persons
 * @property {RawBody[]} [raw] with raw=1 only
 * @property {Object<string, number>} [extrapolated] sensor id -> seconds carried forward
 */

/**
 * @typedef {'connecting' | 'open' | 'closed' | 'refused' | 'stopped'} FeedState
 * closed: dropped, a retry is scheduled (info.retryMs); refused: the token is missing or wrong
 * (info.reason), no retry until setToken().
 */

/**
 * @typedef {object} ApiResult
 * @property {boolean} ok HTTP 2xx
 * @property {number} status HTTP status
 * @property {any} data the parsed JSON body, or null
 */

export const BACKOFF_MIN_MS = 250;
export const BACKOFF_MAX_MS = 3000;
export const TOKEN_STORAGE_KEY = 'skelfuse.token';

/** The token for this page: ?token= in its address, else the one stored for this browser tab
 * session (sessionStorage), else null. */
export function pageToken() {
  const fromUrl = new URLSearchParams(location.search).get('token');
  if (fromUrl) return fromUrl;
  try {
    return sessionStorage.getItem(TOKEN_STORAGE_KEY) || null;
  } catch (e) {
    return null; // storage disabled
  }
}

/** Keeps `token` for this tab's session (cleared when the tab closes); null forgets it. */
export function storeToken(token) {
  try {
    if (token) sessionStorage.setItem(TOKEN_STORAGE_KEY, token);
    else sessionStorage.removeItem(TOKEN_STORAGE_KEY);
  } catch (e) {
    // storage disabled: the token lasts as long as the page
  }
}

/** REST calls with the bearer token, JSON in and out. */
export class ApiClient {
  /**
   * @param {{base?: string, token?: string | null, timeoutMs?: number}} [options]
   *   base: the server's origin ('' = this page's), timeoutMs: per request (8000)
   */
  constructor(options = {}) {
    this.base = options.base || '';
    this.token = options.token || null;
    this.timeoutMs = options.timeoutMs || 8000;
  }

  /** @param {string | null} token */
  setToken(token) {
    this.token = token || null;
  }

  /** Headers for a fetch of your own (a download): Authorization when a token is set. */
  headers() {
    return this.token ? { Authorization: `Bearer ${this.token}` } : {};
  }

  /**
   * @param {string} method
   * @param {string} path e.g. '/api/sensors'
   * @param {any} [body] sent as JSON when given
   * @param {{timeoutMs?: number}} [options]
   * @returns {Promise<ApiResult>} 4xx/5xx are results too (ok false, data.detail says why)
   * @throws on network errors; an AbortError on timeout
   */
  async json(method, path, body, options = {}) {
    const ctrl = new AbortController();
    const timer = setTimeout(() => ctrl.abort(), options.timeoutMs || this.timeoutMs);
    try {
      const init = { method, cache: 'no-store', signal: ctrl.signal, headers: this.headers() };
      if (body !== undefined) {
        init.headers['Content-Type'] = 'application/json';
        init.body = JSON.stringify(body);
      }
      const r = await fetch(this.base + path, init);
      let data = null;
      try {
        data = await r.json();
      } catch (e) {
        data = null;
      }
      return { ok: r.ok, status: r.status, data };
    } finally {
      clearTimeout(timer);
    }
  }

  /** Whether the server takes this token: false on a 401 from an endpoint that needs it. */
  async tokenAccepted() {
    const r = await this.json('GET', '/api/persons', undefined, { timeoutMs: 4000 });
    return r.status !== 401;
  }
}

/** The live feed, reconnecting with backoff. */
export class FeedClient {
  /**
   * @param {object} options
   * @param {string} [options.url] ws(s)://host/ws/skeletons (default: this page's server)
   * @param {string | null} [options.token] the server's --token
   * @param {boolean} [options.raw] also receive every sensor's own bodies
   * @param {Object<string, string>} [options.params] more query parameters
   * @param {ApiClient} [options.api] used to tell a refusal from an outage
   * @param {(m: SkeletonMessage) => void} [options.onSkeleton]
   * @param {(m: FrameMessage) => void} [options.onFrame]
   * @param {(m: object) => void} [options.onOther] messages of other types
   * @param {(s: FeedState, info: {retryMs?: number, reason?: string, code?: number}) => void} [options.onState]
   * @param {(text: string) => void} [options.onError] undecodable messages
   */
  constructor(options = {}) {
    const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
    this.url = options.url || `${proto}//${location.host}/ws/skeletons`;
    this.token = options.token || null;
    this.raw = Boolean(options.raw);
    this.params = options.params || {};
    this.api = options.api || new ApiClient({ token: this.token });
    this.onSkeleton = options.onSkeleton || (() => {});
    this.onFrame = options.onFrame || (() => {});
    this.onOther = options.onOther || (() => {});
    this.onState = options.onState || (() => {});
    this.onError = options.onError || (() => {});
    this.backoffMs = BACKOFF_MIN_MS;
    /** @type {FeedState} */
    this.state = 'stopped';
    this.socket = null;
    this.timer = null;
    this.generation = 0; // bumped by stop/setToken: events of older sockets are ignored
  }

  /** The address connected to, token included. */
  socketUrl() {
    const q = new URLSearchParams(this.params);
    if (this.raw) q.set('raw', '1');
    if (this.token) q.set('token', this.token);
    const query = q.toString();
    return query ? `${this.url}?${query}` : this.url;
  }

  start() {
    if (this.state !== 'stopped' && this.state !== 'refused') return;
    this.connect();
  }

  stop() {
    this.generation++;
    clearTimeout(this.timer);
    if (this.socket) this.socket.close(1000, 'client stopped');
    this.socket = null;
    this.setState('stopped', {});
  }

  /** A new token: reconnects at once with it (and the API client uses it too). */
  setToken(token) {
    this.token = token || null;
    this.api.setToken(this.token);
    this.stop();
    this.backoffMs = BACKOFF_MIN_MS;
    this.connect();
  }

  setState(state, info) {
    this.state = state;
    this.onState(state, info);
  }

  connect() {
    clearTimeout(this.timer);
    const gen = ++this.generation;
    this.setState('connecting', {});
    let ws;
    try {
      ws = new WebSocket(this.socketUrl());
    } catch (e) {
      this.onError(`WebSocket: ${e && e.message ? e.message : e}`);
      this.retry(gen);
      return;
    }
    this.socket = ws;
    let opened = false;
    ws.onopen = () => {
      if (gen !== this.generation) return;
      opened = true;
      this.setState('open', {});
    };
    ws.onmessage = (ev) => {
      if (gen !== this.generation) return;
      this.backoffMs = BACKOFF_MIN_MS; // the server talks: the next drop retries quickly
      this.handle(ev.data);
    };
    ws.onerror = () => {}; // a close event follows
    ws.onclose = (ev) => {
      if (gen !== this.generation) return;
      this.socket = null;
      if (ev.code === 1008 && /token/i.test(ev.reason || '')) {
        this.setState('refused', { code: ev.code, reason: ev.reason });
        return;
      }
      if (opened) {
        this.retry(gen, ev.code);
        return;
      }
      // Never opened: a refusal looks like an outage; the REST side tells them apart.
      this.api.tokenAccepted().then(
        (accepted) => {
          if (gen !== this.generation) return;
          if (accepted) this.retry(gen, ev.code);
          else {
            this.setState('refused', {
              code: ev.code,
              reason: this.token ? 'the server refused this token' : 'this server needs a token',
            });
          }
        },
        () => gen === this.generation && this.retry(gen, ev.code), // server down: retry
      );
    };
  }

  retry(gen, code) {
    if (gen !== this.generation) return;
    const delay = this.backoffMs;
    this.backoffMs = Math.min(this.backoffMs * 2, BACKOFF_MAX_MS);
    this.setState('closed', { retryMs: delay, code });
    this.timer = setTimeout(() => {
      if (gen === this.generation) this.connect();
    }, delay);
  }

  handle(data) {
    if (typeof data !== 'string') return; // msgpack is not asked for
    let msg;
    try {
      msg = JSON.parse(data);
    } catch (e) {
      this.onError(`bad JSON from /ws/skeletons: ${e.message}`);
      return;
    }
    if (!msg || typeof msg !== 'object') return;
    if (msg.type === 'skeleton') this.onSkeleton(msg);
    else if (msg.type === 'frame') this.onFrame(msg);
    else this.onOther(msg);
  }
}

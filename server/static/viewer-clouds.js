// Depth point clouds and raw bodies for setting up: each sensor's downsampled cloud and the bodies
// it sees, coloured per sensor and placed with the sensor's pose, so one sees whether the
// sensors' clouds line up, before and during calibration (docs/api.md, "Setting sensors up").
//
// Data: GET /api/sensors/{id}/cloud?max_points=N -> {sensor_id, frame: "world" | "sensor",
// t_capture, pose, points: [[x, y, z], ...] metres} and GET /api/sensors/{id}/bodies ->
// {pose, bodies: [{joints, joints_world, states}]}. The server places both with the sensor's
// pose: the active calibration's, or mid-calibration the run's provisional one (pose
// "provisional"). Asked on request only (the "depth clouds" box). An agent renders a cloud on
// its CPU and skips frames meanwhile (a simulated one takes 0.3-1 s), and one the server gave up
// on (503 after 5 s) still renders it: asked again at once, a loaded agent would render clouds
// back to back and starve the feed (1 frame/s seen at load 15). So the sensors are asked one
// after the other, the next round waits twice as long as the last one took (REFRESH_MS at the
// least), or BACKOFF_MS after a refusal. The bodies (the newest frame the
// server holds: cheap) every BODIES_MS.
//
// A sensor without any pose yet ("sensor" frame) is drawn in a row beside the others
// (UNPLACED_*), each seen from its own sensor looking along +z.

import * as THREE from 'three';

export const MAX_POINTS = 3000;
export const POINT_SIZE_PX = 3;
const REFRESH_MS = 2000;
const BACKOFF_MS = 10000;
const BODIES_MS = 300;
const REQUEST_TIMEOUT_MS = 15000; // an agent renders the cloud: slow under load
const UNPLACED_SPACING_M = 4.5;
const UNPLACED_HEIGHT_M = 1.0;
const UNPLACED_Z_M = -2.5;

/** A sensor's cloud and bodies in the scene. */
class SensorCloud {
  constructor(id, color, parent) {
    this.id = id;
    this.group = new THREE.Group();
    this.group.matrixAutoUpdate = false; // identity for the world frame, else the row's slot
    this.geometry = new THREE.BufferGeometry();
    this.material = new THREE.PointsMaterial({
      color,
      size: POINT_SIZE_PX,
      sizeAttenuation: false, // pixels on screen: a far sensor's cloud stays visible
    });
    this.points = new THREE.Points(this.geometry, this.material);
    this.points.frustumCulled = false;
    this.bodyGeometry = new THREE.BufferGeometry();
    this.bodies = new THREE.LineSegments(this.bodyGeometry, new THREE.LineBasicMaterial({ color }));
    this.bodies.frustumCulled = false;
    this.group.add(this.points, this.bodies);
    this.group.visible = false;
    this.frame = null; // of the last cloud: 'world' | 'sensor'
    this.pose = null; // its pose source: stored, sim_truth, manual, provisional, or null
    this.count = 0;
    this.bodyCount = 0;
    parent.add(this.group);
  }

  /** Replaces the points with a cloud answer's (N × 3, metres, in its `frame`). */
  setCloud(answer) {
    const pts = Array.isArray(answer.points) ? answer.points : [];
    const flat = new Float32Array(pts.length * 3);
    let n = 0;
    for (const p of pts) {
      if (!Array.isArray(p) || p.length !== 3 || !p.every(Number.isFinite)) continue;
      flat[n * 3] = p[0];
      flat[n * 3 + 1] = p[1];
      flat[n * 3 + 2] = p[2];
      n++;
    }
    this.geometry.dispose(); // a new size each time: a fresh GPU buffer
    this.geometry = new THREE.BufferGeometry();
    this.geometry.setAttribute('position', new THREE.BufferAttribute(flat.subarray(0, n * 3), 3));
    this.points.geometry = this.geometry;
    this.count = n;
    this.frame = answer.frame === 'world' ? 'world' : 'sensor';
    this.pose = typeof answer.pose === 'string' ? answer.pose : null;
  }

  /** Replaces the bodies with a bodies answer's, in the same frame as the cloud. */
  setBodies(answer, bones) {
    const segs = [];
    const bodies = Array.isArray(answer.bodies) ? answer.bodies : [];
    const world = this.frame === 'world';
    let n = 0;
    for (const body of bodies) {
      const joints = body && (world ? body.joints_world : body.joints);
      if (!Array.isArray(joints)) continue;
      n++;
      for (const [a, c] of bones) {
        const pa = joints[a];
        const pc = joints[c];
        if (Array.isArray(pa) && Array.isArray(pc) && pa.length === 3 && pc.length === 3) segs.push(...pa, ...pc);
      }
    }
    this.bodyGeometry.dispose();
    this.bodyGeometry = new THREE.BufferGeometry();
    this.bodyGeometry.setAttribute('position', new THREE.Float32BufferAttribute(segs, 3));
    this.bodies.geometry = this.bodyGeometry;
    this.bodyCount = n;
  }

  /** `matrix` maps the cloud's frame into the world. */
  place(matrix) {
    this.group.matrix.copy(matrix);
    this.group.matrixWorldNeedsUpdate = true;
    this.group.visible = this.count > 0;
  }

  dispose() {
    this.group.removeFromParent();
    this.geometry.dispose();
    this.bodyGeometry.dispose();
    this.material.dispose();
    this.bodies.material.dispose();
  }
}

export class CloudLayer {
  /**
   * @param {object} o
   * @param {THREE.Scene} o.scene
   * @param {import('./skelfuse-client.js').ApiClient} o.api
   * @param {(id: string) => THREE.Color} o.colorOf the sensor's colour
   * @param {() => Array<[number, number]>} o.bones the skeleton's bones (for bodies)
   * @param {() => void} o.requestRender
   * @param {object} o.hook the viewer's test hook (cloud* fields are written)
   * @param {(text: string) => void} o.onNote a line for the HUD ('' clears it)
   * @param {(poses: Map<string, number[][]>) => void} o.onProvisional the sensors placed by a
   *   running calibration's provisional pose (T_world_from_sensor, 4×4), from their bodies answers
   */
  constructor(o) {
    Object.assign(this, o);
    this.root = new THREE.Group();
    this.root.visible = false;
    this.scene.add(this.root);
    this.clouds = new Map(); // id -> SensorCloud
    this.sensorIds = [];
    this.enabled = false;
    this.timer = null;
    this.bodiesTimer = null;
    this.running = false;
    this.generation = 0;
    this.provisional = new Map(); // id -> T_world_from_sensor of a provisional pose
    Object.assign(this.hook, {
      cloudsEnabled: false, // state of the "depth clouds" box
      cloudsDrawn: 0, // sensors whose cloud is in the scene
      cloudPoints: {}, // sensor id -> points drawn
      cloudPoses: {}, // sensor id -> where its placement comes from (the answer's pose, or null)
      cloudBodies: {}, // sensor id -> bodies drawn from GET /api/sensors/{id}/bodies
      cloudsUnplaced: [], // sensors drawn in the row (no pose yet)
      cloudRounds: 0, // completed rounds of cloud requests
      cloudErrors: {}, // sensor id -> the last refusal or failure of its cloud
    });
  }

  /** The sensors to ask (the connected ones /api/sensors lists). */
  setSensors(ids) {
    this.sensorIds = [...ids].sort();
    for (const [id, cloud] of this.clouds) {
      if (!this.sensorIds.includes(id)) {
        cloud.dispose();
        this.clouds.delete(id);
      }
    }
    this.placeAll();
  }

  setEnabled(on) {
    this.enabled = on;
    this.hook.cloudsEnabled = on;
    this.generation++;
    clearTimeout(this.timer);
    clearTimeout(this.bodiesTimer);
    this.root.visible = on;
    if (on) {
      this.round(this.generation);
      this.pollBodies(this.generation);
    } else {
      this.onNote('');
      this.provisional.clear();
      this.onProvisional(this.provisional);
    }
    this.placeAll();
  }

  async round(gen) {
    if (this.running) return;
    this.running = true;
    const started = performance.now();
    let delay = REFRESH_MS;
    try {
      const errors = {};
      for (const id of this.sensorIds) {
        if (gen !== this.generation) return;
        const text = await this.fetchCloud(id);
        if (text) errors[id] = text;
      }
      if (gen !== this.generation) return;
      const took = performance.now() - started;
      delay = Object.keys(errors).length ? BACKOFF_MS : Math.max(REFRESH_MS, 2 * took);
      this.hook.cloudErrors = errors;
      this.hook.cloudRounds++;
      const failed = Object.entries(errors);
      this.onNote(failed.length ? `depth: ${failed.map(([id, t]) => `${id} ${t}`).join('; ')}` : '');
    } finally {
      this.running = false;
      if (gen === this.generation && this.enabled) {
        this.timer = setTimeout(() => this.round(gen), delay);
      }
    }
  }

  async pollBodies(gen) {
    try {
      for (const id of this.sensorIds) {
        const cloud = this.clouds.get(id);
        if (!cloud || gen !== this.generation) continue; // bodies follow their cloud's frame
        const r = await this.api.json('GET', `/api/sensors/${encodeURIComponent(id)}/bodies`);
        if (gen !== this.generation) return;
        if (r.ok && r.data && typeof r.data === 'object') {
          cloud.setBodies(r.data, this.bones());
          const T = r.data.T_world_from_sensor;
          if (r.data.pose === 'provisional' && Array.isArray(T)) this.provisional.set(id, T);
          else this.provisional.delete(id);
        }
      }
      for (const id of this.provisional.keys()) if (!this.sensorIds.includes(id)) this.provisional.delete(id);
      this.onProvisional(this.provisional);
      this.placeAll();
    } catch (e) {
      // transient: the next poll retries
    } finally {
      if (gen === this.generation && this.enabled) {
        this.bodiesTimer = setTimeout(() => this.pollBodies(gen), BODIES_MS);
      }
    }
  }

  /** Asks one sensor's cloud; returns an error text, or '' when drawn. */
  async fetchCloud(id) {
    let r;
    try {
      r = await this.api.json(
        'GET',
        `/api/sensors/${encodeURIComponent(id)}/cloud?max_points=${MAX_POINTS}`,
        undefined,
        { timeoutMs: REQUEST_TIMEOUT_MS },
      );
    } catch (e) {
      return e && e.name === 'AbortError' ? 'timeout' : String(e && e.message ? e.message : e);
    }
    if (!r.ok || !r.data || typeof r.data !== 'object') {
      const d = r.data && r.data.detail;
      return typeof d === 'string' ? d : `HTTP ${r.status}`;
    }
    if (!this.enabled) return '';
    let cloud = this.clouds.get(id);
    if (!cloud) {
      cloud = new SensorCloud(id, this.colorOf(id), this.root);
      this.clouds.set(id, cloud);
    }
    cloud.setCloud(r.data);
    this.placeAll();
    return '';
  }

  /** Re-applies the placements (the row depends on how many sensors have no pose). */
  placeAll() {
    const unplaced = this.sensorIds.filter((id) => {
      const c = this.clouds.get(id);
      return c && c.frame === 'sensor';
    });
    const matrix = new THREE.Matrix4();
    const points = {};
    const poses = {};
    const bodies = {};
    let drawn = 0;
    for (const [id, cloud] of this.clouds) {
      const k = unplaced.indexOf(id);
      if (k < 0) matrix.identity();
      else {
        const x = (k - (unplaced.length - 1) / 2) * UNPLACED_SPACING_M;
        matrix.makeTranslation(x, UNPLACED_HEIGHT_M, UNPLACED_Z_M);
      }
      cloud.place(matrix);
      if (cloud.group.visible) {
        drawn++;
        points[id] = cloud.count;
        poses[id] = cloud.pose;
        bodies[id] = cloud.bodyCount;
      }
    }
    const on = this.enabled;
    this.hook.cloudsDrawn = on ? drawn : 0;
    this.hook.cloudPoints = on ? points : {};
    this.hook.cloudPoses = on ? poses : {};
    this.hook.cloudBodies = on ? bodies : {};
    this.hook.cloudsUnplaced = on ? unplaced : [];
    this.requestRender();
  }
}

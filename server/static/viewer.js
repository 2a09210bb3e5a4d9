// skelfuse live viewer: fused skeletons, raw per-sensor views and sensor poses in three.js.
//
// Data: WebSocket /ws/skeletons?raw=1 (skeleton definition, then frames) and GET /api/sensors
// polled once a second. World frame = three.js frame (right-handed, +Y up, metres, floor y = 0).
//
// Test hook: window.skelfuseViewer (see HOOK below), refreshed after every render.

import * as THREE from 'three';
import { OrbitControls } from './vendor/OrbitControls.js';

// --- test hook ---------------------------------------------------------------------------------

const HOOK = {
  connected: false, // WebSocket open
  framesReceived: 0, // "frame" messages received since page load (all connections)
  lastSeq: -1, // seq of the newest frame received (-1: none yet)
  personsDrawn: 0, // fused persons currently in the scene
  jointsDrawn: 0, // visible fused joint spheres (non-null joints) over all persons
  bonesDrawn: 0, // fused bone segments drawn (both ends non-null)
  rawViewsDrawn: 0, // raw per-sensor bodies drawn (0 while "raw views" is off)
  sensorsDrawn: 0, // sensor frustums drawn (sensors with a known T_world_from_sensor)
  skeletonName: null, // "name" of the skeleton definition received, or null
  errors: [], // problems seen (bad messages, WebGL failure, uncaught exceptions); capped
  // extras, informative only
  webgl: false, // a WebGL renderer was created
  rawEnabled: false, // state of the "raw views" checkbox
  fps: 0, // frames/s received over the last second
  renders: 0, // render passes done
  applyMs: 0, // time spent applying the last frame to the scene (JS only, not GPU)
  renderMs: 0, // time spent in the last renderer.render() call (CPU side)
  gpuGeometries: 0, // renderer.info.memory.geometries: constant while the scene content is steady
  gpuTextures: 0, // renderer.info.memory.textures
  sensorsListed: 0, // sensors in the last /api/sensors answer
};
window.skelfuseViewer = HOOK;

const MAX_ERRORS = 50;
let lastErrorText = '';

function reportError(text) {
  const msg = String(text);
  if (msg === lastErrorText) return; // a repeating problem is reported once
  lastErrorText = msg;
  HOOK.errors.push(msg);
  if (HOOK.errors.length > MAX_ERRORS) HOOK.errors.splice(0, HOOK.errors.length - MAX_ERRORS);
  console.warn('[skelfuse viewer]', msg);
  const el = document.getElementById('hud-error');
  if (el) {
    el.hidden = false;
    el.textContent = msg;
  }
}

window.addEventListener('error', (ev) => reportError(`uncaught: ${ev.message || ev}`));
window.addEventListener('unhandledrejection', (ev) => reportError(`unhandled rejection: ${ev.reason}`));

// --- skeleton definition -------------------------------------------------------------------------

// Kinect v2 (kinect_v2_25) parents: used only until the server's definition arrives.
const FALLBACK_PARENTS = [
  -1, 0, 20, 2, 20, 4, 5, 6, 20, 8, 9, 10, 0, 12, 13, 14, 0, 16, 17, 18, 1, 7, 6, 11, 10,
];

const skeleton = {
  name: null,
  jointCount: FALLBACK_PARENTS.length,
  bones: bonesFromParents(FALLBACK_PARENTS),
  headIndex: 3,
};

function bonesFromParents(parents) {
  const bones = [];
  parents.forEach((p, child) => {
    if (p >= 0) bones.push([p, child]);
  });
  return bones;
}

function applySkeleton(msg) {
  const joints = Array.isArray(msg.joints) ? msg.joints : null;
  const n = joints ? joints.length : Array.isArray(msg.parents) ? msg.parents.length : 0;
  if (!(n > 0)) {
    reportError('skeleton message without joints');
    return;
  }
  let bones = null;
  if (Array.isArray(msg.bones)) {
    bones = msg.bones.filter(
      (b) => Array.isArray(b) && b.length === 2 && b.every((i) => Number.isInteger(i) && i >= 0 && i < n),
    );
    if (bones.length !== msg.bones.length) reportError('skeleton message: some bones are invalid');
  } else if (Array.isArray(msg.parents)) {
    bones = bonesFromParents(msg.parents);
  } else {
    reportError('skeleton message without bones or parents');
    bones = [];
  }
  const changed =
    n !== skeleton.jointCount ||
    bones.length !== skeleton.bones.length ||
    bones.some((b, i) => b[0] !== skeleton.bones[i][0] || b[1] !== skeleton.bones[i][1]);
  skeleton.name = typeof msg.name === 'string' ? msg.name : null;
  skeleton.jointCount = n;
  skeleton.bones = bones;
  const head = joints ? joints.indexOf('Head') : -1;
  skeleton.headIndex = head >= 0 ? head : -1;
  HOOK.skeletonName = skeleton.name;
  if (changed) resetSkeletonPools();
}

// --- colours -----------------------------------------------------------------------------------

// Bright, well separated colours for a dark background. A person keeps its colour for as long as
// it is tracked (and when it comes back soon after). The first choice is id mod palette size, so
// consecutive ids get neighbouring, contrasting entries; if another person on screen already has
// that colour, the next free one is taken, so people drawn together never share a colour (up to
// 12 of them).
const PERSON_PALETTE = [
  '#ff5252', '#40c4ff', '#ffd740', '#69f0ae', '#e040fb', '#ff9100',
  '#18ffff', '#f48fb1', '#c6ff00', '#b388ff', '#ffab91', '#64ffda',
].map((hex) => new THREE.Color(hex));
const personColorMemory = new Map(); // id -> palette index, most recent last
const PERSON_COLOR_MEMORY = 256;

function pickPersonColorIndex(id, usedIndices) {
  let idx = personColorMemory.get(id);
  if (idx === undefined || usedIndices.has(idx)) {
    const num = Number(id);
    const pref = (Number.isInteger(num) ? Math.abs(num) : hashString(String(id))) % PERSON_PALETTE.length;
    idx = pref;
    for (let k = 0; k < PERSON_PALETTE.length; k++) {
      const cand = (pref + k) % PERSON_PALETTE.length;
      if (!usedIndices.has(cand)) {
        idx = cand;
        break;
      }
    }
  }
  personColorMemory.delete(id);
  personColorMemory.set(id, idx);
  if (personColorMemory.size > PERSON_COLOR_MEMORY) {
    personColorMemory.delete(personColorMemory.keys().next().value);
  }
  return idx;
}

// Softer tones than the person palette, so raw views stand apart from the fused skeletons.
const SENSOR_PALETTE = ['#8c9eff', '#ffcc80', '#80cbc4', '#ce93d8', '#e6ee9c', '#ef9a9a', '#b0bec5', '#bcaaa4'];
const sensorColorCache = new Map();

function sensorColor(id) {
  let c = sensorColorCache.get(id);
  if (!c) {
    const k = sensorColorCache.size;
    c = k < SENSOR_PALETTE.length
      ? new THREE.Color(SENSOR_PALETTE[k])
      : new THREE.Color().setHSL((0.55 + k * 0.618033988749895) % 1, 0.6, 0.7, THREE.SRGBColorSpace);
    sensorColorCache.set(id, c);
  }
  return c;
}

function hashString(s) {
  let h = 2166136261;
  for (let i = 0; i < s.length; i++) {
    h ^= s.charCodeAt(i);
    h = Math.imul(h, 16777619);
  }
  return h >>> 0;
}

const GREY = new THREE.Color(0x6b7178);

// --- renderer and scene ------------------------------------------------------------------------

const container = document.getElementById('viewport');
let renderer = null;
try {
  renderer = new THREE.WebGLRenderer({ antialias: true });
  renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
  renderer.setSize(window.innerWidth, window.innerHeight);
  container.appendChild(renderer.domElement);
  HOOK.webgl = true;
} catch (e) {
  renderer = null;
  reportError(`WebGL unavailable: ${e && e.message ? e.message : e}`);
}

const scene = new THREE.Scene();
scene.background = new THREE.Color(0x111418);

const camera = new THREE.PerspectiveCamera(50, window.innerWidth / Math.max(1, window.innerHeight), 0.05, 200);
camera.position.set(0, 3, 6);

let controls = null;
if (renderer) {
  controls = new OrbitControls(camera, renderer.domElement);
  controls.target.set(0, 1, 0);
  controls.enableDamping = true;
  controls.dampingFactor = 0.12;
  controls.minDistance = 0.5;
  controls.maxDistance = 40;
  controls.maxPolarAngle = Math.PI * 0.5 + 0.25; // a little below the floor, not upside down
  controls.update();
} else {
  camera.lookAt(0, 1, 0);
}

scene.add(new THREE.HemisphereLight(0xffffff, 0x404858, 2.2));
const sun = new THREE.DirectionalLight(0xffffff, 1.6);
sun.position.set(3, 6, 4);
scene.add(sun);

const grid = new THREE.GridHelper(10, 10, 0x5a6470, 0x2c333c); // 10 × 10 m, 1 m cells
scene.add(grid);
const axes = new THREE.AxesHelper(0.6);
axes.position.y = 0.002; // above the grid lines: no z-fighting
scene.add(axes);

window.addEventListener('resize', () => {
  const w = window.innerWidth;
  const h = Math.max(1, window.innerHeight);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  if (renderer) renderer.setSize(w, h);
});

// --- shared resources --------------------------------------------------------------------------

const JOINT_RADIUS = 0.03;
const jointGeometry = new THREE.SphereGeometry(JOINT_RADIUS, 14, 10);
const jointMaterial = new THREE.MeshLambertMaterial({ color: 0xffffff }); // tinted per instance
const placeholderLineMaterial = new THREE.LineBasicMaterial({ color: 0xffffff });

const scratchMatrix = new THREE.Matrix4();
const scratchColor = new THREE.Color();

function finite3(p) {
  return (
    Array.isArray(p) &&
    p.length === 3 &&
    Number.isFinite(p[0]) &&
    Number.isFinite(p[1]) &&
    Number.isFinite(p[2])
  );
}

// Labels keep a constant size on screen (sizeAttenuation off): `height` is a fraction of the
// view height at unit distance, 0.03 ≈ 3 % of the canvas height.
function makeLabelSprite(text, height = 0.03) {
  const canvas = document.createElement('canvas');
  canvas.width = 256;
  canvas.height = 64;
  const texture = new THREE.CanvasTexture(canvas);
  texture.colorSpace = THREE.SRGBColorSpace;
  const material = new THREE.SpriteMaterial({
    map: texture,
    depthTest: false,
    depthWrite: false,
    transparent: true,
    sizeAttenuation: false,
  });
  const sprite = new THREE.Sprite(material);
  sprite.scale.set(height * 4, height, 1);
  sprite.renderOrder = 10;
  sprite.userData.canvas = canvas;
  drawLabel(sprite, text);
  return sprite;
}

function drawLabel(sprite, text) {
  const canvas = sprite.userData.canvas;
  const ctx = canvas.getContext('2d');
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  ctx.font = '600 34px system-ui, sans-serif';
  ctx.textAlign = 'center';
  ctx.textBaseline = 'middle';
  ctx.lineJoin = 'round';
  ctx.lineWidth = 7;
  ctx.strokeStyle = 'rgba(0, 0, 0, 0.85)';
  ctx.strokeText(text, canvas.width / 2, canvas.height / 2, canvas.width - 8);
  ctx.fillStyle = '#ffffff';
  ctx.fillText(text, canvas.width / 2, canvas.height / 2, canvas.width - 8);
  sprite.material.map.needsUpdate = true;
}

// --- fused persons -----------------------------------------------------------------------------

class PersonSlot {
  constructor(jointCount, boneCount) {
    this.group = new THREE.Group();
    this.jointCount = jointCount;

    this.joints = new THREE.InstancedMesh(jointGeometry, jointMaterial, jointCount);
    this.joints.instanceMatrix.setUsage(THREE.DynamicDrawUsage);
    this.joints.setColorAt(0, scratchColor.setRGB(1, 1, 1)); // allocates instanceColor once
    this.joints.instanceColor.setUsage(THREE.DynamicDrawUsage);
    this.joints.frustumCulled = false; // bounds change every frame; a few spheres cost nothing
    this.joints.count = 0;

    this.bonePositions = new Float32Array(Math.max(1, boneCount) * 6);
    const geometry = new THREE.BufferGeometry();
    this.boneAttr = new THREE.BufferAttribute(this.bonePositions, 3).setUsage(THREE.DynamicDrawUsage);
    geometry.setAttribute('position', this.boneAttr);
    geometry.setDrawRange(0, 0);
    this.boneMaterial = new THREE.LineBasicMaterial({ color: 0xffffff });
    this.bones = new THREE.LineSegments(geometry, this.boneMaterial);
    this.bones.frustumCulled = false;

    this.label = makeLabelSprite('', 0.026);
    this.label.visible = false;

    this.points = new Float32Array(jointCount * 3);
    this.valid = new Uint8Array(jointCount);
    this.id = null;
    this.group.add(this.joints, this.bones, this.label);
  }

  assign(id, colorIndex) {
    this.id = id;
    this.colorIndex = colorIndex;
    const c = PERSON_PALETTE[colorIndex];
    this.color = c;
    this.boneMaterial.color.copy(c);
    this.label.material.color.copy(c);
    drawLabel(this.label, `#${id}`);
    this.group.visible = true;
  }

  /** Returns [jointsDrawn, bonesDrawn]. */
  update(person, bones, headIndex) {
    const joints = person.joints;
    const conf = Array.isArray(person.confidence) ? person.confidence : null;
    const n = this.jointCount;
    let drawn = 0;
    let topY = -Infinity;
    let topX = 0;
    let topZ = 0;
    for (let i = 0; i < n; i++) {
      const p = joints[i];
      if (!finite3(p)) {
        this.valid[i] = 0;
        continue;
      }
      this.valid[i] = 1;
      const x = p[0];
      const y = p[1];
      const z = p[2];
      this.points[i * 3] = x;
      this.points[i * 3 + 1] = y;
      this.points[i * 3 + 2] = z;
      scratchMatrix.makeTranslation(x, y, z);
      this.joints.setMatrixAt(drawn, scratchMatrix);
      let k = 1;
      if (conf && Number.isFinite(conf[i])) k = 0.3 + 0.7 * Math.min(1, Math.max(0, conf[i]));
      scratchColor.copy(this.color).multiplyScalar(k);
      this.joints.setColorAt(drawn, scratchColor);
      drawn++;
      if (i === headIndex || (headIndex < 0 && y > topY)) {
        topY = y;
        topX = x;
        topZ = z;
      }
    }
    this.joints.count = drawn;
    this.joints.instanceMatrix.needsUpdate = true;
    this.joints.instanceColor.needsUpdate = true;

    let nb = 0;
    const pos = this.bonePositions;
    for (let b = 0; b < bones.length; b++) {
      const a = bones[b][0];
      const c = bones[b][1];
      if (!this.valid[a] || !this.valid[c]) continue;
      const o = nb * 6;
      pos[o] = this.points[a * 3];
      pos[o + 1] = this.points[a * 3 + 1];
      pos[o + 2] = this.points[a * 3 + 2];
      pos[o + 3] = this.points[c * 3];
      pos[o + 4] = this.points[c * 3 + 1];
      pos[o + 5] = this.points[c * 3 + 2];
      nb++;
    }
    this.bones.geometry.setDrawRange(0, nb * 2);
    this.boneAttr.needsUpdate = true;

    if (drawn > 0 && Number.isFinite(topY)) {
      this.label.visible = true;
      this.label.position.set(topX, topY + 0.16, topZ);
    } else {
      this.label.visible = false;
    }
    return [drawn, nb];
  }

  release() {
    this.id = null;
    this.group.visible = false;
  }

  dispose() {
    this.group.removeFromParent();
    this.joints.dispose();
    this.bones.geometry.dispose();
    this.boneMaterial.dispose();
    this.label.material.map.dispose();
    this.label.material.dispose();
  }
}

const personsRoot = new THREE.Group();
scene.add(personsRoot);
const activePersons = new Map(); // id -> PersonSlot
const freePersons = [];

// --- raw per-sensor views ----------------------------------------------------------------------

class RawSlot {
  constructor(jointCount, boneCount) {
    this.positions = new Float32Array(Math.max(1, boneCount) * 6);
    const geometry = new THREE.BufferGeometry();
    this.attr = new THREE.BufferAttribute(this.positions, 3).setUsage(THREE.DynamicDrawUsage);
    geometry.setAttribute('position', this.attr);
    geometry.setDrawRange(0, 0);
    this.lines = new THREE.LineSegments(geometry, placeholderLineMaterial); // material set per use
    this.lines.frustumCulled = false;
    this.lines.renderOrder = 1;
    this.valid = new Uint8Array(jointCount);
    this.jointCount = jointCount;
  }

  update(body, bones, material) {
    this.lines.material = material;
    const joints = body.joints;
    const states = Array.isArray(body.states) ? body.states : null;
    for (let i = 0; i < this.jointCount; i++) {
      this.valid[i] = finite3(joints[i]) && !(states && states[i] === 0) ? 1 : 0;
    }
    let nb = 0;
    const pos = this.positions;
    for (let b = 0; b < bones.length; b++) {
      const a = bones[b][0];
      const c = bones[b][1];
      if (!this.valid[a] || !this.valid[c]) continue;
      const pa = joints[a];
      const pc = joints[c];
      const o = nb * 6;
      pos[o] = pa[0];
      pos[o + 1] = pa[1];
      pos[o + 2] = pa[2];
      pos[o + 3] = pc[0];
      pos[o + 4] = pc[1];
      pos[o + 5] = pc[2];
      nb++;
    }
    this.lines.geometry.setDrawRange(0, nb * 2);
    this.attr.needsUpdate = true;
    this.lines.visible = true;
    return nb;
  }

  dispose() {
    this.lines.removeFromParent();
    this.lines.geometry.dispose();
  }
}

const rawRoot = new THREE.Group();
scene.add(rawRoot);
const rawSlots = []; // pool, first rawInUse are drawn
let rawInUse = 0;

function resetSkeletonPools() {
  for (const slot of activePersons.values()) slot.dispose();
  for (const slot of freePersons) slot.dispose();
  activePersons.clear();
  freePersons.length = 0;
  for (const slot of rawSlots) slot.dispose();
  rawSlots.length = 0;
  rawInUse = 0;
  pendingFrame = lastFrame; // redraw with the new definition
}

// --- sensors -----------------------------------------------------------------------------------

const FRUSTUM_DEPTH = 0.3;
const frustumGeometry = (() => {
  const d = FRUSTUM_DEPTH;
  const hx = d * Math.tan(THREE.MathUtils.degToRad(70 / 2));
  const hy = d * Math.tan(THREE.MathUtils.degToRad(60 / 2));
  const o = [0, 0, 0];
  const c = [
    [hx, hy, d],
    [-hx, hy, d],
    [-hx, -hy, d],
    [hx, -hy, d],
  ];
  const up = [
    [-0.06, hy + 0.015, d],
    [0, hy + 0.075, d],
    [0.06, hy + 0.015, d],
  ];
  const segs = [
    [o, c[0]], [o, c[1]], [o, c[2]], [o, c[3]],
    [c[0], c[1]], [c[1], c[2]], [c[2], c[3]], [c[3], c[0]],
    [up[0], up[1]], [up[1], up[2]], [up[2], up[0]], // "up" marker on the far top edge
  ];
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.Float32BufferAttribute(segs.flat(2), 3));
  return g;
})();
const sensorBodyGeometry = new THREE.BoxGeometry(0.25, 0.066, 0.066); // Kinect-ish bar at the origin

class SensorView {
  constructor(id) {
    this.id = id;
    this.color = sensorColor(id);
    this.group = new THREE.Group();
    this.group.matrixAutoUpdate = false;
    this.lineMaterial = new THREE.LineBasicMaterial({ color: this.color });
    this.bodyMaterial = new THREE.MeshLambertMaterial({ color: this.color });
    this.frustum = new THREE.LineSegments(frustumGeometry, this.lineMaterial);
    this.body = new THREE.Mesh(sensorBodyGeometry, this.bodyMaterial);
    this.group.add(this.frustum, this.body);
    this.label = makeLabelSprite(id, 0.03);
    this.label.material.color.copy(this.color);
    this.matrix = new THREE.Matrix4();
    this.connected = null;
    this.group.visible = false;
    this.label.visible = false;
    scene.add(this.group, this.label);
  }

  /** Returns true when the frustum is drawn. */
  update(info) {
    const connected = info.connected === true;
    if (connected !== this.connected) {
      this.connected = connected;
      const c = connected ? this.color : GREY;
      this.lineMaterial.color.copy(c);
      this.bodyMaterial.color.copy(c);
      this.label.material.color.copy(c);
    }
    const T = info.calibration && info.calibration.T_world_from_sensor;
    if (!isMatrix4x4(T)) {
      this.hide();
      return false;
    }
    this.matrix.set(
      T[0][0], T[0][1], T[0][2], T[0][3],
      T[1][0], T[1][1], T[1][2], T[1][3],
      T[2][0], T[2][1], T[2][2], T[2][3],
      T[3][0], T[3][1], T[3][2], T[3][3],
    );
    this.group.matrix.copy(this.matrix);
    this.group.matrixWorldNeedsUpdate = true;
    this.group.visible = true;
    this.label.position.set(T[0][3], T[1][3] + 0.16, T[2][3]);
    this.label.visible = true;
    return true;
  }

  hide() {
    this.group.visible = false;
    this.label.visible = false;
  }

  rawMaterial() {
    if (!this._raw) {
      this._raw = new THREE.LineBasicMaterial({
        color: this.color,
        transparent: true,
        opacity: 0.55,
        depthWrite: false,
      });
    }
    return this._raw;
  }
}

function isMatrix4x4(T) {
  return (
    Array.isArray(T) &&
    T.length === 4 &&
    T.every((row) => Array.isArray(row) && row.length === 4 && row.every(Number.isFinite))
  );
}

const sensorViews = new Map(); // id -> SensorView

function sensorView(id) {
  let v = sensorViews.get(id);
  if (!v) {
    v = new SensorView(id);
    sensorViews.set(id, v);
  }
  return v;
}

// Raw bodies from a sensor /api/sensors has not listed yet still get a stable colour.
const rawOnlyMaterials = new Map();

function rawMaterialFor(sensorId) {
  const v = sensorViews.get(sensorId);
  if (v) return v.rawMaterial();
  let m = rawOnlyMaterials.get(sensorId);
  if (!m) {
    m = new THREE.LineBasicMaterial({ color: sensorColor(sensorId), transparent: true, opacity: 0.55, depthWrite: false });
    rawOnlyMaterials.set(sensorId, m);
  }
  return m;
}

function applySensors(list) {
  if (!Array.isArray(list)) {
    reportError('/api/sensors: "sensors" is not a list');
    return;
  }
  const seen = new Set();
  let drawn = 0;
  for (const info of list) {
    if (!info || typeof info.id !== 'string') continue;
    seen.add(info.id);
    if (sensorView(info.id).update(info)) drawn++;
  }
  for (const [id, v] of sensorViews) if (!seen.has(id)) v.hide();
  HOOK.sensorsDrawn = drawn;
  HOOK.sensorsListed = seen.size;
  renderSensorTable(list);
}

// --- frames ------------------------------------------------------------------------------------

let pendingFrame = null; // newest frame not yet applied (older ones are skipped)
let lastFrame = null; // newest frame applied, re-applied when the raw toggle changes
const EMPTY_FRAME = { type: 'frame', persons: [], raw: [] };
let rawEnabled = false;

function applyFrame(frame) {
  const persons = Array.isArray(frame.persons) ? frame.persons : [];
  const bones = skeleton.bones;
  const seen = new Set();
  let joints = 0;
  let bonesDrawn = 0;
  for (const person of persons) {
    if (!person || !Array.isArray(person.joints)) continue;
    const id = person.id;
    if (seen.has(id)) continue; // duplicate id in one frame: draw the first only
    seen.add(id);
    let slot = activePersons.get(id);
    if (!slot) {
      slot = freePersons.pop() || new PersonSlot(skeleton.jointCount, bones.length);
      if (!slot.group.parent) personsRoot.add(slot.group);
      const used = new Set();
      for (const other of activePersons.values()) used.add(other.colorIndex);
      slot.assign(id, pickPersonColorIndex(id, used));
      activePersons.set(id, slot);
    }
    const [j, b] = slot.update(person, bones, skeleton.headIndex);
    joints += j;
    bonesDrawn += b;
  }
  for (const [id, slot] of activePersons) {
    if (!seen.has(id)) {
      slot.release();
      activePersons.delete(id);
      freePersons.push(slot);
    }
  }
  HOOK.personsDrawn = activePersons.size;
  HOOK.jointsDrawn = joints;
  HOOK.bonesDrawn = bonesDrawn;

  let used = 0;
  if (rawEnabled && Array.isArray(frame.raw)) {
    for (const body of frame.raw) {
      if (!body || !Array.isArray(body.joints)) continue;
      let slot = rawSlots[used];
      if (!slot) {
        slot = new RawSlot(skeleton.jointCount, bones.length);
        rawSlots.push(slot);
        rawRoot.add(slot.lines);
      }
      slot.update(body, bones, rawMaterialFor(String(body.sensor)));
      used++;
    }
  }
  for (let i = used; i < rawInUse; i++) rawSlots[i].lines.visible = false;
  rawInUse = used;
  HOOK.rawViewsDrawn = used;

  updatePersonChips();
}

// --- WebSocket ---------------------------------------------------------------------------------

const BACKOFF_MIN_MS = 250;
const BACKOFF_MAX_MS = 3000;
let backoffMs = BACKOFF_MIN_MS;
let socket = null;
const frameTimes = []; // receive instants over the last second, for frames/s

function socketUrl() {
  const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
  return `${proto}//${location.host}/ws/skeletons?raw=1`;
}

function connect() {
  setConnState('connecting');
  let ws;
  try {
    ws = new WebSocket(socketUrl());
  } catch (e) {
    reportError(`WebSocket: ${e && e.message ? e.message : e}`);
    scheduleReconnect();
    return;
  }
  socket = ws;
  ws.onopen = () => {
    HOOK.connected = true;
    setConnState('open');
  };
  ws.onmessage = (ev) => {
    backoffMs = BACKOFF_MIN_MS; // the server talks: the next drop retries quickly
    handleMessage(ev.data);
  };
  ws.onclose = () => {
    if (socket !== ws) return;
    socket = null;
    HOOK.connected = false;
    pendingFrame = EMPTY_FRAME; // no stale skeletons while disconnected
    lastFrame = EMPTY_FRAME;
    scheduleReconnect();
  };
  ws.onerror = () => {}; // a close event follows
}

function scheduleReconnect() {
  const delay = backoffMs;
  backoffMs = Math.min(backoffMs * 2, BACKOFF_MAX_MS);
  setConnState('closed', delay);
  setTimeout(connect, delay);
}

function handleMessage(data) {
  if (typeof data !== 'string') return; // binary: not part of protocol v1
  let msg;
  try {
    msg = JSON.parse(data);
  } catch (e) {
    reportError(`bad JSON from /ws/skeletons: ${e.message}`);
    return;
  }
  if (!msg || typeof msg !== 'object') return;
  if (msg.type === 'skeleton') {
    applySkeleton(msg);
  } else if (msg.type === 'frame') {
    HOOK.framesReceived++;
    if (Number.isInteger(msg.seq)) HOOK.lastSeq = msg.seq;
    frameTimes.push(performance.now());
    pendingFrame = msg;
    lastFrame = msg;
  }
  // other types (e.g. "calibration") are ignored for now
}

// --- /api/sensors ------------------------------------------------------------------------------

async function pollSensors() {
  const ctrl = new AbortController();
  const timer = setTimeout(() => ctrl.abort(), 2500);
  try {
    const r = await fetch('/api/sensors', { cache: 'no-store', signal: ctrl.signal });
    if (!r.ok) throw new Error(`HTTP ${r.status}`);
    const body = await r.json();
    applySensors(body && body.sensors);
    setApiNote('');
  } catch (e) {
    // Transient while the server restarts: shown in the HUD, not counted as an error.
    setApiNote(`/api/sensors: ${e && e.name === 'AbortError' ? 'timeout' : e && e.message ? e.message : e}`);
  } finally {
    clearTimeout(timer);
    setTimeout(pollSensors, 1000);
  }
}

// --- HUD ---------------------------------------------------------------------------------------

const hudConn = document.getElementById('hud-conn');
const hudFps = document.getElementById('hud-fps');
const hudSeq = document.getElementById('hud-seq');
const hudPersons = document.getElementById('hud-persons');
const hudChips = document.getElementById('hud-person-chips');
const hudSensorRows = document.getElementById('hud-sensor-rows');
const hudApi = document.getElementById('hud-api');
const rawToggle = document.getElementById('raw-toggle');

function setConnState(state, retryMs) {
  hudConn.className = `state state-${state}`;
  if (state === 'open') hudConn.textContent = 'connected';
  else if (state === 'connecting') hudConn.textContent = 'connecting…';
  else hudConn.textContent = `disconnected, retry in ${(retryMs / 1000).toFixed(1)} s`;
}

function setApiNote(text) {
  if (hudApi.textContent !== text) hudApi.textContent = text;
}

let chipsKey = '';

function updatePersonChips() {
  const slots = [...activePersons.values()];
  const key = slots.map((slot) => `${slot.id}:${slot.colorIndex}`).join(',');
  if (key === chipsKey) return;
  chipsKey = key;
  hudPersons.textContent = String(slots.length);
  hudChips.replaceChildren(
    ...slots.map((slot) => {
      const chip = document.createElement('span');
      chip.className = 'chip';
      chip.style.background = `#${slot.color.getHexString()}`;
      chip.textContent = `#${slot.id}`;
      return chip;
    }),
  );
}

function cell(text, className) {
  const td = document.createElement('td');
  td.textContent = text;
  if (className) td.className = className;
  return td;
}

function renderSensorTable(list) {
  const rows = [];
  for (const s of list) {
    if (!s || typeof s.id !== 'string') continue;
    const tr = document.createElement('tr');
    if (!s.connected) tr.className = 'disconnected';
    const sw = document.createElement('span');
    sw.className = 'swatch';
    sw.style.background = `#${(s.connected ? sensorColor(s.id) : GREY).getHexString()}`;
    const tdSw = document.createElement('td');
    tdSw.appendChild(sw);
    const cal = s.calibration && typeof s.calibration.state === 'string' ? s.calibration.state : '–';
    tr.append(
      tdSw,
      cell(s.id),
      cell(s.connected ? 'yes' : 'no', s.connected ? 'ok' : 'bad'),
      cell(Number.isFinite(s.fps) ? s.fps.toFixed(1) : '–', 'num'),
      cell(Number.isFinite(s.bodies) ? String(s.bodies) : '–', 'num'),
      cell(cal),
    );
    rows.push(tr);
  }
  if (rows.length === 0) {
    const tr = document.createElement('tr');
    tr.className = 'empty';
    const td = cell('no sensors');
    td.colSpan = 6;
    tr.appendChild(td);
    rows.push(tr);
  }
  hudSensorRows.replaceChildren(...rows);
}

function updateRate() {
  const now = performance.now();
  while (frameTimes.length && now - frameTimes[0] > 1000) frameTimes.shift();
  HOOK.fps = frameTimes.length;
  hudFps.textContent = frameTimes.length.toFixed(1);
  hudSeq.textContent = HOOK.lastSeq >= 0 ? String(HOOK.lastSeq) : '–';
}
setInterval(updateRate, 500);

rawToggle.checked = false;
rawToggle.addEventListener('change', () => {
  rawEnabled = rawToggle.checked;
  HOOK.rawEnabled = rawEnabled;
  if (lastFrame) pendingFrame = lastFrame; // redraw (or hide) raw views right away
});

// --- main loop ---------------------------------------------------------------------------------

function renderOnce() {
  if (pendingFrame) {
    const f = pendingFrame;
    pendingFrame = null;
    try {
      const t0 = performance.now();
      applyFrame(f);
      HOOK.applyMs = performance.now() - t0;
    } catch (e) {
      reportError(`frame: ${e && e.message ? e.message : e}`);
    }
  }
  if (controls) controls.update();
  if (renderer) {
    const t0 = performance.now();
    renderer.render(scene, camera);
    HOOK.renderMs = performance.now() - t0;
    HOOK.renders++;
    HOOK.gpuGeometries = renderer.info.memory.geometries;
    HOOK.gpuTextures = renderer.info.memory.textures;
  } else {
    HOOK.personsDrawn = HOOK.jointsDrawn = HOOK.bonesDrawn = HOOK.rawViewsDrawn = HOOK.sensorsDrawn = 0;
  }
}

function animate() {
  requestAnimationFrame(animate);
  renderOnce();
}

if (renderer) {
  animate();
} else {
  // No WebGL: still apply frames so the HUD and the counters stay live.
  setInterval(renderOnce, 100);
}
connect();
pollSensors();

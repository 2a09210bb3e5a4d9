// skelfuse live viewer: fused skeletons, raw per-sensor views and sensor poses in three.js.
//
// Data: WebSocket /ws/skeletons?raw=1 (skeleton definition, then frames) through the ES module
// client (skelfuse-client.js: token, reconnects, refusals), GET /api/sensors polled once a second,
// and the calibration REST API (/api/calibration: the active version every 2 s;
// /api/calibration/runs: the newest run, every 0.5 s while one is running). Depth clouds
// (viewer-clouds.js) and recordings (viewer-recording.js) have their own modules. World frame =
// three.js frame (right-handed, +Y up, metres, floor y = 0).
//
// Test hook: window.skelfuseViewer (see HOOK below), refreshed after every render.

import * as THREE from 'three';
import { OrbitControls } from './vendor/OrbitControls.js';
import { ApiClient, FeedClient, pageToken, storeToken } from './skelfuse-client.js';
import { CloudLayer } from './viewer-clouds.js';
import { initRecording } from './viewer-recording.js';

// --- test hook ---------------------------------------------------------------------------------

const HOOK = {
  connected: false, // WebSocket open
  feedState: 'stopped', // the feed client's state: connecting | open | closed | refused
  tokenPrompt: false, // the token field is shown (the feed refused the page)
  feedRefusals: 0, // times the feed refused the page (token missing or wrong)
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
  sensorsMoved: [], // ids the last /api/sensors answer flags "moved?" (drift detection)
  learnedErrorCells: 0, // sensor rows whose learned-error cell shows numbers (learned_error set)
  learnedErrorWorst: {}, // group (legs, arms, trunk) -> the sensor highlighted as worst in it
  // calibration panel
  calibrationVersion: null, // active calibration version (GET /api/calibration), null: none yet
  calibrationRunId: null, // the run the panel shows (the newest one), or null
  calibrationRunState: null, // its state: capturing | solving | done | failed, or null
  calibrationRunProgress: 0, // its progress, 0..1
  calibrationRunCommitted: null, // its committed_version, or null
  calibrationError: null, // the last error shown in the panel (a 4xx detail), or null
  ghostSensorsDrawn: 0, // dashed frustums of a done, uncommitted run's proposed poses
  provisionalSensorsDrawn: 0, // dashed frustums of a running run's provisional poses (clouds on)
  calibrationStage: null, // the run's current stage (its name), or null
  calibrationStages: [], // the run's stages, in order
  calibrationStageIndex: 0, // index of the current stage in calibrationStages
  calibrationEtaS: null, // seconds left as the server estimates them, or null (not known)
  labelsClipped: [], // 3D labels (sensor ids, "#id") drawn partly outside the canvas
  // joint colouring
  confidenceColouring: false, // state of the "colour by confidence" checkbox
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
  jointNames: null,
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
  skeleton.jointNames = joints ? joints.map(String) : null;
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
const MOVED_COLOR = new THREE.Color(0xf0735a); // a sensor drift detection flags "moved?" (as .bad)

// Confidence scale, evenly spaced stops for 0, 1/3, 2/3, 1, interpolated in sRGB. The fused
// confidence is 1 − Π(1 − w_k) over the views' weights (docs/fusion.md §7-8): how much evidence
// backs a joint, not an error. One view side-on or an inferred joint gives about 0.3 (the median
// in the demo), one tracked frontal view about 0.7, two good views 0.9 and more. So the scale has
// no red (which reads as "wrong"): violet, little evidence → blue → teal → yellow-green, several
// good views; the legend (#confidence-legend) says what the values mean. Joints without a
// confidence value are drawn white.
const CONFIDENCE_RAMP = ['#8a6cff', '#3d8bff', '#1fd1c1', '#d4f55a'];
const confidenceRampSrgb = CONFIDENCE_RAMP.map((hex) => {
  const v = parseInt(hex.slice(1), 16);
  return [(v >> 16) & 255, (v >> 8) & 255, v & 255].map((x) => x / 255);
});

function confidenceColor(value, target) {
  if (!Number.isFinite(value)) return target.setRGB(1, 1, 1);
  const t = Math.min(1, Math.max(0, value)) * (confidenceRampSrgb.length - 1);
  const k = Math.min(Math.floor(t), confidenceRampSrgb.length - 2);
  const f = t - k;
  const a = confidenceRampSrgb[k];
  const b = confidenceRampSrgb[k + 1];
  return target.setRGB(
    a[0] + (b[0] - a[0]) * f,
    a[1] + (b[1] - a[1]) * f,
    a[2] + (b[2] - a[2]) * f,
    THREE.SRGBColorSpace,
  );
}

function confidenceCss(value) {
  return `#${confidenceColor(value, new THREE.Color()).getHexString()}`;
}

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

// The HUD covers the left of the canvas: the projection's centre moves right by the HUD's width
// (a wider virtual image of which the canvas shows the left part), so the scene is centred in
// the free part and the view fit (frameSensors) keeps sensors and labels out from under the HUD.
let hudShiftPx = 0;

function applyViewSize() {
  const w = window.innerWidth;
  const h = Math.max(1, window.innerHeight);
  const hud = document.getElementById('hud');
  const right = hud ? hud.getBoundingClientRect().right : 0;
  hudShiftPx = w - right >= 400 ? right : 0; // a narrow window: the HUD floats over the scene
  camera.aspect = (w + hudShiftPx) / h;
  if (hudShiftPx > 0) camera.setViewOffset(w + hudShiftPx, h, 0, 0, w, h);
  else camera.clearViewOffset();
  camera.updateProjectionMatrix();
  if (renderer) renderer.setSize(w, h);
  requestRender();
}

window.addEventListener('resize', applyViewSize);

// --- shared resources --------------------------------------------------------------------------

const JOINT_RADIUS = 0.03;
const jointGeometry = new THREE.SphereGeometry(JOINT_RADIUS, 14, 10);
const jointMaterial = new THREE.MeshLambertMaterial({ color: 0xffffff }); // tinted per instance
const placeholderLineMaterial = new THREE.LineBasicMaterial({ color: 0xffffff });
const confidenceBoneMaterial = new THREE.LineBasicMaterial({ vertexColors: true }); // per-vertex ramp

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
function makeCanvasSprite(width, canvasHeight, height) {
  const canvas = document.createElement('canvas');
  canvas.width = width;
  canvas.height = canvasHeight;
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
  sprite.scale.set(height * (width / canvasHeight), height, 1);
  sprite.renderOrder = 10;
  sprite.userData.canvas = canvas;
  return sprite;
}

function makeLabelSprite(text, height = 0.03) {
  const sprite = makeCanvasSprite(256, 64, height);
  drawLabel(sprite, text);
  return sprite;
}

// A sensor's label: its id, and under it a smaller second line (the residual), when given.
function makeSensorLabelSprite(id) {
  const sprite = makeCanvasSprite(256, 112, 0.03 * (112 / 64)); // first line as tall as others
  sprite.center.set(0.5, 0.05); // drawn above the anchor, clear of the frustum
  sprite.userData.text = null;
  drawSensorLabel(sprite, id, '');
  return sprite;
}

function drawSensorLabel(sprite, title, sub) {
  const key = `${title}\n${sub}`;
  if (sprite.userData.text === key) return;
  sprite.userData.text = key;
  const canvas = sprite.userData.canvas;
  const ctx = canvas.getContext('2d');
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  ctx.textAlign = 'center';
  ctx.textBaseline = 'middle';
  ctx.lineJoin = 'round';
  ctx.strokeStyle = 'rgba(0, 0, 0, 0.85)';
  ctx.fillStyle = '#ffffff';
  ctx.font = '600 34px system-ui, sans-serif';
  ctx.lineWidth = 7;
  ctx.strokeText(title, canvas.width / 2, 32, canvas.width - 8);
  ctx.fillText(title, canvas.width / 2, 32, canvas.width - 8);
  let textWidth = ctx.measureText(title).width;
  if (sub) {
    ctx.font = '500 26px system-ui, sans-serif';
    ctx.lineWidth = 6;
    ctx.strokeText(sub, canvas.width / 2, 82, canvas.width - 8);
    ctx.fillText(sub, canvas.width / 2, 82, canvas.width - 8);
    textWidth = Math.max(textWidth, ctx.measureText(sub).width);
  }
  sprite.userData.textFrac = Math.min(1, (textWidth + 14) / canvas.width); // for labelsClipped
  sprite.material.map.needsUpdate = true;
  requestRender();
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
  sprite.userData.textFrac = Math.min(1, (ctx.measureText(text).width + 14) / canvas.width);
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
    this.boneColors = new Float32Array(Math.max(1, boneCount) * 6);
    this.boneColorAttr = new THREE.BufferAttribute(this.boneColors, 3).setUsage(THREE.DynamicDrawUsage);
    geometry.setAttribute('color', this.boneColorAttr);
    this.boneMaterial = new THREE.LineBasicMaterial({ color: 0xffffff });
    this.bones = new THREE.LineSegments(geometry, this.boneMaterial);
    this.bones.frustumCulled = false;

    this.label = makeLabelSprite('', 0.026);
    this.label.visible = false;

    this.points = new Float32Array(jointCount * 3);
    this.valid = new Uint8Array(jointCount);
    this.conf = new Float32Array(jointCount); // per joint, NaN: unknown
    this.instanceJoint = new Int16Array(jointCount); // instance index -> joint index (hover)
    this.person = null; // the last person message drawn (hover tooltip)
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
  update(person, bones, headIndex, byConfidence) {
    const joints = person.joints;
    const conf = Array.isArray(person.confidence) ? person.confidence : null;
    const n = this.jointCount;
    this.person = person;
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
      const ci = conf && Number.isFinite(conf[i]) ? Math.min(1, Math.max(0, conf[i])) : NaN;
      this.conf[i] = ci;
      if (byConfidence) {
        confidenceColor(ci, scratchColor);
      } else {
        scratchColor.copy(this.color).multiplyScalar(Number.isNaN(ci) ? 1 : 0.3 + 0.7 * ci);
      }
      this.joints.setColorAt(drawn, scratchColor);
      this.instanceJoint[drawn] = i;
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
    const col = this.boneColors;
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
      if (byConfidence) {
        // A bone is as trustworthy as its weaker end (NaN, unknown, counts as neither).
        const ca = this.conf[a];
        const cc = this.conf[c];
        confidenceColor(Number.isNaN(ca) ? cc : Number.isNaN(cc) ? ca : Math.min(ca, cc), scratchColor);
        col[o] = col[o + 3] = scratchColor.r;
        col[o + 1] = col[o + 4] = scratchColor.g;
        col[o + 2] = col[o + 5] = scratchColor.b;
      }
      nb++;
    }
    this.bones.geometry.setDrawRange(0, nb * 2);
    this.boneAttr.needsUpdate = true;
    if (byConfidence) this.boneColorAttr.needsUpdate = true;
    const boneMaterial = byConfidence ? confidenceBoneMaterial : this.boneMaterial;
    if (this.bones.material !== boneMaterial) this.bones.material = boneMaterial;

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
    this.person = null;
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
    this.moved = false; // drift detection flags it "moved?" (fusion/drift.py)
    this.group = new THREE.Group();
    this.group.matrixAutoUpdate = false;
    this.lineMaterial = new THREE.LineBasicMaterial({ color: this.color });
    this.bodyMaterial = new THREE.MeshLambertMaterial({ color: this.color });
    this.frustum = new THREE.LineSegments(frustumGeometry, this.lineMaterial);
    this.body = new THREE.Mesh(sensorBodyGeometry, this.bodyMaterial);
    this.group.add(this.frustum, this.body);
    this.label = makeSensorLabelSprite(id);
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
    this.label.position.set(T[0][3], T[1][3] + 0.1, T[2][3]);
    this.label.visible = true;
    this.moved = isMoved(info);
    this.bodyMaterial.color.copy(this.moved ? MOVED_COLOR : connected ? this.color : GREY);
    this.updateLabel();
    return true;
  }

  /** The label's second line: "moved?" while drift detection flags the sensor, else the
   * residual of this sensor in the active calibration. */
  updateLabel() {
    const sub = this.moved ? 'moved?' : residualText(calibrationEntry(this.id));
    drawSensorLabel(this.label, this.id, sub);
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

// Proposed poses of a done, uncommitted run: dashed frustums next to the active ones.
const ghostRoot = new THREE.Group();
scene.add(ghostRoot);
const ghostViews = new Map(); // sensor id -> LineSegments
let ghostKey = '';

function ghostView(id) {
  let g = ghostViews.get(id);
  if (!g) {
    const material = new THREE.LineDashedMaterial({
      color: sensorColor(id),
      dashSize: 0.035,
      gapSize: 0.025,
      transparent: true,
      opacity: 0.85,
      depthWrite: false,
    });
    g = new THREE.LineSegments(ghostFrustumGeometry(), material);
    g.matrixAutoUpdate = false;
    g.renderOrder = 2;
    ghostRoot.add(g);
    ghostViews.set(id, g);
  }
  return g;
}

let ghostGeometry = null;

function ghostFrustumGeometry() {
  if (!ghostGeometry) {
    const tmp = new THREE.LineSegments(frustumGeometry.clone());
    tmp.computeLineDistances(); // per-segment distances, for the dashes
    ghostGeometry = tmp.geometry;
  }
  return ghostGeometry;
}

/** Shows the run's proposed poses while it is done and not committed; hides them otherwise. */
function updateGhosts(run) {
  const proposed =
    run && run.state === 'done' && run.committed_version == null && run.results && typeof run.results === 'object'
      ? run.results
      : null;
  const key = proposed ? `${run.id}` : '';
  if (key === ghostKey) return;
  ghostKey = key;
  let drawn = 0;
  const seen = new Set();
  if (proposed) {
    for (const [id, result] of Object.entries(proposed)) {
      const T = result && result.T_world_from_sensor;
      if (!isMatrix4x4(T)) continue;
      const g = ghostView(id);
      g.matrix.set(...T.flat());
      g.matrixWorldNeedsUpdate = true;
      g.visible = true;
      seen.add(id);
      drawn++;
    }
  }
  for (const [id, g] of ghostViews) if (!seen.has(id)) g.visible = false;
  HOOK.ghostSensorsDrawn = drawn;
  requestRender();
}

// Sensors a running calibration has placed (its provisional poses, known from the depth clouds'
// bodies answers): dashed frustums, so during a first calibration the sensors appear with their
// clouds instead of only once the run is committed.
const provisionalViews = new Map(); // sensor id -> LineSegments

function showProvisionalSensors(poses) {
  let drawn = 0;
  for (const [id, T] of poses) {
    if (!isMatrix4x4(T)) continue;
    let g = provisionalViews.get(id);
    if (!g) {
      g = new THREE.LineSegments(
        ghostFrustumGeometry(),
        new THREE.LineDashedMaterial({ color: sensorColor(id), dashSize: 0.035, gapSize: 0.025 }),
      );
      g.matrixAutoUpdate = false;
      scene.add(g);
      provisionalViews.set(id, g);
    }
    g.matrix.set(...T.flat());
    g.matrixWorldNeedsUpdate = true;
    g.visible = true;
    drawn++;
  }
  for (const [id, g] of provisionalViews) if (!poses.has(id)) g.visible = false;
  HOOK.provisionalSensorsDrawn = drawn;
  requestRender();
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
  HOOK.sensorsMoved = list.filter(isMoved).map((s) => s.id);
  renderSensorTable(list);
  frameSensors();
  requestRender();
}

// --- frames ------------------------------------------------------------------------------------

let pendingFrame = null; // newest frame not yet applied (older ones are skipped)
let lastFrame = null; // newest frame applied, re-applied when the raw toggle changes
const EMPTY_FRAME = { type: 'frame', persons: [], raw: [] };
let rawEnabled = false;
let confidenceEnabled = false;

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
    const [j, b] = slot.update(person, bones, skeleton.headIndex, confidenceEnabled);
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

// --- feed and token ----------------------------------------------------------------------------

const frameTimes = []; // receive instants over the last second, for frames/s

// A server started with --token wants it on the WebSocket and on every change (docs/security.md).
// The viewer takes it from its own address (http://server:8000/?token=...), else from this tab's
// session storage, where the token field (shown when the feed refuses the page) keeps it.
const api = new ApiClient({ token: pageToken() });

const feed = new FeedClient({
  token: api.token,
  raw: true,
  api,
  onSkeleton: applySkeleton,
  onFrame: (msg) => {
    HOOK.framesReceived++;
    if (Number.isInteger(msg.seq)) HOOK.lastSeq = msg.seq;
    frameTimes.push(performance.now());
    pendingFrame = msg;
    lastFrame = msg;
  },
  onState: (state, info) => {
    HOOK.feedState = state;
    HOOK.connected = state === 'open';
    if (state === 'refused') HOOK.feedRefusals++;
    if (state === 'closed' || state === 'refused') {
      pendingFrame = EMPTY_FRAME; // no stale skeletons while disconnected
      lastFrame = EMPTY_FRAME;
    }
    setConnState(state, info);
    showTokenPrompt(state === 'refused' ? info.reason || 'the server refused the feed' : null);
  },
  onError: reportError,
});

const tokenUi = {
  form: document.getElementById('hud-token'),
  message: document.getElementById('token-message'),
  input: document.getElementById('token-input'),
};

function showTokenPrompt(reason) {
  const show = reason !== null;
  HOOK.tokenPrompt = show;
  tokenUi.form.hidden = !show;
  if (!show) return;
  tokenUi.message.textContent =
    `${reason}: the live feed, recordings and changes need the token the server was started with ` +
    `(skelfuse server --token, or SKELFUSE_TOKEN; skelfuse demo prints its viewer address with ` +
    `it). Paste it here; it is kept for this browser tab only.`;
  if (document.activeElement !== tokenUi.input) tokenUi.input.focus();
}

tokenUi.form.addEventListener('submit', (ev) => {
  ev.preventDefault();
  const token = tokenUi.input.value.trim();
  if (!token) return;
  storeToken(token);
  tokenUi.input.value = '';
  feed.setToken(token); // the API client too: it is shared
  recording.poll();
});

// --- /api/sensors ------------------------------------------------------------------------------

// Once a second; calling pollSensors() polls at once (after a commit: the frustums move).
const pollSensors = makePoller(async () => {
  try {
    const r = await api.json('GET', '/api/sensors', undefined, { timeoutMs: 2500 });
    if (!r.ok) throw new Error(`HTTP ${r.status}`);
    const list = r.data && r.data.sensors;
    applySensors(list);
    if (Array.isArray(list)) clouds.setSensors(list.filter((x) => x && x.connected).map((x) => String(x.id)));
    setApiNote('');
  } catch (e) {
    // Transient while the server restarts: shown in the HUD, not counted as an error.
    setApiNote(`/api/sensors: ${e && e.name === 'AbortError' ? 'timeout' : e && e.message ? e.message : e}`);
  }
}, () => 1000);

// --- HUD ---------------------------------------------------------------------------------------

const hudConn = document.getElementById('hud-conn');
const hudFps = document.getElementById('hud-fps');
const hudSeq = document.getElementById('hud-seq');
const hudPersons = document.getElementById('hud-persons');
const hudChips = document.getElementById('hud-person-chips');
const hudSensorRows = document.getElementById('hud-sensor-rows');
const hudApi = document.getElementById('hud-api');
const rawToggle = document.getElementById('raw-toggle');
const confidenceToggle = document.getElementById('confidence-toggle');

function setConnState(state, info) {
  hudConn.className = `state state-${state}`;
  if (state === 'open') hudConn.textContent = 'connected';
  else if (state === 'connecting') hudConn.textContent = 'connecting…';
  else if (state === 'refused') hudConn.textContent = 'refused: token needed';
  else if (state === 'closed') hudConn.textContent = `disconnected, retry in ${(info.retryMs / 1000).toFixed(1)} s`;
  else hudConn.textContent = state;
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

// Drift detection (fusion/drift.py): a sensor whose views disagree with every other sensor's
// since its calibration looks moved (a bump). drift is null while detection is off or unknown.
function isMoved(s) {
  return Boolean(s && s.drift && s.drift.moved === true);
}

// The flag is decided on the change since the pair's baseline (relative_*), not on the raw
// correction under the calibration, which also holds the calibration's own constant error.
function driftText(drift) {
  if (!drift) return '';
  const against = typeof drift.against === 'string' ? ` vs ${drift.against}` : '';
  const changed = Number.isFinite(drift.relative_rotation_deg) && Number.isFinite(drift.relative_shift_mm);
  const deg = changed ? drift.relative_rotation_deg : drift.rotation_deg;
  const mm = changed ? drift.relative_shift_mm : drift.shift_mm;
  const degText = Number.isFinite(deg) ? `${deg.toFixed(1)}°` : '?°';
  const mmText = Number.isFinite(mm) ? `${Math.round(mm)} mm` : '? mm';
  return changed
    ? `moved ${degText} / ${mmText} since calibration${against}`
    : `off by ${degText} / ${mmText}${against} (no baseline yet)`;
}

function renderSensorTable(list) {
  const rows = [];
  const worst = worstLearned(list);
  let learnedCells = 0;
  for (const s of list) {
    if (!s || typeof s.id !== 'string') continue;
    const tr = document.createElement('tr');
    tr.className = 'sensor';
    if (!s.connected) tr.classList.add('disconnected');
    const sw = document.createElement('span');
    sw.className = 'swatch';
    sw.style.background = `#${(s.connected ? sensorColor(s.id) : GREY).getHexString()}`;
    const tdSw = document.createElement('td');
    tdSw.appendChild(sw);
    let cal = s.calibration && typeof s.calibration.state === 'string' ? s.calibration.state : '–';
    const residual = residualText(calibrationEntry(s.id));
    if (residual && cal === 'stored') cal = `${cal} · ${residual}`;
    const tdCal = cell(cal);
    if (isMoved(s)) {
      tr.classList.add('moved');
      const flag = document.createElement('span');
      flag.className = 'moved-flag';
      flag.textContent = 'moved?';
      flag.title = driftText(s.drift);
      const fix = document.createElement('button');
      fix.type = 'button';
      fix.className = 'moved-fix';
      fix.textContent = 're-solve';
      fix.title = `re-solve ${s.id} against the other sensors (method sensor), then commit`;
      fix.addEventListener('click', () => resolveSensor(s.id));
      tdCal.append(' ', flag, ' ', fix);
    }
    tr.append(
      tdSw,
      cell(s.id),
      cell(s.connected ? 'yes' : 'no', s.connected ? 'ok' : 'bad'),
      cell(Number.isFinite(s.fps) ? s.fps.toFixed(1) : '–', 'num'),
      cell(Number.isFinite(s.bodies) ? String(s.bodies) : '–', 'num'),
      tdCal,
    );
    const learned = learnedErrorRow(s, worst);
    if (hasLearnedError(s)) learnedCells++;
    rows.push(tr, learned);
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
  HOOK.learnedErrorCells = learnedCells;
  HOOK.learnedErrorWorst = Object.fromEntries(worst);
}

// Each sensor's error as fusion learned it from the rig (fusion/rig_errors.py): the RMS 3-D
// error of its leg, arm and trunk joints, so whoever sets up the rig sees which sensor to move.
// Until the evidence outweighs the sensor type's prior the figures are the prior's (greyed).
const LEARNED_GROUPS = ['legs', 'arms', 'trunk'];

function hasLearnedError(s) {
  const e = s && s.learned_error;
  return Boolean(e) && LEARNED_GROUPS.every((g) => Number.isFinite(e[`${g}_mm`]));
}

// Per group, the connected sensor with the largest learned (not prior) error, when at least two
// sensors have learned theirs: with one there is nothing to compare.
function worstLearned(list) {
  const learned = list.filter((s) => s && s.connected && hasLearnedError(s) && s.learned_error.learned === true);
  const worst = new Map();
  if (learned.length < 2) return worst;
  for (const g of LEARNED_GROUPS) {
    let top = learned[0];
    for (const s of learned) if (s.learned_error[`${g}_mm`] > top.learned_error[`${g}_mm`]) top = s;
    worst.set(g, top.id);
  }
  return worst;
}

function learnedErrorRow(s, worst) {
  const tr = document.createElement('tr');
  tr.className = 'learned';
  if (!s.connected) tr.classList.add('disconnected');
  const td = document.createElement('td');
  td.colSpan = 5;
  td.className = 'learned-error';
  const label = document.createElement('span');
  label.className = 'learned-label';
  label.textContent = 'error ';
  td.appendChild(label);
  if (!hasLearnedError(s)) {
    tr.classList.add('unseen');
    td.append('– (no person seen yet)');
    td.title = 'fusion learns each sensor\'s error once it sees a person through it';
  } else {
    const e = s.learned_error;
    LEARNED_GROUPS.forEach((g, i) => {
      if (i > 0) td.append(' · ');
      const part = document.createElement('span');
      part.className = 'learned-group';
      part.dataset.group = g;
      part.textContent = `${g} ${Math.round(e[`${g}_mm`])}`;
      if (worst.get(g) === s.id) {
        part.classList.add('worst');
        part.title = `the largest ${g} error of the sensors: move or turn this one first`;
      }
      td.appendChild(part);
    });
    td.append(' mm');
    if (e.learned !== true) {
      tr.classList.add('prior');
      td.append(' (prior)');
    }
    const samples = Number.isFinite(e.samples) ? Math.round(e.samples) : '?';
    td.title =
      `RMS 3-D error of this sensor's joints where it has been seeing them lately, learned by ` +
      `fusion from the other sensors' views (${samples} views per joint)` +
      (e.learned === true ? '' : '; too little evidence yet: the sensor type\'s prior');
  }
  tr.append(document.createElement('td'), td);
  return tr;
}

function updateRate() {
  const now = performance.now();
  while (frameTimes.length && now - frameTimes[0] > 1000) frameTimes.shift();
  HOOK.fps = frameTimes.length;
  hudFps.textContent = frameTimes.length.toFixed(1);
  hudSeq.textContent = HOOK.lastSeq >= 0 ? String(HOOK.lastSeq) : '–';
}
setInterval(updateRate, 500);

confidenceToggle.checked = false;
confidenceToggle.addEventListener('change', () => {
  confidenceEnabled = confidenceToggle.checked;
  HOOK.confidenceColouring = confidenceEnabled;
  if (lastFrame) pendingFrame = lastFrame; // recolour right away
});

rawToggle.checked = false;
rawToggle.addEventListener('change', () => {
  rawEnabled = rawToggle.checked;
  HOOK.rawEnabled = rawEnabled;
  if (lastFrame) pendingFrame = lastFrame; // redraw (or hide) raw views right away
});

// --- calibration panel -------------------------------------------------------------------------
//
// The active calibration (version, note, per-sensor method and residual) is polled every 2 s;
// the newest run every 3 s, and every 0.5 s while it is capturing or solving. "start" posts a
// run with the chosen method, "commit" makes a done run the active calibration (a new version).
// Refusals (4xx) are shown in the panel with the server's `detail`.

const calUi = {
  section: document.getElementById('hud-calibration'),
  summary: document.getElementById('cal-summary'),
  version: document.getElementById('cal-version'),
  note: document.getElementById('cal-note'),
  method: document.getElementById('cal-method'),
  start: document.getElementById('cal-start'),
  commit: document.getElementById('cal-commit'),
  run: document.getElementById('cal-run'),
  runTitle: document.getElementById('cal-run-title'),
  runState: document.getElementById('cal-run-state'),
  bar: document.getElementById('cal-progress-bar'),
  progressText: document.getElementById('cal-progress-text'),
  stage: document.getElementById('cal-stage'),
  stages: document.getElementById('cal-stages'),
  eta: document.getElementById('cal-eta'),
  results: document.getElementById('cal-results'),
  resultRows: document.getElementById('cal-result-rows'),
  floor: document.getElementById('cal-floor'),
  runWarnings: document.getElementById('cal-run-warnings'),
  runError: document.getElementById('cal-run-error'),
  error: document.getElementById('cal-error'),
};

const cal = {
  active: null, // the last GET /api/calibration answer
  run: null, // the newest run
  runGen: 0, // bumped by start/commit: run answers requested before are stale
  busy: false, // a POST is in flight
  expanded: new Set(), // `${runId}/${sensor}` whose warnings are unfolded
  resultsKey: '',
};

function isActiveRun(run) {
  return !!run && (run.state === 'capturing' || run.state === 'solving');
}

function calibrationEntry(id) {
  const sensors = cal.active && cal.active.sensors;
  const entry = sensors && typeof sensors === 'object' ? sensors[id] : null;
  return entry && typeof entry === 'object' ? entry : null;
}

/** "18.2 mm", "reference", the method when the residual is unknown, or "". */
function residualText(entry) {
  if (!entry) return '';
  if (entry.method === 'reference') return 'reference';
  if (Number.isFinite(entry.residual_mm)) return `${entry.residual_mm.toFixed(1)} mm`;
  return typeof entry.method === 'string' ? entry.method : '';
}

/** fetch + JSON: {ok, status, data}; throws on network errors and timeouts. */
function apiJson(method, path, body) {
  return api.json(method, path, body);
}

/** The server's reason for a refusal: FastAPI's `detail` (a string, or validation errors). */
function errorDetail(res) {
  const d = res.data && res.data.detail;
  if (typeof d === 'string') return d;
  if (Array.isArray(d)) {
    return d
      .map((e) => {
        const loc = Array.isArray(e && e.loc) ? e.loc.filter((x) => x !== 'body').join('.') : '';
        return loc ? `${loc}: ${e.msg}` : String(e && e.msg ? e.msg : JSON.stringify(e));
      })
      .join('; ');
  }
  return `HTTP ${res.status}`;
}

function errorText(e) {
  if (e && e.name === 'AbortError') return 'timeout';
  return e && e.message ? e.message : String(e);
}

function showCalError(text) {
  HOOK.calibrationError = text || null;
  calUi.error.hidden = !text;
  calUi.error.textContent = text || '';
  if (text) calUi.section.open = true; // never hidden in a folded panel
}

/** Runs `fn` now and then after `nextDelay()` ms, one at a time; calling the returned function
 * polls at once (or right after the request in flight). */
function makePoller(fn, nextDelay) {
  let timer = null;
  let inFlight = false;
  let again = false;
  async function poll() {
    clearTimeout(timer);
    timer = null;
    if (inFlight) {
      again = true;
      return;
    }
    inFlight = true;
    try {
      await fn();
    } catch (e) {
      // transient (server restarting): the next poll retries; /api/sensors shows the outage
    } finally {
      inFlight = false;
      const delay = again ? 0 : nextDelay();
      again = false;
      timer = setTimeout(poll, delay);
    }
  }
  return poll;
}

const pollActiveCalibration = makePoller(async () => {
  const r = await apiJson('GET', '/api/calibration');
  if (r.ok && r.data && typeof r.data === 'object') applyActiveCalibration(r.data);
}, () => 2000);

const pollRuns = makePoller(async () => {
  const gen = cal.runGen;
  let run = null;
  if (isActiveRun(cal.run)) {
    const r = await apiJson('GET', `/api/calibration/runs/${encodeURIComponent(cal.run.id)}`);
    if (r.ok && r.data && typeof r.data === 'object') run = r.data;
  }
  if (!run) {
    const r = await apiJson('GET', '/api/calibration/runs');
    const runs = r.ok && r.data && Array.isArray(r.data.runs) ? r.data.runs : null;
    if (!runs) return;
    run = runs.length ? runs[runs.length - 1] : null;
  }
  if (gen === cal.runGen) applyRun(run);
}, () => (isActiveRun(cal.run) ? 500 : 3000));

function applyActiveCalibration(data) {
  cal.active = data;
  const version = Number.isInteger(data.version) ? data.version : null;
  HOOK.calibrationVersion = version;
  calUi.version.textContent = version === null ? 'none yet' : `v${version}`;
  const note = typeof data.note === 'string' ? data.note : '';
  calUi.note.textContent = note;
  const created = Number.isFinite(data.created_unix_s)
    ? `committed ${new Date(data.created_unix_s * 1000).toLocaleString()}`
    : '';
  calUi.note.title = [note, created].filter(Boolean).join('\n');
  for (const v of sensorViews.values()) if (v.label.visible) v.updateLabel();
  renderCalSummary();
}

function applyRun(run) {
  cal.run = run && typeof run === 'object' && typeof run.id === 'string' ? run : null;
  const r = cal.run;
  HOOK.calibrationRunId = r ? r.id : null;
  HOOK.calibrationRunState = r && typeof r.state === 'string' ? r.state : null;
  HOOK.calibrationRunProgress = r && Number.isFinite(r.progress) ? r.progress : 0;
  HOOK.calibrationRunCommitted = r && Number.isInteger(r.committed_version) ? r.committed_version : null;
  HOOK.calibrationStage = r && typeof r.stage === 'string' ? r.stage : null;
  HOOK.calibrationStages = r && Array.isArray(r.stages) ? r.stages.map(String) : [];
  HOOK.calibrationStageIndex = r && Number.isInteger(r.stage_index) ? r.stage_index : 0;
  HOOK.calibrationEtaS = r && isActiveRun(r) && Number.isFinite(r.eta_s) ? r.eta_s : null;
  updateGhosts(r);
  renderRun();
  renderCalSummary();
}

function updateCalButtons() {
  const r = cal.run;
  calUi.start.disabled = cal.busy || isActiveRun(r);
  calUi.start.title = isActiveRun(r) ? 'a run is in progress' : 'start a calibration run with this method';
  calUi.commit.disabled = cal.busy || !(r && r.state === 'done' && r.committed_version == null);
}

function renderCalSummary() {
  const parts = [];
  if (HOOK.calibrationVersion !== null) parts.push(`v${HOOK.calibrationVersion}`);
  else if (cal.active) parts.push('none');
  const r = cal.run;
  if (r) {
    if (isActiveRun(r)) {
      const eta = HOOK.calibrationEtaS === null ? '' : `, ${etaText(HOOK.calibrationEtaS)}`;
      parts.push(`${r.method} ${Math.round(HOOK.calibrationRunProgress * 100)} %${eta}`);
    }
    else if (r.state === 'done' && r.committed_version == null) parts.push(`${r.method} run done: review, commit`);
    else if (r.state === 'failed') parts.push(`${r.method} run failed`);
  }
  calUi.summary.textContent = parts.join(' · ') || '–';
}

function fmt(value, digits, unit) {
  return Number.isFinite(value) ? `${value.toFixed(digits)}${unit}` : null;
}

function renderRun() {
  updateCalButtons();
  const r = cal.run;
  calUi.run.hidden = !r;
  if (!r) return;
  const when = Number.isFinite(r.created_unix_s) ? new Date(r.created_unix_s * 1000).toLocaleTimeString() : '';
  calUi.runTitle.textContent = [r.method, r.reference ? `ref ${r.reference}` : '', when].filter(Boolean).join(' · ');
  calUi.runTitle.title = `run ${r.id}`;
  const state = HOOK.calibrationRunState || '?';
  calUi.runState.textContent = state;
  calUi.runState.className = `hud-label cal-state-${state}`;
  const progress = Math.min(1, Math.max(0, HOOK.calibrationRunProgress));
  calUi.bar.style.width = `${(progress * 100).toFixed(1)}%`;
  calUi.bar.className = `cal-progress-bar${state === 'done' ? ' done' : state === 'failed' ? ' failed' : ''}`;
  calUi.progressText.textContent = `${Math.round(progress * 100)} %`;
  calUi.eta.textContent = HOOK.calibrationEtaS === null ? '' : etaText(HOOK.calibrationEtaS);
  renderStages(r);
  let stage = '';
  if (isActiveRun(r)) {
    const detail = typeof r.stage_detail === 'string' && r.stage_detail ? r.stage_detail : '';
    stage = detail || (HOOK.calibrationStages.length ? '' : HOOK.calibrationStage || '');
  } else if (state === 'done') {
    stage = Number.isInteger(r.committed_version)
      ? `committed as version ${r.committed_version}`
      : 'done, not committed: the dashed frustums show the proposed poses';
  }
  calUi.stage.textContent = stage;

  calUi.runError.hidden = !r.error;
  calUi.runError.textContent = r.error ? `failed: ${r.error}` : '';
  const warnings = Array.isArray(r.warnings) ? r.warnings.map(String) : [];
  calUi.runWarnings.hidden = warnings.length === 0;
  calUi.runWarnings.textContent = warnings.map((w) => `⚠ ${w}`).join('\n');

  const floor = r.floor && typeof r.floor === 'object' ? r.floor : null;
  calUi.floor.hidden = !floor;
  if (floor) {
    const height = fmt(floor.sensor_height_m, 3, ' m');
    const rmse = fmt(floor.rmse_mm, 1, ' mm');
    const tilt = fmt(floor.correction_deg, 2, '°');
    const shift = fmt(floor.correction_mm, 1, ' mm');
    const bits = [
      height && `reference ${height} above it`,
      rmse && `rmse ${rmse}`,
      Number.isFinite(floor.inliers) ? `${floor.inliers} points` : null,
      tilt && `levelled by ${tilt}${shift ? ` / ${shift}` : ''}`,
    ].filter(Boolean);
    calUi.floor.textContent = `floor (${floor.source || '?'})${bits.length ? `: ${bits.join(', ')}` : ''}`;
  }
  renderResults(r);
}

/** "about 40 s left", "about 2 min left", "a few seconds left". */
function etaText(s) {
  if (s < 5) return 'a few seconds left';
  if (s < 90) return `about ${Math.round(s / 5) * 5} s left`;
  return `about ${Math.round(s / 60)} min left`;
}

/** The run's stages as steps: done ✓, the current one ▸ (with its own share done), to come ○. */
function renderStages(r) {
  const stages = HOOK.calibrationStages;
  calUi.stages.hidden = stages.length === 0;
  const active = isActiveRun(r);
  const done = r.state === 'done';
  const current = HOOK.calibrationStageIndex;
  const share = Number.isFinite(r.stage_progress) ? Math.round(r.stage_progress * 100) : null;
  const items = stages.map((name, i) => {
    const li = document.createElement('li');
    const status = done || i < current ? 'done' : active && i === current ? 'current' : r.state === 'failed' && i === current ? 'failed' : 'todo';
    li.className = `cal-step cal-step-${status}`;
    const mark = { done: '✓', current: '▸', failed: '✗', todo: '○' }[status];
    li.textContent = `${mark} ${name}${status === 'current' && share !== null ? ` · ${share} %` : ''}`;
    return li;
  });
  const key = items.map((li) => li.className + li.textContent).join('|');
  if (calUi.stages.dataset.key !== key) {
    calUi.stages.dataset.key = key;
    calUi.stages.replaceChildren(...items);
  }
}

function renderResults(r) {
  const results = r.results && typeof r.results === 'object' ? r.results : {};
  const ids = Object.keys(results).sort();
  const key = `${r.id}|${JSON.stringify(results, (k, v) => (k === 'T_world_from_sensor' ? undefined : v))}`;
  if (key === cal.resultsKey) return;
  cal.resultsKey = key;
  calUi.results.hidden = ids.length === 0;
  const rows = [];
  for (const id of ids) {
    const res = results[id] || {};
    const tr = document.createElement('tr');
    const sw = document.createElement('span');
    sw.className = 'swatch';
    sw.style.background = `#${sensorColor(id).getHexString()}`;
    const tdSw = document.createElement('td');
    tdSw.appendChild(sw);
    const residual = res.method === 'reference' ? '–' : fmt(res.residual_mm, 1, ' mm') || '–';
    const tdRes = cell(residual, 'num');
    const metrics = res.metrics && typeof res.metrics === 'object' ? res.metrics : {};
    tdRes.title = Object.entries(metrics)
      .map(([k, v]) => `${k}: ${typeof v === 'object' ? JSON.stringify(v) : v}`)
      .join('\n');
    const warnings = Array.isArray(res.warnings) ? res.warnings.map(String) : [];
    const tdWarn = cell(warnings.length ? '' : '–', 'warn');
    const expandKey = `${r.id}/${id}`;
    let detailRow = null;
    if (warnings.length) {
      const toggle = document.createElement('span');
      toggle.className = 'cal-warn-toggle';
      toggle.textContent = `⚠ ${warnings.length}`;
      toggle.title = warnings.map((w) => `• ${w}`).join('\n');
      tdWarn.appendChild(toggle);
      detailRow = document.createElement('tr');
      detailRow.className = 'cal-warn-row';
      detailRow.hidden = !cal.expanded.has(expandKey);
      const td = document.createElement('td');
      td.colSpan = 5;
      const ul = document.createElement('ul');
      for (const w of warnings) {
        const li = document.createElement('li');
        li.textContent = w;
        ul.appendChild(li);
      }
      td.appendChild(ul);
      detailRow.appendChild(td);
      const row = detailRow;
      toggle.addEventListener('click', () => {
        row.hidden = !row.hidden;
        if (row.hidden) cal.expanded.delete(expandKey);
        else cal.expanded.add(expandKey);
      });
    }
    tr.append(tdSw, cell(id), cell(typeof res.method === 'string' ? res.method : '–'), tdRes, tdWarn);
    rows.push(tr);
    if (detailRow) rows.push(detailRow);
  }
  calUi.resultRows.replaceChildren(...rows);
}

function setCalBusy(busy) {
  cal.busy = busy;
  updateCalButtons();
}

function startRun() {
  return startRunWith({ method: calUi.method.value });
}

// A sensor flagged "moved?" gets a re-solve button: method sensor re-solves it against the
// others (their poses stay) while fusion runs; the run shows in the calibration panel.
function resolveSensor(id) {
  return startRunWith({ method: 'sensor', sensor: id });
}

async function startRunWith(request) {
  if (cal.busy) return;
  const method = request.method;
  setCalBusy(true);
  showCalError('');
  try {
    const r = await apiJson('POST', '/api/calibration/runs', request);
    if (!r.ok) {
      showCalError(`start ${method}: ${errorDetail(r)}`);
      return;
    }
    cal.runGen++;
    applyRun(r.data);
  } catch (e) {
    showCalError(`start ${method}: ${errorText(e)}`);
  } finally {
    setCalBusy(false);
    pollRuns();
  }
}

async function commitRun() {
  const run = cal.run;
  if (cal.busy || !run) return;
  setCalBusy(true);
  showCalError('');
  try {
    const r = await apiJson('POST', `/api/calibration/runs/${encodeURIComponent(run.id)}/commit`);
    if (!r.ok) {
      showCalError(`commit: ${errorDetail(r)}`);
      return;
    }
    if (r.data && typeof r.data === 'object') {
      cal.runGen++;
      if (cal.run && cal.run.id === run.id) {
        applyRun({ ...cal.run, committed_version: Number.isInteger(r.data.version) ? r.data.version : null });
      }
      applyActiveCalibration({ ...r.data, effective: cal.active ? cal.active.effective : undefined });
    }
  } catch (e) {
    showCalError(`commit: ${errorText(e)}`);
  } finally {
    setCalBusy(false);
    pollRuns();
    pollActiveCalibration();
    pollSensors(); // the frustums move at once
  }
}

calUi.start.addEventListener('click', startRun);
calUi.commit.addEventListener('click', commitRun);

// --- joint hover tooltip -----------------------------------------------------------------------

const hover = { dirty: false, x: 0, y: 0, inside: false, down: false };
const raycaster = new THREE.Raycaster();
const pointerNdc = new THREE.Vector2();
const tip = document.createElement('div');
tip.className = 'joint-tip';
tip.hidden = true;
document.body.appendChild(tip);

if (renderer) {
  const el = renderer.domElement;
  el.addEventListener('pointermove', (ev) => {
    hover.x = ev.clientX;
    hover.y = ev.clientY;
    hover.inside = true;
    hover.down = ev.buttons !== 0;
    hover.dirty = true;
  });
  el.addEventListener('pointerleave', () => {
    hover.inside = false;
    hover.dirty = true;
  });
}

function jointSourcesText(person, joint) {
  const js = Array.isArray(person.joint_sources) ? person.joint_sources[joint] : undefined;
  const sources = Array.isArray(person.sources) ? person.sources : [];
  if (Array.isArray(js)) return js.map(String).join(', ') || 'none'; // a list of sensor ids
  if (Number.isInteger(js)) return sources.filter((s, k) => js & (1 << k)).join(', ') || 'none'; // bitmask
  return null;
}

function updateHover() {
  hover.dirty = false;
  if (!hover.inside || hover.down || !renderer) {
    tip.hidden = true;
    return;
  }
  const rect = renderer.domElement.getBoundingClientRect();
  pointerNdc.set(((hover.x - rect.left) / rect.width) * 2 - 1, -((hover.y - rect.top) / rect.height) * 2 + 1);
  raycaster.setFromCamera(pointerNdc, camera);
  let best = null;
  for (const slot of activePersons.values()) {
    if (slot.joints.count === 0) continue;
    slot.joints.computeBoundingSphere(); // instances move every frame
    const hits = raycaster.intersectObject(slot.joints, false);
    if (hits.length && (!best || hits[0].distance < best.hit.distance)) best = { slot, hit: hits[0] };
  }
  if (!best || best.hit.instanceId === undefined || !best.slot.person) {
    tip.hidden = true;
    return;
  }
  const { slot, hit } = best;
  const joint = slot.instanceJoint[hit.instanceId];
  const name = skeleton.jointNames && skeleton.jointNames[joint] ? skeleton.jointNames[joint] : `joint ${joint}`;
  const conf = slot.conf[joint];
  const lines = [`#${slot.id} ${name}`, `confidence ${Number.isNaN(conf) ? '–' : conf.toFixed(2)}`];
  const src = jointSourcesText(slot.person, joint);
  if (src !== null) lines.push(`sources: ${src}`);
  tip.textContent = lines.join('\n');
  tip.style.borderColor = Number.isNaN(conf) ? '' : confidenceCss(conf);
  tip.style.left = `${hover.x + 14}px`;
  tip.style.top = `${hover.y + 12}px`;
  tip.hidden = false;
}

// --- framing: every sensor and its label in view -------------------------------------------------

// Until the user moves the camera, the view is fitted to the sensors each time their poses
// change: the default camera (3 m up, 6 m back) cut off sensors and their labels in wider rigs.
let userMovedCamera = false;
let framedKey = '';
if (controls) controls.addEventListener('start', () => (userMovedCamera = true));
const VIEW_DIRECTION = new THREE.Vector3(0, 0.42, 1).normalize(); // from the target to the camera

function frameSensors() {
  if (userMovedCamera) return;
  const positions = [...sensorViews.values()].filter((v) => v.group.visible).map((v) => v.label.position);
  const key = positions.map((p) => `${p.x.toFixed(2)},${p.y.toFixed(2)},${p.z.toFixed(2)}`).join(';');
  if (!positions.length || key === framedKey) return;
  framedKey = key;
  const box = new THREE.Box3().setFromPoints(positions);
  box.max.y += 0.35; // the labels above the sensors
  box.min.y = Math.max(0, box.min.y - 0.4); // and the sensors' frustums below them
  box.expandByScalar(0.2);
  const center = box.getCenter(new THREE.Vector3());
  const target = new THREE.Vector3(center.x, Math.min(1, center.y), center.z);
  applyViewSize(); // the HUD's width now that it lists the sensors
  // The nearest camera (along VIEW_DIRECTION) from which the box's corners all project into
  // the canvas right of the HUD, with a margin: a bisection over the distance.
  const corners = [];
  for (const x of [box.min.x, box.max.x])
    for (const y of [box.min.y, box.max.y]) for (const z of [box.min.z, box.max.z]) corners.push(new THREE.Vector3(x, y, z));
  const left = (2 * hudShiftPx) / Math.max(1, window.innerWidth) - 1 + 0.04;
  const fits = (distance) => {
    camera.position.copy(target).addScaledVector(VIEW_DIRECTION, distance);
    camera.lookAt(target);
    camera.updateMatrixWorld();
    return corners.every((c) => {
      const p = c.clone().project(camera);
      return p.z < 1 && p.x >= left && p.x <= 0.96 && Math.abs(p.y) <= 0.92;
    });
  };
  let near = 1;
  let far = 60;
  for (let i = 0; i < 30; i++) {
    const mid = (near + far) / 2;
    if (fits(mid)) far = mid;
    else near = mid;
  }
  camera.position.copy(target).addScaledVector(VIEW_DIRECTION, far);
  camera.lookAt(target);
  if (controls) {
    controls.target.copy(target);
    controls.update();
  }
  requestRender();
}

const labelNdc = new THREE.Vector3();

/** Ids of the visible 3D labels whose text reaches past the canvas edge (sprites drawn at a
 * constant size on screen: their extent in NDC is scale × the projection's focal terms). */
function clippedLabels() {
  const out = [];
  const P = camera.projectionMatrix.elements;
  const labels = [
    ...[...sensorViews.values()].map((v) => [v.id, v.label]),
    ...[...activePersons.values()].map((slot) => [`#${slot.id}`, slot.label]),
  ];
  for (const [id, sprite] of labels) {
    if (!sprite.visible || !sprite.parent) continue;
    sprite.getWorldPosition(labelNdc).project(camera);
    if (labelNdc.z > 1) continue; // behind the camera
    const frac = sprite.userData.textFrac || 1;
    const halfW = P[0] * sprite.scale.x * frac * 0.5;
    const x0 = labelNdc.x + P[0] * sprite.scale.x * (0.5 - sprite.center.x) - halfW;
    const x1 = x0 + 2 * halfW;
    const y0 = labelNdc.y - P[5] * sprite.scale.y * sprite.center.y;
    const y1 = y0 + P[5] * sprite.scale.y;
    if (x0 < -1 || x1 > 1 || y0 < -1 || y1 > 1) out.push(id);
  }
  return out;
}

// --- main loop ---------------------------------------------------------------------------------

// A pass renders only when something changed (a frame, the camera, sensors, calibration...) or
// every 250 ms: frames arrive at 30/s, so rendering at the display's 60 Hz would double the cost
// for nothing (a software-rendered headless browser spends a whole CPU core on it).
let renderRequested = true;
let lastRenderAt = -Infinity;
const IDLE_RENDER_MS = 250;

function requestRender() {
  renderRequested = true;
}

function renderOnce() {
  let dirty = renderRequested;
  renderRequested = false;
  if (pendingFrame) {
    dirty = true;
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
  if (controls && controls.update()) dirty = true; // true while the camera moves (damping too)
  if (hover.dirty || hover.inside) updateHover(); // the joints move under a still pointer too
  if (renderer) {
    const t0 = performance.now();
    if (!dirty && t0 - lastRenderAt < IDLE_RENDER_MS) return;
    lastRenderAt = t0;
    renderer.render(scene, camera);
    HOOK.renderMs = performance.now() - t0;
    HOOK.renders++;
    HOOK.gpuGeometries = renderer.info.memory.geometries;
    HOOK.gpuTextures = renderer.info.memory.textures;
    HOOK.labelsClipped = clippedLabels();
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
const clouds = new CloudLayer({
  scene,
  api,
  colorOf: sensorColor,
  bones: () => skeleton.bones,
  requestRender,
  hook: HOOK,
  onNote: (text) => {
    cloudNote.textContent = text;
  },
  onProvisional: showProvisionalSensors,
});
const cloudNote = document.getElementById('cloud-note');
const cloudsToggle = document.getElementById('clouds-toggle');
cloudsToggle.checked = false;
cloudsToggle.addEventListener('change', () => clouds.setEnabled(cloudsToggle.checked));

const legend = document.getElementById('confidence-legend');
document.getElementById('legend-bar').style.background = `linear-gradient(to right, ${CONFIDENCE_RAMP.join(', ')})`;
confidenceToggle.addEventListener('change', () => (legend.hidden = !confidenceToggle.checked));

const recording = initRecording({ api, hook: HOOK });

feed.start();
pollSensors();
pollActiveCalibration();
pollRuns();

// The 3D view: polls /scene and /cloud of ur_rg2_view3d and draws them with three.js.
// ROS frames are z-up; everything hangs under `world`, turned so that ROS z is three.js y.
import * as THREE from 'three';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
import { OBJLoader } from 'three/examples/jsm/loaders/OBJLoader.js';
import URDFLoader from 'urdf-loader';

const $ = (id) => document.getElementById(id);
const SCENE_PERIOD_MS = 50;
const CLOUD_PERIOD_MS = 500;
const STALE_S = 2.0;  // an entry older than this is shown as stale

const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
$('view').appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x1d2126);
const camera = new THREE.PerspectiveCamera(45, 1, 0.01, 50);
camera.position.set(2.6, 2.2, -2.0);  // ROS (2.6, 2.0, 2.2): across from the sim camera
const controls = new OrbitControls(camera, renderer.domElement);
controls.target.set(0.5, 0.2, 0.5);
controls.update();
scene.add(new THREE.HemisphereLight(0xffffff, 0x444444, 2.0));
const sun = new THREE.DirectionalLight(0xffffff, 1.5);
sun.position.set(2, 4, 1);
scene.add(sun);

const world = new THREE.Group();
world.rotation.x = -Math.PI / 2;
scene.add(world);
const grid = new THREE.GridHelper(2, 8, 0x667080, 0x3a4048);
grid.rotation.x = Math.PI / 2;
world.add(grid);
world.add(new THREE.AxesHelper(0.2));

function sphere(color, radius, opacity = 1) {
  const mesh = new THREE.Mesh(new THREE.SphereGeometry(radius, 24, 16),
    new THREE.MeshStandardMaterial({ color, transparent: opacity < 1, opacity }));
  mesh.visible = false;
  world.add(mesh);
  return mesh;
}
const ballTrue = sphere(0xff3b30, 0.03);
const ballSeen = sphere(0x30d0ff, 0.034, 0.45);
const pickTarget = new THREE.Mesh(new THREE.TorusGeometry(0.045, 0.006, 8, 32),
  new THREE.MeshBasicMaterial({ color: 0xffd54f }));
pickTarget.visible = false;
world.add(pickTarget);

const frustum = new THREE.LineSegments(new THREE.BufferGeometry(),
  new THREE.LineBasicMaterial({ color: 0x9ad0ff }));
frustum.matrixAutoUpdate = false;
frustum.frustumCulled = false;  // its geometry changes: no stale bounding sphere
world.add(frustum);
const cloud = new THREE.Points(new THREE.BufferGeometry(),
  new THREE.PointsMaterial({ size: 0.012, vertexColors: true }));
cloud.frustumCulled = false;
world.add(cloud);

let robot = null;
let loading = false;
let descriptionSize = null;
const view = { robotLoaded: false, meshesLoaded: 0, scenes: 0, clouds: 0 };
window.view3d = view;  // for tests and the curious

function loadMesh(path, manager, material, done) {
  if (/\.obj$/i.test(path)) {
    new OBJLoader(manager).load(path, (group) => {
      group.traverse((child) => { if (child.isMesh) child.material = material; });
      view.meshesLoaded += 1;
      done(group);
    }, null, (err) => done(null, err));
  } else {
    loader.defaultMeshLoader(path, manager, material, (mesh, err) => {
      if (mesh) view.meshesLoaded += 1;
      done(mesh, err);
    });
  }
}
const loader = new URDFLoader();
loader.loadMeshCb = loadMesh;

function loadRobot(size) {
  loading = true;
  loader.loadAsync('robot.urdf').then((loaded) => {
    if (robot) world.remove(robot);
    robot = loaded;
    robot.matrixAutoUpdate = false;
    world.add(robot);
    descriptionSize = size;
    view.robotLoaded = true;
    $('robot').textContent = `robot: ${robot.robotName || 'loaded'}, ` +
      `${Object.keys(robot.joints).length} joints`;
  }).catch((err) => {
    $('robot').textContent = `robot: cannot load robot_description (${err})`;
  }).finally(() => { loading = false; });
}

function fmt(p) {
  return p ? `x ${p[0].toFixed(3)} y ${p[1].toFixed(3)} z ${p[2].toFixed(3)} m` : '–';
}

function setFrustum(cam) {
  const [fx, , cx, , fy, cy] = cam.k;
  const d = 0.25;  // m: how far the drawn frustum reaches
  const corners = [[0, 0], [cam.width, 0], [cam.width, cam.height], [0, cam.height]]
    .map(([u, v]) => [(u - cx) * d / fx, (v - cy) * d / fy, d]);
  const pts = [];
  for (let i = 0; i < 4; i++) {
    pts.push(0, 0, 0, ...corners[i]);
    pts.push(...corners[i], ...corners[(i + 1) % 4]);
  }
  frustum.geometry.setAttribute('position', new THREE.Float32BufferAttribute(pts, 3));
  frustum.matrix.fromArray(cam.pose);  // column-major 4x4, world from optical frame
}

function place(mesh, position, element, label) {
  mesh.visible = Boolean(position);
  if (position) mesh.position.fromArray(position);
  $(element).textContent = `${label}: ${fmt(position)}`;
}

function show(state) {
  view.scenes += 1;
  const ages = state.ages || {};
  if (state.description !== undefined && state.description !== descriptionSize && !loading) {
    loadRobot(state.description);
  }
  if (robot && state.joints) {
    for (const [name, value] of Object.entries(state.joints)) {
      if (robot.joints[name]) robot.setJointValue(name, value);
    }
  }
  if (robot && state.root) robot.matrix.fromArray(state.root);
  const opening = state.gripper_opening_mm;
  $('gripper').textContent = `gripper: ${opening === null || opening === undefined ? '–'
    : opening.toFixed(1) + ' mm open'}`;
  place(ballTrue, ages.ball_true < STALE_S && state.ball_true, 'ball-true', 'ball (true)');
  place(ballSeen, ages.ball_detected < STALE_S && state.ball_detected, 'ball-seen',
    'ball (vision)');
  if (state.camera) setFrustum(state.camera);
  const pick = state.pick;
  pickTarget.visible = Boolean(pick && pick.target);
  if (pick && pick.target) pickTarget.position.fromArray(pick.target);
  if (pick) $('pick').textContent = `last pick: ${pick.text}`;
}

async function poll(path, period, handle) {
  for (;;) {
    const started = performance.now();
    try {
      const response = await fetch(path, { cache: 'no-store' });
      if (response.ok) {
        handle(await response.json());
        $('status').textContent = 'live';
        $('status').className = '';
      }
    } catch (err) {
      $('status').textContent = `no connection to the 3D view node (${err.message})`;
      $('status').className = 'down';
    }
    await new Promise((r) => setTimeout(r, Math.max(0, period - (performance.now() - started))));
  }
}

function showCloud(data) {
  view.clouds += 1;
  cloud.geometry.setAttribute('position', new THREE.Float32BufferAttribute(data.points, 3));
  cloud.geometry.setAttribute('color',
    new THREE.Float32BufferAttribute(data.colors.map((c) => c / 255), 3));
  $('cloud').textContent = `point cloud: ${data.points.length / 3} points`;
}

function resize() {
  renderer.setSize(window.innerWidth, window.innerHeight);
  camera.aspect = window.innerWidth / window.innerHeight;
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();
renderer.setAnimationLoop(() => renderer.render(scene, camera));
poll('scene', SCENE_PERIOD_MS, show);
poll('cloud', CLOUD_PERIOD_MS, showCloud);

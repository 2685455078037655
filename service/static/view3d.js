// spacearm 3D view: a plan's motion played back with three.js (bundled offline from the pinned
// npm packages by web/build.sh; a module file, not inline: the pages' CSP allows scripts from this
// site only).
//
// Data: the trajectory (times, base pose, desired and achieved end-effector paths) from the JSON
// API (GET /v1/plans/{id}?fields=trajectory), the robot's name from GET /v1/robots/{id}, and the
// arm's joint positions per frame, computed on the server by forward kinematics
// (GET /plans/{id}/scene.json, with the carrier's box and the plan's obstacles).
// World frame: z up, metres.
import * as THREE from "./three-0.187.0.min.js";

const COLORS = {
  desired: 0x5fa8ff, achieved: 0xff9f43, arm: 0xd0d7de, joint: 0xe6edf3, tip: 0xf4a261,
  carrier: 0x8e9aaf, trail: 0x2ecc71, obstacle: 0xe5534b, background: 0x0d1b2a, grid: 0x34495e,
};
const LINK_RADIUS = 0.02;  // m, the links' cylinders
const JOINT_RADIUS = 0.035;  // m

const body = document.body;
const planId = body.dataset.planId;
const robotId = body.dataset.robotId;
const canvas = document.getElementById("scene");
const slider = document.getElementById("time");
const timeLabel = document.getElementById("time-label");
const playButton = document.getElementById("play");
const speedSelect = document.getElementById("speed");
const statusLine = document.getElementById("view-status");
const overlay = document.getElementById("overlay");

async function getJson(url) {
  const response = await fetch(url, {headers: {Accept: "application/json"}, credentials: "same-origin"});
  if (!response.ok) { throw new Error(`${url}: ${response.status} ${response.statusText}`); }
  return response.json();
}

function finitePoints(rows) {
  return rows.filter((p) => p && p.every((v) => v !== null && Number.isFinite(v))).map((p) => new THREE.Vector3(p[0], p[1], p[2]));
}

/** A path as a line of constant width on screen (three's Line2: WebGL draws plain lines 1 px
 * wide), drawn over the arm and the carrier (no depth test), in ``order`` among the paths. */
function polyline(points, color, width, opacity, order) {
  const geometry = new THREE.LineGeometry();
  geometry.setPositions(points.flatMap((p) => [p.x, p.y, p.z]));
  const material = new THREE.LineMaterial({color, linewidth: width, transparent: true, opacity, depthTest: false});
  const line = new THREE.Line2(geometry, material);
  line.renderOrder = order;
  return line;
}

function quaternion(wxyz) {  // the API's [w, x, y, z]
  return wxyz && wxyz.every((v) => v !== null) ? new THREE.Quaternion(wxyz[1], wxyz[2], wxyz[3], wxyz[0]) : new THREE.Quaternion();
}

/** The carrier: its collision box, or a box of its mass and inertia (principal axes from the scene), drawn at the base pose. */
function carrierMesh(carrier) {
  const [a, b, c] = carrier.size_m;
  const geometry = new THREE.BoxGeometry(a, b, c);
  const group = new THREE.Group();
  const box = new THREE.Mesh(geometry, new THREE.MeshStandardMaterial({color: COLORS.carrier, transparent: true, opacity: 0.35, metalness: 0.1, roughness: 0.8}));
  const edges = new THREE.LineSegments(new THREE.EdgesGeometry(geometry), new THREE.LineBasicMaterial({color: COLORS.carrier}));
  const axes = carrier.axes;  // columns: principal axes in the base frame
  const principal = new THREE.Group();
  principal.quaternion.setFromRotationMatrix(new THREE.Group().matrix.set(
    axes[0][0], axes[0][1], axes[0][2], 0, axes[1][0], axes[1][1], axes[1][2], 0, axes[2][0], axes[2][1], axes[2][2], 0, 0, 0, 0, 1));
  principal.add(box, edges);
  principal.position.set(...carrier.com_offset_m);  // a collision box's centre from the carrier's CoM
  group.add(principal);
  return group;
}

/** Obstacles of plans with geometry: triangle meshes in the world frame (the scene's `obstacles`). */
function obstacleMeshes(obstacles) {
  const material = new THREE.MeshStandardMaterial({color: COLORS.obstacle, transparent: true, opacity: 0.45, side: THREE.DoubleSide});
  return obstacles.map((o) => {
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute("position", new THREE.Float32BufferAttribute(o.positions_m.flat(), 3));
    geometry.setIndex(o.faces.flat());
    geometry.computeVertexNormals();
    return new THREE.Mesh(geometry, material);
  });
}

/** The arm: one cylinder per link and one sphere per joint, moved to each frame's points. */
class Arm {
  constructor(nPoints) {
    this.group = new THREE.Group();
    const linkMaterial = new THREE.MeshStandardMaterial({color: COLORS.arm, metalness: 0.3, roughness: 0.5});
    const jointMaterial = new THREE.MeshStandardMaterial({color: COLORS.joint, metalness: 0.2, roughness: 0.4});
    const tipMaterial = new THREE.MeshStandardMaterial({color: COLORS.tip, emissive: 0x442200});
    const link = new THREE.CylinderGeometry(LINK_RADIUS, LINK_RADIUS, 1, 16);
    this.links = Array.from({length: nPoints - 1}, () => new THREE.Mesh(link, linkMaterial));
    this.joints = Array.from({length: nPoints}, (_, i) => new THREE.Mesh(
      new THREE.SphereGeometry(i === nPoints - 1 ? 1.4 * JOINT_RADIUS : JOINT_RADIUS, 20, 14),
      i === nPoints - 1 ? tipMaterial : jointMaterial));
    this.group.add(...this.links, ...this.joints);
    this.up = new THREE.Vector3(0, 1, 0);
  }

  show(points) {
    const v = points.map((p) => new THREE.Vector3(p[0], p[1], p[2]));
    v.forEach((p, i) => this.joints[i].position.copy(p));
    this.links.forEach((mesh, i) => {
      const d = new THREE.Vector3().subVectors(v[i + 1], v[i]);
      const length = d.length();
      mesh.visible = length > 1e-6;
      if (!mesh.visible) { return; }
      mesh.position.copy(v[i]).addScaledVector(d, 0.5);
      mesh.quaternion.setFromUnitVectors(this.up, d.divideScalar(length));
      mesh.scale.set(1, length, 1);
    });
  }
}

function fitCamera(camera, controls, points) {
  const min = new THREE.Vector3(Infinity, Infinity, Infinity);
  const max = new THREE.Vector3(-Infinity, -Infinity, -Infinity);
  points.forEach((p) => { min.min(p); max.max(p); });
  const center = new THREE.Vector3().addVectors(min, max).multiplyScalar(0.5);
  const radius = Math.max(0.5, 0.5 * new THREE.Vector3().subVectors(max, min).length());
  const distance = (radius / Math.sin((camera.fov * Math.PI) / 360)) * 0.85;
  camera.position.copy(center).add(new THREE.Vector3(0.9, -1.6, 0.9).normalize().multiplyScalar(distance));
  camera.near = distance / 100;
  camera.far = distance * 20;
  camera.updateProjectionMatrix();
  controls.target.copy(center);
  controls.update();
  return {center, radius};
}

async function main() {
  const [plan, sceneData, robot] = await Promise.all([
    getJson(`/v1/plans/${planId}?fields=trajectory`),
    getJson(`/plans/${planId}/scene.json`),
    robotId ? getJson(`/v1/robots/${encodeURIComponent(robotId)}`) : Promise.resolve(null),
  ]);
  const trajectory = plan.trajectory;
  const frames = sceneData.frames;
  if (!frames.index.length) { throw new Error("this plan has no finite arm pose to show"); }

  const renderer = new THREE.WebGLRenderer({canvas, antialias: true, preserveDrawingBuffer: true});
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(COLORS.background);
  const camera = new THREE.PerspectiveCamera(40, 1, 0.01, 100);
  camera.up.set(0, 0, 1);
  const controls = new THREE.OrbitControls(camera, canvas);
  controls.enableDamping = true;
  scene.add(new THREE.AmbientLight(0xffffff, 0.9));
  const sun = new THREE.DirectionalLight(0xffffff, 1.6);
  sun.position.set(2, -3, 4);
  scene.add(sun);

  const desired = finitePoints(trajectory.ee_position_desired_m);
  const achieved = finitePoints(trajectory.ee_position_m);
  const base = finitePoints(trajectory.base_position_m);
  scene.add(polyline(desired, COLORS.desired, 7, 0.5, 1));
  scene.add(polyline(achieved, COLORS.achieved, 2, 0.45, 2));
  const achievedSoFar = polyline(achieved, COLORS.achieved, 3, 1, 3);  // drawn up to the current time
  scene.add(achievedSoFar);
  if (base.length > 1) { scene.add(polyline(base, COLORS.trail, 3, 1, 1)); }
  obstacleMeshes(sceneData.obstacles).forEach((mesh) => scene.add(mesh));
  document.getElementById("legend-obstacles").hidden = sceneData.obstacles.length === 0;
  const carrier = carrierMesh(sceneData.carrier);
  scene.add(carrier);
  const arm = new Arm(frames.points_m[0].length);
  scene.add(arm.group);

  const everything = [...desired, ...achieved, ...frames.points_m.flat().map((p) => new THREE.Vector3(...p))];
  const view = fitCamera(camera, controls, everything);
  const grid = new THREE.GridHelper(Math.ceil(view.radius * 4), Math.ceil(view.radius * 4) * 4, COLORS.grid, COLORS.grid);
  grid.rotation.x = Math.PI / 2;  // three's grid lies in x-z; ours is the world's x-y plane
  grid.position.set(Math.round(view.center.x), Math.round(view.center.y), Math.min(...everything.map((p) => p.z)) - 0.05);
  scene.add(grid, new THREE.AxesHelper(0.3));

  const times = trajectory.t_s;
  let frame = 0;
  function show(k) {
    frame = Math.max(0, Math.min(frames.index.length - 1, k));
    const sample = frames.index[frame];
    arm.show(frames.points_m[frame]);
    const position = trajectory.base_position_m[sample];
    if (position && position.every((v) => v !== null)) { carrier.position.set(...position); }
    carrier.quaternion.copy(quaternion(trajectory.base_attitude_quaternion[sample]));
    achievedSoFar.geometry.instanceCount = Math.max(0, Math.min(achieved.length - 1, sample));  // segments so far
    slider.value = String(frame);
    timeLabel.textContent = `t = ${frames.t_s[frame].toFixed(2)} s of ${times[times.length - 1].toFixed(2)} s`;
  }

  slider.max = String(frames.index.length - 1);
  slider.addEventListener("input", () => { stop(); show(Number(slider.value)); });

  // playback in the plan's time, scaled by the speed chosen
  let playing = false;
  let clock = 0;
  let last = 0;
  function stop() { playing = false; playButton.textContent = "Play"; }
  playButton.addEventListener("click", () => {
    if (playing) { stop(); return; }
    if (frame >= frames.index.length - 1) { show(0); }
    playing = true;
    clock = frames.t_s[frame];
    last = performance.now();
    playButton.textContent = "Pause";
  });
  document.getElementById("reset-view").addEventListener("click", () => fitCamera(camera, controls, everything));

  function resize() {
    const width = canvas.clientWidth;
    const height = canvas.clientHeight;
    if (canvas.width !== Math.round(width * renderer.getPixelRatio()) || canvas.height !== Math.round(height * renderer.getPixelRatio())) {
      renderer.setSize(width, height, false);
      camera.aspect = width / height;
      camera.updateProjectionMatrix();
    }
  }

  function tick(now) {
    if (playing) {
      clock += ((now - last) / 1000) * Number(speedSelect.value);
      let k = frame;
      while (k < frames.t_s.length - 1 && frames.t_s[k + 1] <= clock) { k += 1; }
      show(k);
      if (k >= frames.t_s.length - 1) { stop(); }
    }
    last = now;
    resize();
    controls.update();
    renderer.render(scene, camera);
    requestAnimationFrame(tick);
  }

  show(0);
  const name = robot ? robot.name : "robot";
  statusLine.textContent = `${name}: ${frames.index.length} frames of ${times.length} samples, three.js r${THREE.REVISION}`;
  overlay.textContent = `${plan.method.name} · ${plan.success ? "success" : "failed"}`;
  // what the browser test reads: the frame shown and the end effector's position
  window.spacearmView = {
    frames: frames.index.length,
    get frame() { return frame; },
    show,
    tip: () => frames.points_m[frame][frames.points_m[frame].length - 1],
  };
  body.dataset.viewReady = "1";
  requestAnimationFrame(tick);
}

main().catch((error) => {
  statusLine.textContent = `The 3D view could not start: ${error.message}`;
  statusLine.className = "error";
  body.dataset.viewReady = "error";
});

// The 3D world of a ride, built from the lane shapes SUMO drives on.
//
// SUMO's coordinates (x east, y north, metres) map to three.js as
// (x, height, -y). A heading is SUMO's angle: degrees clockwise from north.

import * as THREE from "./vendor/three/three.module.js";

const ASPHALT = 0x55585c;
const JUNCTION = 0x5a5d61;
const GRASS = 0x6f9a4a;
const ISLAND = 0x7fae55;
const CAR_LENGTH = 5.0;
const CAR_COLOURS = [0xb8c4d0, 0x2f4f7f, 0x8c1c13, 0xe0e0e0, 0x3c3c3c, 0x6d7f3a, 0xc9a227, 0x5b3a6b];

/** Unit heading vector in SUMO's plane for an angle in degrees. */
export function heading(angleDeg) {
  const a = (angleDeg * Math.PI) / 180;
  return [Math.sin(a), Math.cos(a)];
}

/** A polygon in SUMO's plane as a flat mesh at height y. */
function flatPolygon(points, colour, y) {
  const shape = new THREE.Shape(points.map(([x, yy]) => new THREE.Vector2(x, yy)));
  const mesh = new THREE.Mesh(new THREE.ShapeGeometry(shape),
    new THREE.MeshLambertMaterial({ color: colour }));
  mesh.rotation.x = -Math.PI / 2;
  mesh.position.y = y;
  return mesh;
}

/** The polyline with points at most `step` metres apart. Long triangles
 * and lines that reach far behind the camera are clipped wrongly by some
 * software renderers (SwiftShader), so roads are drawn in short pieces. */
function resample(shape, step) {
  const out = [shape[0]];
  for (let i = 1; i < shape.length; i++) {
    const [ax, ay] = shape[i - 1], [bx, by] = shape[i];
    const n = Math.max(1, Math.ceil(Math.hypot(bx - ax, by - ay) / step));
    for (let k = 1; k <= n; k++) out.push([ax + (bx - ax) * k / n, ay + (by - ay) * k / n]);
  }
  return out;
}

/** Left and right borders of a lane of width w along a polyline. */
function laneBorders(shape, width) {
  const left = [], right = [];
  for (let i = 0; i < shape.length; i++) {
    const a = shape[Math.max(i - 1, 0)], b = shape[Math.min(i + 1, shape.length - 1)];
    let dx = b[0] - a[0], dy = b[1] - a[1];
    const len = Math.hypot(dx, dy) || 1;
    dx /= len; dy /= len;
    const nx = -dy * width / 2, ny = dx * width / 2;  // left normal
    left.push([shape[i][0] + nx, shape[i][1] + ny]);
    right.push([shape[i][0] - nx, shape[i][1] - ny]);
  }
  return [left, right];
}

/** A lane's surface: one quad between each pair of neighbouring points. */
function laneSurface(left, right, material, y) {
  const positions = [];
  for (let i = 1; i < left.length; i++) {
    const quad = [left[i - 1], right[i - 1], left[i], right[i - 1], right[i], left[i]];
    for (const [x, yy] of quad) positions.push(x, y, -yy);
  }
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute(positions, 3));
  geometry.computeVertexNormals();
  return new THREE.Mesh(geometry, material);
}

function line(points, material, y) {
  const geometry = new THREE.BufferGeometry().setFromPoints(
    points.map(([x, yy]) => new THREE.Vector3(x, y, -yy)));
  const l = new THREE.Line(geometry, material);
  if (material.isLineDashedMaterial) l.computeLineDistances();
  return l;
}

/** A deterministic pseudo-random sequence (the same world every ride). */
function randomSequence(seed) {
  let s = seed >>> 0;
  return () => ((s = (s * 1664525 + 1013904223) >>> 0) / 4294967296);
}

function distanceToSegment(x, y, [ax, ay], [bx, by]) {
  const dx = bx - ax, dy = by - ay, len2 = dx * dx + dy * dy || 1;
  const t = Math.min(1, Math.max(0, ((x - ax) * dx + (y - ay) * dy) / len2));
  return Math.hypot(ax + t * dx - x, ay + t * dy - y);
}

function farFromRoads(x, y, lanes, margin) {
  for (const lane of lanes) {
    for (let i = 1; i < lane.shape.length; i++) {
      if (distanceToSegment(x, y, lane.shape[i - 1], lane.shape[i]) < margin) return false;
    }
  }
  return true;
}

/** Lanes whose outer end leads nowhere (the network's border) are drawn on
 * for `length` metres, so that the road does not stop in a field. */
function extendedLanes(lanes, length) {
  const key = ([x, y]) => `${x.toFixed(1)},${y.toFixed(1)}`;
  const ends = new Map();
  for (const lane of lanes) {
    for (const p of [lane.shape[0], lane.shape[lane.shape.length - 1]]) {
      ends.set(key(p), (ends.get(key(p)) || 0) + 1);
    }
  }
  return lanes.map((lane) => {
    if (lane.internal || lane.shape.length < 2) return lane;
    const shape = lane.shape.map((p) => [...p]);
    const n = shape.length;
    const stretch = (end, next) => {
      const dx = end[0] - next[0], dy = end[1] - next[1], len = Math.hypot(dx, dy) || 1;
      return [end[0] + dx / len * length, end[1] + dy / len * length];
    };
    if (ends.get(key(shape[0])) === 1) shape.unshift(stretch(shape[0], shape[1]));
    if (ends.get(key(shape[n - 1])) === 1) shape.push(stretch(shape[n - 1], shape[n - 2]));
    return { ...lane, shape };
  });
}

/** Scenery that gives depth: houses and trees away from the roads. */
function scenery(scene, lanes, radius) {
  const rand = randomSequence(17);
  const houseColours = [0xd9c7a7, 0xc98f6b, 0xe6e0d4, 0xa9b3b8, 0xcfb48a];
  for (let placed = 0, tries = 0; placed < 90 && tries < 3000; tries++) {
    const a = rand() * 2 * Math.PI, r = radius + 14 + rand() * 140;
    const x = r * Math.cos(a), y = r * Math.sin(a);
    const w = 8 + rand() * 10, d = 8 + rand() * 10, h = 6 + rand() * 16;
    if (!farFromRoads(x, y, lanes, Math.hypot(w, d) / 2 + 6)) continue;
    const house = new THREE.Mesh(new THREE.BoxGeometry(w, h, d),
      new THREE.MeshLambertMaterial({ color: houseColours[placed % houseColours.length] }));
    house.position.set(x, h / 2, -y);
    house.rotation.y = rand() * Math.PI;
    scene.add(house);
    placed++;
  }
  const trunk = new THREE.MeshLambertMaterial({ color: 0x6b4f2a });
  const leaves = new THREE.MeshLambertMaterial({ color: 0x3f6f2f });
  for (let placed = 0, tries = 0; placed < 80 && tries < 3000; tries++) {
    const x = (rand() - 0.5) * 2 * (radius + 60), y = (rand() - 0.5) * 2 * (radius + 60);
    if (!farFromRoads(x, y, lanes, 5) || Math.hypot(x, y) < radius + 4) continue;
    scene.add(tree(x, y, 3 + rand() * 3, trunk, leaves));
    placed++;
  }
}

function tree(x, y, height, trunk, leaves) {
  const group = new THREE.Group();
  const stem = new THREE.Mesh(new THREE.CylinderGeometry(0.2, 0.25, height * 0.4), trunk);
  stem.position.y = height * 0.2;
  const crown = new THREE.Mesh(new THREE.ConeGeometry(height * 0.3, height * 0.75, 8), leaves);
  crown.position.y = height * 0.4 + height * 0.35;
  group.add(stem, crown);
  group.position.set(x, 0, -y);
  return group;
}

/** The central island: a raised green disc inside the ring lanes. */
function island(scene, roads) {
  const ring = roads.lanes.filter((l) => l.id.startsWith("ring_"));
  if (ring.length === 0) return 0;
  let inner = Infinity;
  for (const lane of ring) {
    for (const [x, y] of lane.shape) inner = Math.min(inner, Math.hypot(x, y) - lane.width / 2);
  }
  const disc = new THREE.Mesh(new THREE.CylinderGeometry(inner - 0.3, inner - 0.3, 0.25, 48),
    new THREE.MeshLambertMaterial({ color: ISLAND }));
  disc.position.y = 0.125;
  const kerb = new THREE.Mesh(new THREE.CylinderGeometry(inner, inner, 0.18, 48),
    new THREE.MeshLambertMaterial({ color: 0xd0d0d0 }));
  kerb.position.y = 0.09;
  scene.add(kerb, disc);
  const trunk = new THREE.MeshLambertMaterial({ color: 0x6b4f2a });
  const leaves = new THREE.MeshLambertMaterial({ color: 0x2f5f27 });
  scene.add(tree(0, 0, 5, trunk, leaves));
  return inner;
}

/** The world: ground, roads from the lane shapes, island, scenery, lights. */
export function buildWorld(roads) {
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0xa8cbe8);
  scene.fog = new THREE.Fog(0xa8cbe8, 120, 420);
  scene.add(new THREE.HemisphereLight(0xe8f0ff, 0x4a5a3a, 1.6));
  const sun = new THREE.DirectionalLight(0xffffff, 1.4);
  sun.position.set(60, 120, 40);
  scene.add(sun);
  const ground = new THREE.Mesh(new THREE.PlaneGeometry(1200, 1200, 120, 120),
    new THREE.MeshLambertMaterial({ color: GRASS }));
  ground.rotation.x = -Math.PI / 2;
  scene.add(ground);
  for (const polygon of roads.junctions) scene.add(flatPolygon(polygon, JUNCTION, 0.015));
  const edgeMaterial = new THREE.LineBasicMaterial({ color: 0xf2f2f2 });
  const centreMaterial = new THREE.LineDashedMaterial({ color: 0xf2f2f2, dashSize: 3, gapSize: 3 });
  const lanes = extendedLanes(roads.lanes, 300);
  const asphalt = new THREE.MeshLambertMaterial({ color: ASPHALT, side: THREE.DoubleSide });
  for (const lane of lanes) {
    if (lane.shape.length < 2) continue;
    const [left, right] = laneBorders(resample(lane.shape, 2), lane.width);
    scene.add(laneSurface(left, right, asphalt, lane.internal ? 0.02 : 0.025));
    if (!lane.internal) {
      scene.add(line(right, edgeMaterial, 0.04));
      scene.add(line(left, centreMaterial, 0.04));
    }
  }
  const radius = island(scene, roads);
  scenery(scene, lanes, Math.max(radius, 10) + 10);
  return scene;
}

/** A simple car body; every car looks alike but for a colour from its number. */
export function carMesh(number) {
  const group = new THREE.Group();
  const paint = new THREE.MeshLambertMaterial({ color: CAR_COLOURS[number % CAR_COLOURS.length] });
  const glass = new THREE.MeshLambertMaterial({ color: 0x22303a });
  const body = new THREE.Mesh(new THREE.BoxGeometry(1.8, 0.75, CAR_LENGTH * 0.96), paint);
  body.position.y = 0.6;
  const cabin = new THREE.Mesh(new THREE.BoxGeometry(1.6, 0.6, CAR_LENGTH * 0.5), glass);
  cabin.position.set(0, 1.25, 0.2);
  const wheels = new THREE.MeshLambertMaterial({ color: 0x151515 });
  group.add(body, cabin);
  for (const [dx, dz] of [[-0.85, -1.6], [0.85, -1.6], [-0.85, 1.6], [0.85, 1.6]]) {
    const wheel = new THREE.Mesh(new THREE.CylinderGeometry(0.33, 0.33, 0.25, 12), wheels);
    wheel.rotation.z = Math.PI / 2;
    wheel.position.set(dx, 0.33, dz);
    group.add(wheel);
  }
  return group;
}

/** Place a car whose front bumper is at (x, y) with heading angleDeg. */
export function placeCar(mesh, x, y, angleDeg) {
  const [hx, hy] = heading(angleDeg);
  const cx = x - hx * CAR_LENGTH / 2, cy = y - hy * CAR_LENGTH / 2;
  mesh.position.set(cx, 0, -cy);
  mesh.rotation.y = (-angleDeg * Math.PI) / 180;  // local -z is forward
}

/** The driver's eye of a car whose front bumper is at (x, y). */
export function placeDriverCamera(camera, x, y, angleDeg) {
  const [hx, hy] = heading(angleDeg);
  const back = 2.3, left = 0.35, eye = 1.2;
  const ex = x - hx * back - hy * left, ey = y - hy * back + hx * left;
  camera.position.set(ex, eye, -ey);
  camera.lookAt(ex + hx * 20, eye - 0.6, -(ey + hy * 20));
}

/** The ego's bonnet, seen from the driver's seat (child of the camera). */
export function bonnet() {
  const mesh = new THREE.Mesh(new THREE.BoxGeometry(1.7, 0.1, 2.4),
    new THREE.MeshLambertMaterial({ color: 0x1d3557 }));
  mesh.position.set(0.35, -0.85, -1.4);
  return mesh;
}

export { THREE };

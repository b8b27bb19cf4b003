// A ride in the browser: the WebSocket, the pedals, the driver's-eye view.
//
// The server sends a frame per SUMO step (10 Hz); the view is drawn at the
// display's rate, one step behind, interpolating between the last two
// frames. Each key press or release is sent at once with a new input number,
// and the time from the key event to the first drawn frame that reflects it
// (the frame's "seq" has reached it) is sent back as the input-to-frame
// latency. A frame that answers a key press is drawn as it arrives, without
// waiting for the display's next frame. The server says where its part of
// that time went ("timing"); the page adds its own parts and keeps each
// measured input, part by part, in `window.studyLatency` (docs/study.md).
// Where the display's frames come slowly (software rendering), the view is
// drawn with fewer pixels.

import { bonnet, buildWorld, carMesh, placeCar, placeDriverCamera, THREE } from "./scene.js";
import { drawLane, drawPedals, drawSpeedometer, Minimap } from "./hud.js";
import { readPads, readSignalButtons } from "./pedals.js";

const PEDAL_PRESS_START = 0.3;   // a key press puts the pedal here at once
const PEDAL_RISE_PER_S = 1.2;    // holding it presses harder
const PEDAL_FALL_PER_S = 4.0;    // releasing lets go quickly
const SEND_EVERY_MS = 50;        // pedal updates while a key is held
const COUNTDOWN_S = 2;
const THROTTLE_KEYS = new Set(["ArrowUp", "KeyW"]);
const BRAKE_KEYS = new Set(["ArrowDown", "KeyS", "Space"]);
const SIGNAL_KEYS = { ArrowLeft: "left", KeyA: "left", ArrowRight: "right", KeyD: "right" };
const BLINK_MS = 400;            // the turn signal's arrow: on, off

const LATENCY_KEPT = 2000;        // measured inputs kept on the page
const RESOLUTION_EVERY = 30;      // display frames between two resolution checks
const MIN_PIXEL_RATIO = 0.5;

function lerp(a, b, t) { return a + (b - a) * t; }
function lerpAngle(a, b, t) { const d = ((b - a + 540) % 360) - 180; return a + d * t; }

/** The view shared by every ride of a participant. */
export class Cockpit {
  constructor(elements, roads) {
    this.el = elements;
    this.roads = roads;
    this.renderer = new THREE.WebGLRenderer({ canvas: elements.view, antialias: false,
      preserveDrawingBuffer: false });
    this.scene = buildWorld(roads);
    this.camera = new THREE.PerspectiveCamera(70, 1, 0.1, 900);
    this.camera.add(bonnet());
    this.scene.add(this.camera);
    this.minimap = new Minimap(elements.minimap, roads);
    this.cars = new Map();
    this.lanes = new Map(roads.lanes.map((l) => [l.id, l]));
    this.pixelRatio = this.fullRatio = Math.min(window.devicePixelRatio || 1, 2);
    this.intervals = [];
    window.addEventListener("resize", () => this.resize());
  }

  /** Fewer pixels when the display's frames come slower than 30 a second
   * (software rendering), more again when they come faster than 50. */
  adaptResolution(intervalMs) {
    this.intervals.push(intervalMs);
    if (this.intervals.length < RESOLUTION_EVERY) return;
    const sorted = this.intervals.sort((a, b) => a - b);
    const median = sorted[sorted.length >> 1];
    this.intervals = [];
    const ratio = median > 1000 / 30 ? Math.max(MIN_PIXEL_RATIO, this.pixelRatio * 0.75)
      : median < 1000 / 50 ? Math.min(this.fullRatio, this.pixelRatio / 0.75) : this.pixelRatio;
    if (ratio !== this.pixelRatio) { this.pixelRatio = ratio; this.resize(); }
  }

  resize() {
    const canvas = this.el.view;
    const w = canvas.clientWidth || window.innerWidth, h = canvas.clientHeight || window.innerHeight;
    this.renderer.setPixelRatio(this.pixelRatio);
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
  }

  /** Drive one ride; resolves with the server's summary at its end. */
  ride(info, stepS) {
    this.resize();
    this.showCars([]);  // nothing of the ride before
    return new Ride(this, info, stepS).run();
  }

  /** The waiting screen over the view until the ride is ready. */
  waiting(share) {
    const { wait, waitBar, waitText } = this.el;
    wait.hidden = share === null;
    if (share === null) return;
    waitBar.style.width = `${Math.round(share * 100)}%`;
    waitText.textContent = share > 0 ? `${Math.round(share * 100)}% ready` : "Starting the simulation\u2026";
  }

  showCars(cars) {
    const seen = new Set();
    for (const car of cars) {
      let mesh = this.cars.get(car.n);
      if (!mesh) { mesh = carMesh(car.n); this.cars.set(car.n, mesh); this.scene.add(mesh); }
      placeCar(mesh, car.x, car.y, car.angle);
      seen.add(car.n);
    }
    for (const [n, mesh] of this.cars) {
      if (!seen.has(n)) { this.scene.remove(mesh); this.cars.delete(n); }
    }
  }

  /** Before the ego enters: stand at the start of its first lane. */
  entryView(laneIds) {
    const lane = this.lanes.get(laneIds[0]);
    if (!lane) return null;
    const [a, b] = lane.shape;
    const angle = (Math.atan2(b[0] - a[0], b[1] - a[1]) * 180) / Math.PI;
    return { x: a[0], y: a[1], angle, speed: 0 };
  }
}

class Ride {
  constructor(cockpit, info, stepS) {
    this.cockpit = cockpit;
    this.info = info;
    this.periodMs = stepS * 1000;
    this.keys = new Set();
    this.keyPedals = { throttle: 0, brake: 0 };  // from the keys
    this.padPedals = { throttle: 0, brake: 0 };  // from gamepads and wheels
    this.pedals = { throttle: 0, brake: 0 };     // sent: the more pressed of the two
    this.sent = { throttle: 0, brake: 0, at: 0 };
    this.seq = -1;
    this.probe = null;       // the input whose latency is measured (see measure)
    this.prev = null; this.cur = null;
    this.started = false; this.over = false;
    this.collisions = 0; this.egoLanes = [];
    this.signalButtons = { left: false, right: false };
    this.ready = false;
  }

  run() {
    return new Promise((resolve) => {
      this.resolve = resolve;
      const proto = location.protocol === "https:" ? "wss" : "ws";
      const url = `${proto}://${location.host}/ws/rides/${encodeURIComponent(this.info.ride_id)}`
        + `?token=${encodeURIComponent(this.info.token)}`;
      this.ws = new WebSocket(url);
      this.ws.onmessage = (event) => this.onMessage(JSON.parse(event.data));
      this.ws.onclose = () => this.finish({ status: "error",
        error: this.errorText || "The connection to the server was lost." });
      this.onKey = (event) => this.key(event);
      window.addEventListener("keydown", this.onKey);
      window.addEventListener("keyup", this.onKey);
      this.status("");
      this.cockpit.waiting(0);
      this.lastTick = performance.now();
      requestAnimationFrame((t) => this.tick(t));
    });
  }

  status(text) { this.cockpit.el.status.textContent = text; }

  onMessage(m) {
    if (m.type === "frame") {
      this.prev = this.cur;
      this.cur = { f: m, at: performance.now() };
      if (this.probe && !this.probe.receivedAt && m.seq >= this.probe.seq) {
        this.probe.receivedAt = this.cur.at;
        if (this.ready) {  // drawn at once, not at the display's next frame
          this.draw(performance.now());
          this.probe.drawnAt = performance.now();
        }
        this.measureIfDone();
      }
      if (m.collisions > this.collisions) this.flashCollision();
      this.collisions = m.collisions;
    } else if (m.type === "timing") {
      if (this.probe && !this.probe.server && m.seq >= this.probe.seq) this.probe.server = m;
      this.measureIfDone();
    } else if (m.type === "preparing") {
      this.cockpit.waiting(m.done);
    } else if (m.type === "ready") {
      this.egoLanes = m.ego_lanes;
      this.cockpit.minimap.setRoute(m.ego_lanes);
      this.ready = true;
      this.cockpit.waiting(null);
      this.countdown(COUNTDOWN_S);
    } else if (m.type === "end") {
      this.finish(m);
    } else if (m.type === "error") {
      this.errorText = m.message;
    }
  }

  countdown(n) {
    if (this.over) return;
    if (n > 0) { this.status(`Starting in ${n}\u2026`); setTimeout(() => this.countdown(n - 1), 1000); return; }
    this.status("");
    this.started = true;
    this.send({ type: "start" });
  }

  send(message) {
    if (this.ws.readyState === WebSocket.OPEN) this.ws.send(JSON.stringify(message));
  }

  key(event) {
    const direction = SIGNAL_KEYS[event.code];
    if (direction) {
      event.preventDefault();
      if (event.type === "keydown" && !event.repeat) this.signal(direction);
      return;
    }
    const throttle = THROTTLE_KEYS.has(event.code), brake = BRAKE_KEYS.has(event.code);
    if (!throttle && !brake) return;
    event.preventDefault();
    if (event.repeat) return;
    if (event.type === "keydown") this.keys.add(event.code); else this.keys.delete(event.code);
    const pedal = throttle ? "throttle" : "brake";
    this.keyPedals[pedal] = event.type === "keydown" ? Math.max(this.keyPedals[pedal], PEDAL_PRESS_START) : 0;
    this.combinePedals();
    this.sendPedals(event.timeStamp);
  }

  /** The turn signal: ask the server for the lane to the `direction`. */
  signal(direction) {
    if (this.started && !this.over) this.send({ type: "lane", direction });
  }

  /** Send the pedals; `eventAt` (the key event's time) measures this input. */
  sendPedals(eventAt = null) {
    if (!this.started || this.over) return;
    this.seq += 1;
    const now = performance.now();
    this.send({ type: "input", seq: this.seq, throttle: this.pedals.throttle, brake: this.pedals.brake });
    this.sent = { throttle: this.pedals.throttle, brake: this.pedals.brake, at: now };
    if (eventAt !== null) {
      this.probe = { seq: this.seq, eventAt: Math.min(eventAt, now), sentAt: now,
        receivedAt: null, drawnAt: null, server: null };
    }
  }

  /** The input-to-frame latency of the probe, part by part (ms), once it
   * was drawn: the browser's event handling, the WebSocket both ways (with
   * the wait for the page's thread), the server's parts, the drawing. */
  measureIfDone(now = performance.now()) {
    const p = this.probe;
    if (p && p.drawnAt && (p.server || now - p.drawnAt > 1000)) this.measure();
  }

  measure() {
    const p = this.probe, drawnAt = p.drawnAt;
    const total = drawnAt - p.eventAt;
    const record = { seq: p.seq, total, event: p.sentAt - p.eventAt, draw: drawnAt - p.receivedAt };
    if (p.server) {
      const parts = ["relay_in", "wait", "sumo", "frame", "relay_out"];
      let inServer = 0;
      for (const part of parts) { record[part] = p.server[part]; inServer += p.server[part] || 0; }
      record.websocket = p.receivedAt - p.sentAt - inServer;
    }
    const kept = (window.studyLatency = window.studyLatency || []);
    if (kept.length < LATENCY_KEPT) kept.push(record);
    this.send({ type: "latency", seq: p.seq, ms: Math.min(60000, total) });
    this.probe = null;
  }

  updatePedals(dt) {
    const held = (set) => [...this.keys].some((k) => set.has(k));
    for (const [pedal, set] of [["throttle", THROTTLE_KEYS], ["brake", BRAKE_KEYS]]) {
      const v = this.keyPedals[pedal];
      this.keyPedals[pedal] = held(set) ? Math.min(1, Math.max(v, PEDAL_PRESS_START) + PEDAL_RISE_PER_S * dt)
        : Math.max(0, v - PEDAL_FALL_PER_S * dt);
    }
    this.padPedals = readPads();  // pedals.js
    const buttons = readSignalButtons();
    for (const direction of ["left", "right"]) {
      if (buttons[direction] && !this.signalButtons[direction]) this.signal(direction);
    }
    this.signalButtons = buttons;
    this.combinePedals();
    const moved = Math.abs(this.pedals.throttle - this.sent.throttle) > 0.02
      || Math.abs(this.pedals.brake - this.sent.brake) > 0.02;
    if (moved && performance.now() - this.sent.at >= SEND_EVERY_MS) this.sendPedals();
  }

  combinePedals() {
    for (const pedal of ["throttle", "brake"]) {
      this.pedals[pedal] = Math.max(this.keyPedals[pedal], this.padPedals[pedal]);
    }
  }

  /** The cars and the ego at the display's time, one step behind the last frame. */
  interpolated(now) {
    const cur = this.cur.f;
    const t = this.prev ? Math.min(1, (now - this.cur.at) / this.periodMs) : 1;
    const before = new Map();
    const prev = this.prev ? this.prev.f : cur;
    for (let i = 0; i < prev.cars.length; i += 4) before.set(prev.cars[i], i);
    const cars = [];
    for (let i = 0; i < cur.cars.length; i += 4) {
      const n = cur.cars[i], j = before.get(n);
      const [x, y, a] = [cur.cars[i + 1], cur.cars[i + 2], cur.cars[i + 3]];
      if (j === undefined) { cars.push({ n, x, y, angle: a }); continue; }
      cars.push({ n, x: lerp(prev.cars[j + 1], x, t), y: lerp(prev.cars[j + 2], y, t),
        angle: lerpAngle(prev.cars[j + 3], a, t) });
    }
    let ego = null;
    if (cur.ego) {
      const [x, y, a, v] = cur.ego;
      ego = { x, y, angle: a, speed: v };
      if (prev.ego) {
        const [px, py, pa, pv] = prev.ego;
        ego = { x: lerp(px, x, t), y: lerp(py, y, t), angle: lerpAngle(pa, a, t), speed: lerp(pv, v, t) };
      }
    }
    return { cars, ego };
  }

  tick(now) {
    if (this.over) return;
    const dt = Math.min(0.1, (now - this.lastTick) / 1000);
    this.lastTick = now;
    this.updatePedals(dt);
    if (this.ready) {  // else the waiting screen covers the view
      this.cockpit.adaptResolution(dt * 1000);
      this.draw(now);
      if (this.probe && this.probe.receivedAt && !this.probe.drawnAt) this.probe.drawnAt = performance.now();
      this.measureIfDone(now);
    }
    requestAnimationFrame((t) => this.tick(t));
  }

  /** Draw the view, the dashboard and the map as of `now`. */
  draw(now) {
    const c = this.cockpit;
    let cars = [], ego = null;
    if (this.cur) ({ cars, ego } = this.interpolated(now));
    c.showCars(cars);
    const view = ego || c.entryView(this.egoLanes);  // before each pass: at the entry
    if (view) placeDriverCamera(c.camera, view.x, view.y, view.angle);
    c.renderer.render(c.scene, c.camera);
    drawSpeedometer(c.el.speedometer, ego ? ego.speed : 0);
    drawPedals(c.el.throttleBar, c.el.brakeBar, this.pedals.throttle, this.pedals.brake);
    c.minimap.draw(cars, ego);
    drawLane(c.el.lane, this.cur && ego ? this.cur.f.lane : null, now % (2 * BLINK_MS) < BLINK_MS);
    if (this.started && this.cur) {
      const f = this.cur.f;
      const left = Math.max(0, this.info.ride_s - (f.step + 1) * this.periodMs / 1000);
      const pass = f.passes > 1 ? `Pass ${f.pass} of ${f.passes}: ` : "";
      this.status(ego ? `${pass}${Math.ceil(left)} s left` : `${pass}entering the road\u2026`);
    }
  }

  flashCollision() {
    const flash = this.cockpit.el.collision;
    flash.hidden = false;
    clearTimeout(this.flashTimer);
    this.flashTimer = setTimeout(() => { flash.hidden = true; }, 1500);
  }

  finish(summary) {
    if (this.over) return;
    this.over = true;
    window.removeEventListener("keydown", this.onKey);
    window.removeEventListener("keyup", this.onKey);
    this.ws.onclose = null;
    this.cockpit.waiting(null);
    if (this.ws.readyState === WebSocket.OPEN) this.ws.close(1000);
    this.resolve(summary);
  }
}

// The dashboard over the view: speedometer, pedal bars, a top-down map.

const MAX_KMH = 80;

/** A round speedometer, 0-80 km/h, with the speed written in its middle. */
export function drawSpeedometer(canvas, speedMps) {
  const ctx = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height, cx = w / 2, cy = h / 2, r = w / 2 - 8;
  const kmh = Math.max(0, speedMps * 3.6);
  ctx.clearRect(0, 0, w, h);
  ctx.fillStyle = "rgba(15, 20, 28, 0.78)";
  ctx.beginPath(); ctx.arc(cx, cy, r + 6, 0, 2 * Math.PI); ctx.fill();
  const start = 0.75 * Math.PI, sweep = 1.5 * Math.PI;
  ctx.strokeStyle = "#d8dde3"; ctx.lineWidth = 2; ctx.fillStyle = "#d8dde3";
  ctx.font = "12px sans-serif"; ctx.textAlign = "center"; ctx.textBaseline = "middle";
  for (let v = 0; v <= MAX_KMH; v += 10) {
    const a = start + sweep * v / MAX_KMH;
    ctx.beginPath();
    ctx.moveTo(cx + Math.cos(a) * (r - 10), cy + Math.sin(a) * (r - 10));
    ctx.lineTo(cx + Math.cos(a) * r, cy + Math.sin(a) * r);
    ctx.stroke();
    ctx.fillText(String(v), cx + Math.cos(a) * (r - 24), cy + Math.sin(a) * (r - 24));
  }
  const a = start + sweep * Math.min(kmh, MAX_KMH) / MAX_KMH;
  ctx.strokeStyle = "#ff5a36"; ctx.lineWidth = 4;
  ctx.beginPath(); ctx.moveTo(cx, cy);
  ctx.lineTo(cx + Math.cos(a) * (r - 14), cy + Math.sin(a) * (r - 14)); ctx.stroke();
  ctx.fillStyle = "#ffffff"; ctx.font = "bold 26px sans-serif";
  ctx.fillText(String(Math.round(kmh)), cx, cy + 34);
  ctx.font = "11px sans-serif"; ctx.fillText("km/h", cx, cy + 54);
}

/** Pedal bars: the height of each bar is the pedal's position. */
export function drawPedals(throttleBar, brakeBar, throttle, brake) {
  throttleBar.style.height = `${Math.round(throttle * 100)}%`;
  brakeBar.style.height = `${Math.round(brake * 100)}%`;
}

/** The lane indicator on two-lane roads: the ego's lane of the road's
 *  lanes (from the right), the turn signal's arrow and, where the lane ends
 *  before the route's next road, the side to move to. `lane` is a frame's
 *  [index, lanes, signal, route side], or null (inside a junction). */
export function drawLane(el, lane, blinkOn) {
  if (!lane || lane[1] < 2) { el.box.hidden = true; return; }
  const [index, lanes, signal, side] = lane;
  el.box.hidden = false;
  el.text.textContent = `lane ${index + 1} of ${lanes}`;
  el.left.classList.toggle("on", signal > 0 && blinkOn);
  el.right.classList.toggle("on", signal < 0 && blinkOn);
  el.hint.textContent = side < 0 ? "your exit: move right" : side > 0 ? "your route: move left" : "";
}

/** A north-up map of the lanes, the ego's route, the cars and the ego. */
export class Minimap {
  constructor(canvas, roads) {
    this.canvas = canvas;
    this.roads = roads;
    const [x0, y0, x1, y1] = roads.bounds;
    const span = Math.max(x1 - x0, y1 - y0) * 1.08;
    this.scale = canvas.width / span;
    this.cx = (x0 + x1) / 2; this.cy = (y0 + y1) / 2;
    this.route = new Set();
  }

  toCanvas(x, y) {
    const w = this.canvas.width;
    return [w / 2 + (x - this.cx) * this.scale, w / 2 - (y - this.cy) * this.scale];
  }

  setRoute(laneIds) { this.route = new Set(laneIds); }

  draw(cars, ego) {
    const ctx = this.canvas.getContext("2d");
    const w = this.canvas.width;
    ctx.clearRect(0, 0, w, w);
    ctx.fillStyle = "rgba(15, 20, 28, 0.72)";
    ctx.fillRect(0, 0, w, w);
    ctx.lineCap = "round";
    for (const lane of this.roads.lanes) {
      const onRoute = this.route.has(lane.id);
      ctx.strokeStyle = onRoute ? "#4da3ff" : "#9aa3ad";
      ctx.lineWidth = Math.max(2, lane.width * this.scale * (onRoute ? 0.9 : 0.7));
      ctx.beginPath();
      lane.shape.forEach(([x, y], i) => {
        const [px, py] = this.toCanvas(x, y);
        if (i === 0) ctx.moveTo(px, py); else ctx.lineTo(px, py);
      });
      ctx.stroke();
    }
    ctx.fillStyle = "#f2f2f2";
    for (const car of cars) {
      const [px, py] = this.toCanvas(car.x, car.y);
      ctx.beginPath(); ctx.arc(px, py, 3, 0, 2 * Math.PI); ctx.fill();
    }
    if (ego) {
      const [px, py] = this.toCanvas(ego.x, ego.y);
      ctx.fillStyle = "#ff5a36";
      ctx.beginPath(); ctx.arc(px, py, 4.5, 0, 2 * Math.PI); ctx.fill();
    }
  }
}

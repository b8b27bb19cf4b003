// Pedals from gamepads and wheels.
//
// A pad's pedals are read from, in this order: the set-up the participant
// ran in this browser (localStorage, per gamepad id), the study's default
// for that id (`jaxround study serve --pedal-map`), or, for a pad with the
// browser's standard mapping, its triggers (7 throttle, 6 brake). A pedal
// is an axis or a button with a resting and a pressed value; its position
// is 0 at rest and 1 pressed fully, whichever way the raw value runs.

const STORE = "jaxround-pedals";
export const PEDALS = ["throttle", "brake"];
const DEADZONE = 0.03;          // pedal positions below this are released
const STANDARD = {
  throttle: { kind: "button", index: 7, rest: 0, pressed: 1 },
  brake: { kind: "button", index: 6, rest: 0, pressed: 1 },
};

let studyDefaults = {};
const movedAxes = new Set();    // `${pad.id}/${index}`: axes seen away from 0

/** The study's set-ups per gamepad id (from `/api/study`). */
export function setStudyDefaults(map) { studyDefaults = map || {}; }

export function savedSetups() {
  try { return JSON.parse(localStorage.getItem(STORE) || "{}") || {}; } catch { return {}; }
}

export function saveSetup(id, setup) {
  const all = savedSetups();
  all[id] = setup;
  localStorage.setItem(STORE, JSON.stringify(all));
}

export function resetSetup(id) {
  const all = savedSetups();
  delete all[id];
  localStorage.setItem(STORE, JSON.stringify(all));
}

/** Where a pad's pedals come from: {source: "saved" | "study" | "standard" | null, setup}. */
export function setupOf(pad) {
  const saved = savedSetups()[pad.id];
  if (saved) return { source: "saved", setup: saved };
  if (studyDefaults[pad.id]) return { source: "study", setup: studyDefaults[pad.id] };
  if (pad.mapping === "standard") return { source: "standard", setup: STANDARD };
  return { source: null, setup: null };
}

export function connectedPads() {
  const pads = navigator.getGamepads ? navigator.getGamepads() : [];
  return [...pads].filter((pad) => pad && pad.connected !== false);
}

function rawValue(pad, input) {
  const raw = input.kind === "axis" ? pad.axes[input.index] : pad.buttons[input.index]?.value;
  return typeof raw === "number" && Number.isFinite(raw) ? raw : null;
}

/** A pedal's position, 0 (released) to 1 (pressed fully). */
export function pedalPosition(pad, input) {
  const raw = rawValue(pad, input);
  if (raw === null) return 0;
  const key = `${pad.id}/${input.index}`;
  if (input.kind === "axis" && raw !== 0) movedAxes.add(key);
  // Some browsers report a wheel's axis as 0 until it first moves: a pedal
  // that rests at +1 or -1 is released then, not half pressed.
  if (input.kind === "axis" && raw === 0 && Math.abs(input.rest) > 0.5 && !movedAxes.has(key)) return 0;
  const x = (raw - input.rest) / (input.pressed - input.rest);
  return x < DEADZONE ? 0 : Math.min(1, x);
}

/** The pedals of the connected pads: {throttle, brake}, the most pressed of each. */
export function readPads(pads = connectedPads()) {
  const out = { throttle: 0, brake: 0 };
  for (const pad of pads) {
    const { setup } = setupOf(pad);
    if (!setup) continue;
    for (const pedal of PEDALS) {
      if (setup[pedal]) out[pedal] = Math.max(out[pedal], pedalPosition(pad, setup[pedal]));
    }
  }
  return out;
}

/** The turn-signal buttons of the connected pads with the standard mapping
 *  (4: left shoulder, 5: right shoulder): {left, right}, pressed or not. */
export function readSignalButtons(pads = connectedPads()) {
  const out = { left: false, right: false };
  for (const pad of pads) {
    if (pad.mapping !== "standard") continue;
    out.left = out.left || Boolean(pad.buttons[4]?.pressed);
    out.right = out.right || Boolean(pad.buttons[5]?.pressed);
  }
  return out;
}

export function describeInput(input) {
  const r = (x) => x.toFixed(2);
  return `${input.kind} ${input.index} (rest ${r(input.rest)}, pressed ${r(input.pressed)})`;
}

// ---------------------------------------------------------------- set-up

const MIN_SWING = 0.5;      // an input must move this much to count
const BACK_WITHIN = 0.1;    // at a value: within this share of the swing
const STILL = 0.03;         // moves smaller than this leave an input still
const SETTLE_MS = 400;      // released: still for this long

/** The values an input took: the first, the lowest and the highest. */
class Span {
  constructor(v) { Object.assign(this, { first: v, lo: v, hi: v }); }
  add(v) { this.lo = Math.min(this.lo, v); this.hi = Math.max(this.hi, v); }
  get swing() { return this.hi - this.lo; }
  near(v, x) { return Math.abs(v - x) <= BACK_WITHIN * this.swing; }
  /** The end of the span farther from `v`. */
  far(v) { return v - this.lo > this.hi - v ? this.lo : this.hi; }
}

/** One axis or button watched during a set-up step.
 *
 *  Pressed and released: it moved at least MIN_SWING and is still again,
 *  back where it started (rest there, pressed at the far end). An axis that
 *  reads 0 until it first moves (some browsers) starts at 0 without resting
 *  there; from its first other value on, it is released when it is still at
 *  one end of its span and went beyond that first value towards the other end
 *  (a press and a release: a pedal pressed and held is still at the end it
 *  moved to, with its first value at the other). */
class Trace {
  constructor(v, t) {
    this.all = new Span(v);
    this.moved = v === 0 ? null : this.all;
    Object.assign(this, { v, still: v, since: t });
  }

  add(v, t) {
    this.v = v;
    this.all.add(v);
    if (this.moved) this.moved.add(v); else if (v !== 0) this.moved = new Span(v);
    if (Math.abs(v - this.still) > STILL) Object.assign(this, { still: v, since: t });
  }

  /** {rest, pressed, swing} once pressed and released, else null. */
  result(t) {
    if (t - this.since < SETTLE_MS) return null;
    const pressed = backAtFirst(this.all, this.v) ?? pressedAndReleased(this.moved, this.v);
    if (pressed === null) return null;
    const round = (x) => Math.round(x * 1000) / 1000;
    return { rest: round(this.v), pressed: round(pressed), swing: Math.abs(this.v - pressed) };
  }
}

/** The pressed value of a span that is back at its first value `v`, or null. */
function backAtFirst(span, v) {
  return span.swing >= MIN_SWING && span.near(v, span.first) ? span.far(v) : null;
}

/** The pressed value of a span still at one end `v` after it went beyond its
 *  first value towards the other end, or null. */
function pressedAndReleased(span, v) {
  if (!span || span.swing < MIN_SWING) return null;
  const pressed = span.far(v), released = span.far(pressed);
  return span.near(v, released) && !span.near(pressed, span.first) ? pressed : null;
}

/** Finds the input that was pressed fully and released: the one that moved
 *  the most. `taken` ({id, input}) are not caught again in the same direction. */
export class PedalCatcher {
  constructor(taken = []) {
    this.traces = new Map();
    this.taken = taken;
  }

  /** Add a sample of every pad; the caught {id, input}, or null. */
  sample(pads, t) {
    for (const pad of pads) {
      pad.axes.forEach((v, i) => this.add(pad.id, "axis", i, v, t));
      pad.buttons.forEach((b, i) => this.add(pad.id, "button", i, b.value, t));
    }
    let best = null;
    for (const { id, kind, index, trace } of this.traces.values()) {
      const r = trace.result(t);
      if (!r || (best && best.swing >= r.swing)) continue;
      const input = { kind, index, rest: r.rest, pressed: r.pressed };
      if (!this.isTaken(id, input)) best = { id, input, swing: r.swing };
    }
    return best && { id: best.id, input: best.input };
  }

  add(id, kind, index, v, t) {
    if (typeof v !== "number" || !Number.isFinite(v)) return;
    const key = `${id}|${kind}|${index}`;
    const entry = this.traces.get(key);
    if (entry) entry.trace.add(v, t);
    else this.traces.set(key, { id, kind, index, trace: new Trace(v, t) });
  }

  isTaken(id, input) {
    const sign = Math.sign(input.pressed - input.rest);
    return this.taken.some((c) => c.id === id && c.input.kind === input.kind
      && c.input.index === input.index && Math.sign(c.input.pressed - c.input.rest) === sign);
  }
}

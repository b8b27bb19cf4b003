// The pedal set-up on the page before each drive: which gamepads are
// connected and how their pedals are read, a two-step set-up (press the
// throttle fully and release it, then the brake) and a reset.

import {
  connectedPads, describeInput, PedalCatcher, pedalPosition, PEDALS, resetSetup, savedSetups,
  saveSetup, setupOf,
} from "./pedals.js";

const POLL_MS = 300;
const INSTRUCTIONS = {
  throttle: "Press the throttle (accelerator) pedal fully, then release it.",
  brake: "Now press the brake pedal fully, then release it.",
};

function padName(pad) { return pad.id.replace(/\s*\(.*\)\s*$/, "") || `gamepad ${pad.index}`; }

function padLine(pad) {
  const { source, setup } = setupOf(pad);
  const name = padName(pad);
  if (source === "standard") return `${name}: right trigger accelerates, left trigger brakes.`;
  if (source === null) return `${name}: its pedals are not set up. Set them up before you drive.`;
  const used = PEDALS.filter((p) => setup[p]);
  const by = source === "saved" ? "set up in this browser" : "set up by the study";
  const inputs = used.map((p) => `${p} ${describeInput(setup[p])}`).join(", ");
  const now = used.map((p) => `${p} ${Math.round(pedalPosition(pad, setup[p]) * 100)}%`).join(", ");
  return `${name}: pedals ${by}: ${inputs}. Now: ${now}.`;
}

/** The pedal box of the intro page. `el`: box, status, setup, reset, wizard,
 *  step, cancel, note, json; `onBusy(busy)` is told when a set-up starts and ends. */
export class PedalPanel {
  constructor(el, onBusy) {
    this.el = el;
    this.onBusy = onBusy;
    this.run = null;
    el.setup.onclick = () => this.begin();
    el.reset.onclick = () => this.reset();
    el.cancel.onclick = () => this.end("The set-up was cancelled; nothing was changed.");
  }

  /** Watch for pads while the intro page shows. */
  start() {
    this.refresh();
    clearInterval(this.timer);
    this.timer = setInterval(() => this.refresh(), POLL_MS);
  }

  stop() {
    clearInterval(this.timer);
    if (this.run) this.end("");
  }

  refresh() {
    const pads = connectedPads(), el = this.el;
    el.box.hidden = pads.length === 0 && !this.run;
    el.status.replaceChildren(...pads.map((pad) => {
      const line = document.createElement("div");
      line.textContent = padLine(pad);
      line.className = setupOf(pad).source === null ? "error" : "";
      return line;
    }));
    const saved = savedSetups();
    const mine = Object.fromEntries(pads.filter((pad) => saved[pad.id]).map((pad) => [pad.id, saved[pad.id]]));
    el.reset.hidden = Object.keys(mine).length === 0 || Boolean(this.run);
    el.setup.hidden = Boolean(this.run);
    el.json.parentElement.hidden = el.reset.hidden;
    el.json.textContent = JSON.stringify(mine, null, 1);
  }

  begin() {
    this.run = { pedal: 0, found: [], catcher: new PedalCatcher() };
    this.el.wizard.hidden = false;
    this.el.note.textContent = "";
    this.onBusy(true);
    this.instruct();
    this.refresh();
    requestAnimationFrame((t) => this.watch(t));
  }

  instruct() { this.el.step.textContent = INSTRUCTIONS[PEDALS[this.run.pedal]]; }

  watch(t) {
    const run = this.run;
    if (!run) return;
    const caught = run.catcher.sample(connectedPads(), t);
    if (caught) {
      run.found.push({ pedal: PEDALS[run.pedal], ...caught });
      run.pedal += 1;
      if (run.pedal === PEDALS.length) return this.save(run.found);
      run.catcher = new PedalCatcher(run.found);
      this.instruct();
    }
    requestAnimationFrame((next) => this.watch(next));
  }

  /** Store the set-up per gamepad id (replacing what those pads had). */
  save(found) {
    const setups = {};
    for (const { pedal, id, input } of found) (setups[id] ||= {})[pedal] = input;
    for (const [id, setup] of Object.entries(setups)) saveSetup(id, setup);
    this.end("Pedals set up.");
  }

  reset() {
    for (const pad of connectedPads()) resetSetup(pad.id);
    this.el.note.textContent = "The pedal set-up of this browser was removed.";
    this.refresh();
  }

  end(message) {
    this.run = null;
    this.el.wizard.hidden = true;
    this.el.note.textContent = message;
    this.onBusy(false);
    this.refresh();
  }
}

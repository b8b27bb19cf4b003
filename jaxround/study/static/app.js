// The study's pages in order: consent, about you, practice, two rides,
// three questions, thanks. Where the participant is stays in sessionStorage,
// so a reload comes back to the same page (a ride cut short starts anew).

import { Cockpit } from "./drive.js";
import { PedalPanel } from "./pedal-setup.js";
import { setStudyDefaults } from "./pedals.js";

const STORE = "jaxround-study";
const $ = (id) => document.getElementById(id);
let state = JSON.parse(sessionStorage.getItem(STORE) || "null") || { step: "consent" };
let study = null, roads = null, cockpit = null, pedalPanel = null;

function save() { sessionStorage.setItem(STORE, JSON.stringify(state)); }

function show(page) {
  for (const section of document.querySelectorAll(".page")) section.hidden = section.id !== `page-${page}`;
  if (page === "intro") pedalPanel.start(); else pedalPanel.stop();
}

async function api(method, path, body) {
  const response = await fetch(path, {
    method, headers: { "Content-Type": "application/json" },
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  let data = null;
  try { data = await response.json(); } catch { data = null; }
  return { status: response.status, data };
}

function problem(result) {
  const detail = result.data && result.data.detail;
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail)) return detail.map((d) => `${(d.loc || []).join(".")}: ${d.msg}`).join("; ");
  return `the server answered ${result.status}`;
}

function go(step) { state.step = step; save(); render(); }

const RIDES = {
  practice: { title: "Practice drive", next: "first-intro" },
  first: { title: "Ride 1 of 2", next: "second-intro" },
  second: { title: "Ride 2 of 2", next: "survey" },
};

function render() {
  const step = state.step;
  if (step === "consent") return show("consent");
  if (step === "demographics") return show("demographics");
  if (step.endsWith("-intro")) return intro(step.slice(0, -"-intro".length));
  if (step === "survey") return survey();
  if (step === "thanks") return show("thanks");
  return show("consent");
}

function intro(kind) {
  $("intro-title").textContent = RIDES[kind].title;
  const exit = "enter from the east, go round the ring and take the third exit (a left turn)";
  const passes = (n) => (n === 1 ? "once" : `${n} times: after each exit you start again at the entry`);
  $("intro-text").textContent = kind === "practice"
    ? `A practice drive on the empty roundabout: ${exit}, ${passes(study.practice_passes)}. `
      + `It ends after that, or after ${study.practice_s} s.`
    : `This ride is ${state.labels[kind]}. Drive as you would in real traffic: ${exit}, `
      + `${passes(study.passes)}. It ends after that, or after ${study.ride_s} s.`;
  $("intro-error").textContent = "";
  $("intro-go").disabled = false;
  $("intro-go").onclick = () => drive(kind);
  show("intro");
}

async function drive(kind) {
  $("intro-go").disabled = true;
  const result = await api("POST", "/api/rides", { participant_id: state.participant_id, kind });
  if (result.status === 503) {
    $("busy-message").textContent = result.data.detail;
    $("busy-retry").onclick = () => render();
    return show("busy");
  }
  if (result.status !== 201) {
    $("intro-error").textContent = problem(result);
    $("intro-go").disabled = false;
    return;
  }
  if (!roads) roads = (await api("GET", "/api/roads")).data;
  show("drive");
  if (!cockpit) {
    cockpit = new Cockpit({
      view: $("view"), speedometer: $("speedometer"), minimap: $("minimap"),
      throttleBar: $("pedal-throttle"), brakeBar: $("pedal-brake"),
      status: $("drive-status"), collision: $("collision-flash"),
      wait: $("drive-wait"), waitBar: $("drive-wait-bar"), waitText: $("drive-wait-text"),
      lane: { box: $("lane-box"), text: $("lane-text"), left: $("lane-left"),
        right: $("lane-right"), hint: $("lane-hint") },
    }, roads);
  }
  $("drive-label").textContent = kind === "practice" ? "Practice" : `${RIDES[kind].title}: ${result.data.label}`;
  $("drive-end").hidden = true;
  const summary = await cockpit.ride(result.data, study.step_s);
  const completed = summary.status === "arrived" || summary.status === "time_limit";
  const lines = [];
  if (summary.crossing_time_s !== null && summary.passes) {
    const each = summary.passes === 1 ? "" : ` ${summary.passes} times, ${summary.crossing_time_s.toFixed(1)} s each on average`;
    lines.push(summary.passes === 1 ? `You crossed the roundabout in ${summary.crossing_time_s.toFixed(1)} s.`
      : `You crossed the roundabout${each}.`);
  }
  if (summary.status === "time_limit") lines.push("The ride reached its time limit.");
  if (summary.collisions) lines.push(`Collisions: ${summary.collisions}.`);
  if (!completed) lines.push(`The ride did not complete (${summary.error || summary.status}). You can drive it again.`);
  $("drive-end-text").textContent = lines.join(" ");
  $("drive-end").hidden = false;
  $("drive-end-go").onclick = () => { $("drive-end").hidden = true; go(completed ? RIDES[kind].next : `${kind}-intro`); };
}

function survey() {
  const index = state.question || 0;
  if (index >= study.questions.length) return finish();
  const question = study.questions[index];
  $("survey-number").textContent = String(index + 1);
  $("survey-heading").textContent = question.heading;
  const form = $("survey-options");
  form.replaceChildren(...question.options.map((text, i) => {
    const label = document.createElement("label");
    label.className = "option";
    const input = document.createElement("input");
    Object.assign(input, { type: "radio", name: "option", value: String(i), id: `option-${i}` });
    input.onchange = () => { $("survey-go").disabled = false; };
    label.append(input, ` ${text}`);
    return label;
  }));
  $("survey-error").textContent = "";
  $("survey-go").disabled = true;
  $("survey-go").onclick = async () => {
    const chosen = form.querySelector("input[name=option]:checked");
    if (!chosen) return;
    $("survey-go").disabled = true;
    const result = await api("POST", `/api/participants/${state.participant_id}/answers`,
      { question: question.id, option: Number(chosen.value) });
    const answeredBefore = result.status === 409 && /answered already/.test(problem(result));
    if (result.status !== 201 && !answeredBefore) {
      $("survey-error").textContent = problem(result);
      $("survey-go").disabled = false;
      return;
    }
    state.question = index + 1; save(); survey();
  };
  show("survey");
}

async function finish() {
  const result = await api("POST", `/api/participants/${state.participant_id}/finish`);
  if (result.status !== 200) {
    $("survey-error").textContent = problem(result);
    return show("survey");
  }
  go("thanks");
}

async function main() {
  study = (await api("GET", "/api/study")).data;
  setStudyDefaults(study.pedal_map);
  $("consent-minutes").textContent = String(study.estimate_min);
  $("lane-keys").hidden = !study.lane_changes;
  pedalPanel = new PedalPanel({
    box: $("pedal-box"), status: $("pedal-status"), setup: $("pedal-setup"), reset: $("pedal-reset"),
    wizard: $("pedal-wizard"), step: $("pedal-step"), cancel: $("pedal-cancel"), note: $("pedal-note"),
    json: $("pedal-json"),
  }, (busy) => { $("intro-go").disabled = busy; });
  $("consent-box").onchange = () => { $("consent-go").disabled = !$("consent-box").checked; };
  $("consent-go").onclick = async () => {
    $("consent-go").disabled = true;
    const result = await api("POST", "/api/participants", { consent: true });
    if (result.status !== 201) { $("consent-go").disabled = false; return; }
    Object.assign(state, { participant_id: result.data.participant_id, labels: result.data.labels });
    go("demographics");
  };
  $("demo-go").onclick = async () => {
    const number = (id) => ($(id).value === "" ? null : Number($(id).value));
    const body = { gender: $("demo-gender").value || null, age: number("demo-age"),
      driving_years: number("demo-years") };
    const result = await api("POST", `/api/participants/${state.participant_id}/demographics`, body);
    if (result.status !== 200) { $("demo-error").textContent = problem(result); return; }
    go("practice-intro");
  };
  if (state.step === "consent" && study.places_free <= 0) {
    const n = study.max_participants;
    $("busy-message").textContent = n === 1 ? "The study's driving place is taken."
      : `All ${n} driving places are taken.`;
    $("busy-retry").onclick = () => location.reload();
    return show("busy");
  }
  render();
}

main();

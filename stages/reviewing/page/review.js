// mlnseq review: the recordings, one recording's channels and phases (uPlot), a frame explained, labels edited and
// saved. Everything comes from the server that served this page (/api/...); nothing is fetched from elsewhere.
"use strict";

const COLORS = ["#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#76b7b2", "#edc948", "#b07aa1", "#ff9da7", "#9c755f",
  "#bab0ac"];
const ROWS = { model: [2, 20], differ: [24, 32], labels: [36, 62], audit: [66, 76] };  // the bands' rows, in CSS px
const state = { meta: null, index: null, data: null, plots: [], edit: [], undo: [], boundary: null, segment: null,
  frame: null, drag: null, drawnMs: null, explained: null, saved: null, shown: null, syncing: false };
window.review = state;  // what the page holds, for a reader of the page (and its tests)

async function getJSON(url, options) {
  const reply = await fetch(url, options);
  const body = await reply.json();
  if (!reply.ok) throw new Error(body.error || reply.statusText);
  return body;
}

function status(text) { document.getElementById("status").textContent = text; }
function color(k) { return k < 0 ? "#ffffff" : COLORS[k % COLORS.length]; }
function cell(row, text) { const td = document.createElement("td"); td.textContent = text; row.append(td); return td; }

async function start() {
  state.meta = await getJSON("/api/recordings");
  const m = state.meta;
  document.getElementById("model").textContent = `${m.model} + ${m.decoder} · saves to ${m.save} (${m.unit})`;
  const legend = document.getElementById("legend");
  m.classes.forEach((name, k) => {
    const span = document.createElement("span");
    const swatch = document.createElement("i");
    swatch.style.background = color(k);
    span.append(swatch, `${k + 1} ${name}`);
    legend.append(span);
  });
  state.shown = new Set(m.features);
  table();
  if (m.recordings.length) await open(m.recordings[0].index);
}

function table() {
  const body = document.querySelector("#recordings tbody");
  body.textContent = "";
  for (const r of state.meta.recordings) {
    const row = document.createElement("tr");
    row.dataset.index = r.index;
    row.title = r.reason + (r.verdict ? ` · audit: ${r.verdict}${r.why ? `, ${r.why}` : ""}` : "");
    row.classList.toggle("current", r.index === state.index);
    row.classList.toggle("suspect", r.verdict === "suspect");
    for (const text of [r.rank, r.id, r.frames, r.seconds.toFixed(1), `${(100 * r.confidence).toFixed(0)}%`,
      labelsCell(r), auditCell(r)]) cell(row, text);
    row.addEventListener("click", () => open(r.index));
    body.append(row);
  }
}

const ORIGINS = { "its own": "own", "the labels file's": "file", "estimated between your clicks": "clicks",
  "estimated by alignment": "aligned" };

function labelsCell(r) {  // what the table says of a recording's labels
  if (r.unsaved) return "not saved";
  if (r.saved) return "saved";
  if (!r.labelled) return "–";
  return ORIGINS[r.origin] || "yes";
}

function reasons() {  // the audit's verdict and reasons in words, each where it happens (marked on the audit row)
  const box = document.getElementById("audit"), audit = state.data.audit;
  box.textContent = "";
  if (!audit) { box.textContent = "audit: none (the model file holds no audit profile)"; return; }
  const head = document.createElement("span");
  head.className = audit.verdict;
  head.textContent = `audit: ${audit.verdict}, score ${audit.score.toFixed(2)} (suspect from 1)`;
  box.append(head);
  const list = document.createElement("ol");
  for (const r of audit.reasons) {
    const item = document.createElement("li");
    item.className = r.severity >= 1 ? "suspect" : "ok";
    item.textContent = `${r.reason} · ${r.phase}, ${r.where} · severity ${r.severity.toFixed(2)}`;
    list.append(item);
  }
  box.append(list);
}

function auditCell(r) {  // the audit's score, flagged where suspect (suspect from 1)
  if (!r.verdict) return "–";
  return (r.verdict === "suspect" ? "\u2691 " : "") + r.score.toFixed(2);
}

function niceStep(span) {  // 1, 2 or 5 times a power of ten, about a third of ``span``
  const raw = span / 3, power = 10 ** Math.floor(Math.log10(raw)), unit = raw / power;
  return power * (unit < 1.5 ? 1 : unit < 3.5 ? 2 : 5);
}

function splits(u, axis, min, max) {  // every axis gets two ticks or more, whatever its range
  if (!(max > min)) return [min];
  const step = niceStep(max - min), ticks = [];
  for (let t = Math.ceil(min / step) * step; t <= max + step * 1e-9; t += step) ticks.push(+t.toPrecision(12));
  return ticks.length >= 2 ? ticks : [min, max];
}

function choices() {
  const box = document.getElementById("channel-choice");
  box.textContent = "";
  for (const name of state.meta.features) {
    const label = document.createElement("label");
    const input = document.createElement("input");
    input.type = "checkbox";
    input.checked = state.shown.has(name);
    input.addEventListener("change", () => {
      if (input.checked) state.shown.add(name); else state.shown.delete(name);
      draw();
    });
    label.title = name;
    label.append(input, " ", name);
    box.append(label);
  }
}

async function open(index) {
  const started = performance.now();
  state.drawnMs = null;
  status("loading…");
  const data = await getJSON(`/api/recording?index=${index}`);
  Object.assign(state, { index, data, undo: [], boundary: null, segment: null, frame: null, explained: null });
  state.edit = (data.saved || data.proposal || data.labels || data.phases).map((s) => s.slice());
  const from = data.saved ? "the saved labels" : data.proposal ? "fit's proposal" : data.labels ?
    "the recording's labels" : "the model's phases";
  document.getElementById("labels-from").textContent = `the labels band starts from ${from}` +
    (data.origin ? ` · the labels fit trained on: ${data.origin}` : "");
  table();
  reasons();
  choices();
  draw();
  await new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)));
  state.drawnMs = performance.now() - started;
  status(`${data.id}: ${data.time.length} frames, ${state.plots.length - 1} channels drawn in ` +
    `${state.drawnMs.toFixed(0)} ms`);
}

function frameAt(t) {  // the frame nearest time t
  const time = state.data.time;
  let lo = 0, hi = time.length - 1;
  while (lo < hi) {
    const mid = (lo + hi) >> 1;
    if (time[mid] < t) lo = mid + 1; else hi = mid;
  }
  return lo > 0 && t - time[lo - 1] < time[lo] - t ? lo - 1 : lo;
}

function plotOptions(title, width, height, extra) {
  return Object.assign({
    title, width, height, legend: { show: false },
    cursor: { sync: { key: "review" }, drag: { x: true, y: false } },
    scales: { x: { time: false } },
    axes: [{ size: 28, splits }, { size: 56, splits }],
    hooks: { setScale: [(u, key) => key === "x" && follow(u)] },
  }, extra || {});
}

function follow(source) {  // one time axis: a zoom in one plot zooms them all, and the bands
  if (state.syncing) return;
  state.syncing = true;
  const { min, max } = source.scales.x;
  for (const u of state.plots) if (u !== source) u.setScale("x", { min, max });
  state.syncing = false;
  bands();
}

function draw() {
  for (const u of state.plots) u.destroy();
  state.plots = [];
  const data = state.data, time = data.time;
  const width = document.getElementById("view").clientWidth;
  const pick = (rows) => rows.map((r) => time[r]);
  const phases = new uPlot(plotOptions("probability of the decided class", width, 130, {
    series: [{}, { stroke: "#333", width: 1 }], scales: { x: { time: false }, y: { range: [0, 1] } },
  }), [pick(data.probability.rows), data.probability.values], document.getElementById("phases"));
  state.plots.push(phases);
  const holder = document.getElementById("channels");
  holder.textContent = "";
  data.channels.forEach((channel, k) => {
    if (!state.shown.has(channel.name)) return;
    const box = document.createElement("div");
    box.className = "channel";
    holder.append(box);
    state.plots.push(new uPlot(plotOptions(channel.name, width, 90, {
      series: [{}, { stroke: COLORS[k % COLORS.length], width: 1 }],
    }), [pick(channel.rows), channel.values], box));
  });
  for (const u of state.plots) u.over.addEventListener("click", () => clicked(u));
  bands();
}

function clicked(u) {
  if (u.select.width > 2) return;  // the end of a drag that zoomed
  const t = u.posToVal(u.cursor.left, "x");
  if (Number.isFinite(t)) explainFrame(frameAt(t));
}

function xOf(frame) {  // a frame's start on the bands, in CSS pixels
  const u = state.plots[0], time = state.data.time, n = time.length;
  const t = frame < n ? time[frame] : time[n - 1] + (n > 1 ? time[n - 1] - time[n - 2] : 1);
  return u.bbox.left / devicePixelRatio + u.valToPos(t, "x");
}

function frameAtX(x) {
  const u = state.plots[0];
  return frameAt(u.posToVal(x - u.bbox.left / devicePixelRatio, "x"));
}

function expand(runs, n) {
  const out = new Int32Array(n).fill(-1);
  for (const [a, b, k] of runs) out.fill(k, a, b + 1);
  return out;
}

function paint(ctx, runs, [top, bottom]) {
  for (const [a, b, k] of runs) {
    ctx.fillStyle = color(k);
    ctx.fillRect(xOf(a), top, Math.max(1, xOf(b + 1) - xOf(a)), bottom - top);
  }
}

function bands() {
  const canvas = document.getElementById("bands"), u = state.plots[0];
  if (!u) return;
  const width = canvas.clientWidth, height = canvas.clientHeight;
  canvas.width = width * devicePixelRatio;
  canvas.height = height * devicePixelRatio;
  const ctx = canvas.getContext("2d");
  ctx.scale(devicePixelRatio, devicePixelRatio);
  const left = u.bbox.left / devicePixelRatio, right = left + u.bbox.width / devicePixelRatio;
  ctx.save();
  ctx.beginPath();
  ctx.rect(left, 0, right - left, height);
  ctx.clip();
  const n = state.data.time.length, model = expand(state.data.phases, n), labels = expand(state.edit, n);
  paint(ctx, state.data.phases, ROWS.model);
  paint(ctx, state.edit, ROWS.labels);
  for (const r of (state.data.audit ? state.data.audit.reasons : [])) {  // each reason's stretch, from its start
    ctx.fillStyle = r.severity >= 1 ? "#b00020" : "#e6a3ad";
    ctx.fillRect(xOf(r.start), ROWS.audit[0], Math.max(2, xOf(r.stop) - xOf(r.start)), ROWS.audit[1] - ROWS.audit[0]);
  }
  ctx.fillStyle = "#d62728";
  for (let t = 0; t < n; t++) {
    if (labels[t] >= 0 && labels[t] !== model[t]) ctx.fillRect(xOf(t), ROWS.differ[0], Math.max(1, xOf(t + 1) - xOf(t)), 8);
  }
  if (state.segment !== null && state.edit[state.segment]) {
    const [a, b] = state.edit[state.segment];
    ctx.strokeStyle = "#000";
    ctx.lineWidth = 2;
    ctx.strokeRect(xOf(a) + 1, ROWS.labels[0] + 1, xOf(b + 1) - xOf(a) - 2, ROWS.labels[1] - ROWS.labels[0] - 2);
  }
  if (state.boundary !== null && state.edit[state.boundary + 1]) {
    ctx.fillStyle = "#000";
    ctx.fillRect(xOf(state.edit[state.boundary][1] + 1) - 2, ROWS.labels[0] - 3, 4, ROWS.labels[1] - ROWS.labels[0] + 6);
  }
  if (state.frame !== null) {
    ctx.fillStyle = "#000";
    ctx.fillRect(xOf(state.frame), 0, 1, height);
  }
  ctx.restore();
  ctx.fillStyle = "#444";
  ctx.font = "11px system-ui";
  ctx.fillText("model", 4, 15);
  ctx.fillText("labels", 4, 53);
  if (state.data.audit) ctx.fillText("audit", 4, 75);
}

function change(edit) {  // every edit goes through here: undo keeps what was
  state.undo.push(state.edit.map((s) => s.slice()));
  state.edit = edit.filter(([a, b]) => b >= a);
  bands();
}

function moveBoundary(j, last) {  // segment j now ends at frame `last`; segment j + 1 starts after it
  const edit = state.edit.map((s) => s.slice());
  if (!edit[j + 1]) return false;
  last = Math.max(edit[j][0], Math.min(edit[j + 1][1] - 1, last));
  if (last === edit[j][1]) return false;
  edit[j][1] = last;
  edit[j + 1][0] = last + 1;
  state.edit = edit;
  return true;
}

function segmentAt(frame) { return state.edit.findIndex(([a, b]) => a <= frame && frame <= b); }

function onKey(event) {
  if (!state.data || event.target.tagName === "INPUT") return;
  const edit = state.edit, classes = state.meta.classes;
  if ((event.ctrlKey || event.metaKey) && event.key === "s") { event.preventDefault(); save(); return; }
  if (event.key === "[" || event.key === "]") {
    const last = edit.length - 2;
    if (last < 0) return;
    const now = state.boundary === null ? (event.key === "]" ? -1 : last + 1) : state.boundary;
    state.boundary = Math.max(0, Math.min(last, now + (event.key === "]" ? 1 : -1)));
    state.segment = null;
  } else if ((event.key === "ArrowLeft" || event.key === "ArrowRight") && state.boundary !== null) {
    event.preventDefault();
    const before = edit.map((s) => s.slice()), step = (event.shiftKey ? 10 : 1) * (event.key === "ArrowLeft" ? -1 : 1);
    if (moveBoundary(state.boundary, edit[state.boundary][1] + step)) state.undo.push(before);
  } else if (/^[1-9]$/.test(event.key) && state.segment !== null && Number(event.key) <= classes.length) {
    const next = edit.map((s) => s.slice());
    next[state.segment][2] = Number(event.key) - 1;
    change(next);
  } else if (event.key === "s" && state.segment !== null && state.frame !== null) {
    const [a, b, k] = edit[state.segment];
    if (state.frame <= a || state.frame > b) return;
    change([...edit.slice(0, state.segment), [a, state.frame - 1, k], [state.frame, b, k], ...edit.slice(state.segment + 1)]);
  } else if (event.key === "m" && state.segment !== null && edit[state.segment + 1]) {
    const [a, , k] = edit[state.segment], b = edit[state.segment + 1][1];
    change([...edit.slice(0, state.segment), [a, b, k], ...edit.slice(state.segment + 2)]);
  } else if (event.key === "z" || ((event.ctrlKey || event.metaKey) && event.key === "Z")) {
    if (state.undo.length) state.edit = state.undo.pop();
  } else return;
  bands();
}

function onDown(event) {
  if (!state.data) return;
  const x = event.offsetX, edit = state.edit;
  for (let j = 0; j + 1 < edit.length; j++) {
    if (Math.abs(xOf(edit[j][1] + 1) - x) <= 5) {
      state.drag = { j, before: edit.map((s) => s.slice()), moved: false };
      state.boundary = j;
      state.segment = null;
      bands();
      return;
    }
  }
  state.segment = segmentAt(frameAtX(x));
  state.boundary = null;
  bands();
}

function onMove(event) {
  if (!state.drag) return;
  const canvas = document.getElementById("bands");
  const x = event.clientX - canvas.getBoundingClientRect().left;
  if (moveBoundary(state.drag.j, frameAtX(x) - 1)) state.drag.moved = true;
  bands();
}

function onUp() {
  if (state.drag && state.drag.moved) state.undo.push(state.drag.before);
  state.drag = null;
}

async function explainFrame(frame) {
  state.frame = frame;
  bands();
  const record = await getJSON(`/api/explain?index=${state.index}&frame=${frame}`);
  state.explained = record;
  const aside = document.getElementById("explain");
  aside.textContent = "";
  const head = document.createElement("p");
  const margin = record.margin === null ? "no other class possible" : `margin ${record.margin.toFixed(3)}`;
  head.textContent = `frame ${record.frame} (t = ${record.time}): ${record.class} over ${record.versus ?? "–"}, ` +
    `${margin} · ${record.decoder}`;
  const terms = document.createElement("table");
  for (const term of record.terms) {
    const row = document.createElement("tr");
    row.className = `term ${term.kind}`;
    if (term.kind === "formula" && term.truth && term.truth[0] > 0) row.classList.add("holds");
    cell(row, term.kind);
    cell(row, term.text + (term.line ? ` (line ${term.line})` : ""));
    cell(row, term.contribution === null ? "removed" : term.contribution.toFixed(3)).className = "number";
    terms.append(row);
  }
  aside.append(head, terms);
}

async function save() {
  const classes = state.meta.classes;
  const segments = state.edit.map(([a, b, k]) => [a, b, classes[k]]);
  try {
    const done = await getJSON("/api/save", {
      method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ index: state.index, segments }),
    });
    state.saved = done;
    Object.assign(state.meta.recordings.find((r) => r.index === state.index), { saved: true, unsaved: false });
    table();
    status(`saved ${done.rows} intervals of ${done.episode} to ${done.saved}`);
  } catch (error) {
    state.saved = null;
    Object.assign(state.meta.recordings.find((r) => r.index === state.index), { saved: false, unsaved: true });
    table();
    status(`not saved: ${error.message}`);
  }
}

const bandsCanvas = document.getElementById("bands");
bandsCanvas.addEventListener("mousedown", onDown);
window.addEventListener("mousemove", onMove);
window.addEventListener("mouseup", onUp);
document.addEventListener("keydown", onKey);
document.getElementById("undo").addEventListener("click", () => { if (state.undo.length) { state.edit = state.undo.pop(); bands(); } });
document.getElementById("save").addEventListener("click", save);
window.addEventListener("resize", () => state.data && draw());
start().catch((error) => status(`error: ${error.message}`));

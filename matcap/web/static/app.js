// The page: uploads, the job list (polled), the result of the selected job.
// Job ids live in localStorage and the URL (#job=<id>), so a reload finds them again;
// the server keeps every job's status on disk.
"use strict";

const STORE_KEY = "relight-jobs";
const POLL_MS = 500;
const $ = (id) => document.getElementById(id);

const state = { limits: null, jobs: new Map(), selected: null, viewer: null, shown: null };

function savedIds() {
  try { return JSON.parse(localStorage.getItem(STORE_KEY) || "[]").filter((id) => /^[0-9a-f]{16}$/.test(id)); }
  catch { return []; }
}
function saveIds() { localStorage.setItem(STORE_KEY, JSON.stringify([...state.jobs.keys()])); }

function showError(message) {
  const box = $("error");
  box.textContent = message;
  box.hidden = !message;
}
function addError(message) {
  const box = $("error");
  box.textContent = box.hidden ? message : `${box.textContent}\n${message}`;
  box.hidden = false;
}

async function loadOptions() {
  const res = await fetch("/api/options");
  const opts = await res.json();
  state.limits = opts.limits;
  const select = $("relighter");
  for (const name of opts.relighters) {
    const option = document.createElement("option");
    option.value = option.textContent = name;
    select.append(option);
  }
  select.value = opts.defaults.relighter;
  $("relit").value = opts.defaults.relit;
  $("relit").max = opts.limits.relit;
  $("refine").value = opts.defaults.refine;
  $("refine").max = opts.limits.refine;
}

// ---------------------------------------------------------------- uploads
async function upload(file) {
  const name = file.name || "photo";
  if (state.limits && file.size > state.limits.upload_bytes) {
    addError(`${name}: the file is larger than the upload limit of ${state.limits.upload_bytes / 1e6} MB`);
    return;
  }
  const form = new FormData();
  form.append("photo", file, name);
  for (const key of ["relit", "relighter", "refine", "fov"]) form.append(key, $(key).value);
  let res;
  try {
    res = await fetch("/api/jobs", { method: "POST", body: form });
  } catch (err) {
    addError(`${name}: the upload failed (${err.message}); is the server running?`);
    return;
  }
  let body = {};
  try { body = await res.json(); } catch { /* not JSON: fall through */ }
  if (!res.ok) {
    addError(body.error ? (body.error.startsWith(name) ? body.error : `${name}: ${body.error}`) : `${name}: upload refused (HTTP ${res.status})`);
    return;
  }
  track(body.id, body);
  if (!state.selected) select(body.id);
}

function uploadAll(files) {
  showError("");
  return Promise.all([...files].map(upload));
}

function setupDrop() {
  const drop = $("drop"), input = $("photo");
  input.addEventListener("change", () => { uploadAll(input.files).then(() => { input.value = ""; }); });
  for (const type of ["dragenter", "dragover"]) {
    drop.addEventListener(type, (e) => { e.preventDefault(); drop.classList.add("over"); });
  }
  for (const type of ["dragleave", "drop"]) {
    drop.addEventListener(type, (e) => { e.preventDefault(); drop.classList.remove("over"); });
  }
  drop.addEventListener("drop", (e) => uploadAll(e.dataTransfer.files));
  // A file dropped beside the drop zone would make the browser open it in place of the page.
  for (const type of ["dragover", "drop"]) {
    window.addEventListener(type, (e) => {
      if (drop.contains(e.target)) return;
      e.preventDefault();
      if (e.dataTransfer) e.dataTransfer.dropEffect = "none"; // the "not here" cursor
    });
  }
}

// ---------------------------------------------------------------- the job list
function track(id, status) {
  if (!state.jobs.has(id)) {
    const li = document.createElement("li");
    li.dataset.jobId = id;
    li.innerHTML = '<span class="name"></span><div><progress max="100" value="0"></progress>' +
      '<div class="stage"></div></div><span class="actions"></span>';
    li.addEventListener("click", () => select(id));
    $("jobs").prepend(li);
    state.jobs.set(id, { li, status: null });
    saveIds();
  }
  if (status) render(id, status);
}

function render(id, status) {
  const job = state.jobs.get(id);
  if (!job) return;
  job.status = status;
  const { li } = job;
  li.dataset.state = status.state;
  li.className = `${status.state}${state.selected === id ? " selected" : ""}`;
  li.querySelector(".name").textContent = status.photo_name;
  li.querySelector(".name").title = `${status.photo_name} (${id})`;
  li.querySelector("progress").value = status.percent || 0;
  let text = status.stage;
  // The number next to the bar: the bar alone does not say how far a slow step is.
  if (status.state === "running") text = `${Math.round(status.percent || 0)} % \u00b7 ${status.stage}`;
  if (status.state === "queued") text = status.queue_position ? `waiting (${status.queue_position} in the queue)` : "waiting";
  if (status.state === "failed") text = `failed: ${status.error}`;
  if (status.state === "done") text = `done in ${Math.round(status.finished - status.started)} s`;
  li.querySelector(".stage").textContent = text;
  const actions = li.querySelector(".actions");
  actions.replaceChildren();
  if (!status.final) {
    const button = document.createElement("button");
    button.type = "button";
    button.textContent = "Cancel";
    button.addEventListener("click", (e) => { e.stopPropagation(); fetch(`/api/jobs/${id}/cancel`, { method: "POST" }); });
    actions.append(button);
  }
  if (status.state === "done" && state.selected === id && state.shown !== id) showResult(id, status);
}

async function poll() {
  const open = [...state.jobs.entries()].filter(([, job]) => !job.status || !job.status.final);
  await Promise.all(open.map(async ([id, job]) => {
    try {
      const res = await fetch(`/api/jobs/${id}`);
      if (res.status === 404) { job.li.remove(); state.jobs.delete(id); saveIds(); return; }
      if (res.ok) render(id, await res.json());
    } catch { /* the server is restarting: try again next time */ }
  }));
  setTimeout(poll, POLL_MS);
}

function select(id) {
  state.selected = id;
  history.replaceState(null, "", `#job=${id}`);
  for (const [other, job] of state.jobs) job.li.classList.toggle("selected", other === id);
  const job = state.jobs.get(id);
  if (job && job.status && job.status.state === "done") showResult(id, job.status);
}

// ---------------------------------------------------------------- the result
function figure(url, caption, onClick) {
  const fig = document.createElement("figure");
  const img = document.createElement("img");
  img.src = url;
  img.alt = caption;
  const cap = document.createElement("figcaption");
  cap.textContent = caption;
  fig.append(img, cap);
  if (onClick) fig.addEventListener("click", onClick);
  return fig;
}

const fmt = (p) => `(${p.map((v) => Number(v).toFixed(1)).join(", ")})`;

async function showResult(id, status) {
  state.shown = id;
  const r = status.result;
  $("result").hidden = false;
  $("result-name").textContent = `: ${status.photo_name}`;
  $("download-zip").href = r.zip;
  $("download-glb").href = r.glb || "";
  $("download-glb").hidden = !r.glb;
  $("relit-views").replaceChildren(...r.relit.map((v, k) =>
    figure(v.url, `light ${k + 1} ${fmt(v.light)}`, () => state.viewer && state.viewer.setLight(v.light))));
  $("maps").replaceChildren(...Object.entries(r.maps).filter(([, url]) => url).map(([name, url]) => figure(url, name)));
  $("renders").replaceChildren(...r.renders.map((v, k) =>
    figure(v.url, k === 0 ? "flash" : `light ${k} ${fmt(v.light)}`, () => state.viewer && state.viewer.setLight(v.light))));
  drawDiagram(r);
  await loadViewer(id, r.viewer);
}

async function loadViewer(id, settings) {
  const err = $("viewer-error");
  err.hidden = true;
  try {
    if (!state.viewer) state.viewer = new MatcapViewer($("plane-view"), $("sphere-view"), onLight);
    state.viewer.ready = false;
    const res = await fetch(`/api/jobs/${id}/maps.bin`);
    if (!res.ok) throw new Error(`maps.bin: HTTP ${res.status}`);
    const buffer = await res.arrayBuffer();
    if (state.shown !== id) return; // another job was selected meanwhile
    state.viewer.load(settings, buffer);
    document.body.dataset.viewerJob = id;
  } catch (e) {
    err.textContent = `The live preview is unavailable: ${e.message}`;
    err.hidden = false;
  }
}

function onLight(light) {
  $("light-readout").textContent = `light at ${fmt(light)}`;
  $("light-z").value = light[2];
  const marker = document.getElementById("diagram-light");
  if (marker) { marker.setAttribute("cx", light[0]); marker.setAttribute("cy", -light[1]); }
}

// Top view of the scene: the plane (side 4), the photo on it, the camera/flash, the
// relit views' lights (numbered) and the viewer's light. SVG y is down, scene y is up.
function drawDiagram(r) {
  const svg = $("light-diagram");
  const ns = "http://www.w3.org/2000/svg";
  const el = (tag, attrs, text) => {
    const node = document.createElementNS(ns, tag);
    for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
    if (text !== undefined) node.textContent = text;
    svg.append(node);
    return node;
  };
  svg.replaceChildren();
  const p = r.photo_plane;
  el("rect", { x: -2, y: -2, width: 4, height: 4, fill: "#f1f1f1", stroke: "#bbb", "stroke-width": 0.03 });
  el("rect", { x: p.x0, y: -p.y0, width: p.width * p.dx, height: p.height * p.dy, fill: "#d9e4f0", stroke: "#7a9cc6", "stroke-width": 0.04 });
  el("circle", { cx: r.camera[0], cy: -r.camera[1], r: 0.22, fill: "none", stroke: "#333", "stroke-width": 0.06 });
  el("text", { x: r.camera[0] + 0.3, y: -r.camera[1] - 0.3, "font-size": 0.45, fill: "#333" }, "flash");
  r.relit.forEach((v, k) => {
    el("circle", { cx: v.light[0], cy: -v.light[1], r: 0.28, fill: "#f2b01e", stroke: "#8a6100", "stroke-width": 0.04,
      class: "relit-light" }).append(Object.assign(document.createElementNS(ns, "title"), { textContent: `light ${k + 1} ${fmt(v.light)}` }));
    el("text", { x: v.light[0], y: -v.light[1] + 0.15, "font-size": 0.4, "text-anchor": "middle" }, String(k + 1));
  });
  el("circle", { id: "diagram-light", cx: 0, cy: 0, r: 0.18, fill: "#d23", stroke: "#fff", "stroke-width": 0.05 });
}

function setupLightControls() {
  $("light-z").addEventListener("input", (e) => {
    if (!state.viewer || !state.viewer.ready) return;
    const [x, y] = state.viewer.light;
    state.viewer.setLight([x, y, Number(e.target.value)]);
  });
  $("light-flash").addEventListener("click", () => {
    if (state.viewer && state.viewer.ready) state.viewer.setLight(state.viewer.settings.camera.slice());
  });
}

// ---------------------------------------------------------------- start
async function main() {
  setupDrop();
  setupLightControls();
  try { await loadOptions(); } catch (e) { showError(`cannot reach the server: ${e.message}`); }
  const fromUrl = (location.hash.match(/job=([0-9a-f]{16})/) || [])[1];
  const ids = savedIds();
  if (fromUrl && !ids.includes(fromUrl)) ids.push(fromUrl);
  for (const id of ids) track(id, null);
  if (fromUrl) select(fromUrl);
  else if (ids.length) select(ids[ids.length - 1]);
  poll();
}

window.relightApp = state;
main();

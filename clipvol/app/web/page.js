// `clipvol serve`'s page: the live view (view.js, the notebook widget's own module) over a WebSocket
// `model`, and the controls a notebook leaves to Python: view presets, window, iso value, slices,
// crop box and clip plane, the store. Every request carries the server's token (this script's own
// URL holds it). Frames arrive as a JSON `frame` message then the image as a binary message; the
// image is shown through a blob: URL (the page's content security policy allows no other).
const token = new URL(import.meta.url).searchParams.get("token");
const query = (extra) => "?" + new URLSearchParams({ ...(token ? { token } : {}), ...extra }).toString();
const here = new URLSearchParams(location.search);
const storeIndex = here.get("store") || "0";
const { default: view } = await import("/view.js" + query({}));

const LETTERS = { anterior: "A", posterior: "P", left: "L", right: "R", superior: "S", inferior: "I" };
const state = { image: "", hud: "", error: "", handled: 0, pick: [0, 0, 0, 0] };
const handlers = {};
let dirty = {};
const emit = (name, ...args) => { for (const cb of handlers[name] || []) cb(...args); };
const scheme = location.protocol === "https:" ? "wss" : "ws";
const ws = new WebSocket(`${scheme}://${location.host}/ws` + query({ store: storeIndex }));
ws.binaryType = "blob";
const send = (msg) => { if (ws.readyState === WebSocket.OPEN) { ws.send(JSON.stringify(msg)); info.sent++; } };
const model = {
  get: (k) => state[k],
  set: (k, v) => { if (state[k] !== v) { state[k] = v; dirty[k] = v; emit("change:" + k); } },
  on: (name, cb) => { (handlers[name] = handlers[name] || []).push(cb); },
  off: (name, cb) => { handlers[name] = (handlers[name] || []).filter((f) => cb && f !== cb); },
  save_changes: () => { if (Object.keys(dirty).length) { send({ method: "update", state: dirty }); dirty = {}; } },
  send: () => {},
};
// what a test (or a curious user) reads: frames shown, the last frame's message, the last full frame
const info = window.clipvol = { sent: 0, frames: 0, full: 0, moving: 0, last: null, lastFull: null, lastFullMessage: null, closed: null, firstFrameMs: null };
const apply = (values) => { for (const [k, v] of Object.entries(values)) { state[k] = v; emit("change:" + k); } };

let meta = null, url = null;
ws.onmessage = (ev) => {
  if (typeof ev.data !== "string") {  // the image of the frame message before it
    if (!meta) return;
    const old = url;
    const blob = new Blob([ev.data], { type: meta.format });  // typed: image/png, image/jpeg or image/webp
    url = URL.createObjectURL(blob);
    info.frames++; info.last = meta;
    if (info.frames === 1) info.firstFrameMs = performance.now();  // since the page's navigation began
    if (meta.full) { info.full++; info.lastFull = blob; info.lastFullMessage = meta; } else info.moving++;
    apply({ image: url, hud: meta.hud, error: meta.error });
    apply({ handled: meta.handled });
    if (old) setTimeout(() => URL.revokeObjectURL(old), 1000);
    meta = null;
    return;
  }
  const msg = JSON.parse(ev.data);
  if (msg.method === "hello") start(msg);
  else if (msg.method === "frame") meta = msg;
  else if (msg.method === "update") {
    const { handled, ...rest } = msg.state;
    apply(rest);
    if (handled !== undefined) apply({ handled });
  }
};
ws.onclose = (ev) => {
  info.closed = ev.code;
  apply({ error: `the server closed this view (${ev.code}${ev.reason ? ": " + ev.reason : ""}); reload the page` });
};

function control(parent, label, el) {
  const span = document.createElement("label");
  span.append(label + " ", el);
  parent.append(span);
  return el;
}

function numbers(text, n) {
  const t = text.trim();
  if (!t) return null;
  const v = t.split(/[ ,]+/).map(Number);
  return v.length === n && v.every(Number.isFinite) ? v : t;  // the server names a wrong one
}

function start(hello) {
  Object.assign(state, hello.state);
  const el = document.getElementById("view");
  view.render({ model, el });
  const img = el.querySelector("img");
  const [w, h] = hello.size;
  img.style.width = w + "px"; img.style.height = h + "px";  // a moving frame is smaller: shown scaled up
  const box = document.getElementById("controls");
  const change = (values) => { for (const [k, v] of Object.entries(values)) model.set(k, v); model.save_changes(); };

  if (hello.stores.length > 1) {
    const sel = document.createElement("select");
    hello.stores.forEach((name, i) => { const o = new Option(name, String(i)); sel.append(o); });
    sel.id = "store";
    sel.value = String(hello.store);
    sel.onchange = () => { here.set("store", sel.value); location.search = here.toString(); };
    control(box, "store", sel);
  }
  const views = document.createElement("span");
  views.append("view ");
  for (const name of hello.state.views) {
    const b = document.createElement("button");
    b.textContent = LETTERS[name] || name;
    b.title = name;
    b.dataset.view = name;
    b.onclick = () => change({ view: name, azimuth: 0, elevation: 0, zoom: 1 });
    views.append(b);
  }
  box.append(views);

  const [vlo, vhi] = hello.value_range;
  const lo = control(box, "window", document.createElement("input"));
  const hi = document.createElement("input");
  lo.id = "window-low"; hi.id = "window-high";
  for (const i of [lo, hi]) { i.type = "number"; i.step = "any"; }
  lo.placeholder = String(vlo); hi.placeholder = String(vhi);
  lo.after(" to ", hi);
  const setWindow = () => {
    if (lo.value === "" && hi.value === "") change({ window: null });
    else change({ window: [Number(lo.value === "" ? vlo : lo.value), Number(hi.value === "" ? vhi : hi.value)] });
  };
  lo.onchange = setWindow; hi.onchange = setWindow;
  const iso = control(box, "iso value", document.createElement("input"));
  iso.type = "number"; iso.step = "any"; iso.id = "iso";
  iso.onchange = () => change({ iso_value: iso.value === "" ? null : Number(iso.value) });

  const sl = control(box, "slice", document.createElement("select"));
  sl.id = "slice";
  for (const [v, t] of [["", "none (3D)"], ["axial", "axial"], ["coronal", "coronal"], ["sagittal", "sagittal"]]) sl.append(new Option(t, v));
  const idx = control(box, "at", document.createElement("input"));
  idx.type = "range"; idx.min = "0"; idx.step = "1"; idx.id = "slice-index";
  const axis = { axial: 0, coronal: 1, sagittal: 2 };
  const shape = hello.shape;
  const fit = () => { const n = sl.value ? shape[axis[sl.value]] : 1; idx.max = String(n - 1); idx.value = String(Math.floor((n - 1) / 2)); };
  sl.onchange = () => { fit(); change({ slice: sl.value, slice_index: sl.value ? Number(idx.value) : null }); };
  idx.oninput = () => change({ slice_index: Number(idx.value) });

  const crop = control(box, "crop voxels x0,y0,z0,x1,y1,z1", document.createElement("input"));
  crop.type = "text"; crop.placeholder = "whole volume"; crop.id = "crop";
  crop.onchange = () => change({ crop_voxels: numbers(crop.value, 6) });
  const clip = control(box, "clip plane x,y,z,nx,ny,nz", document.createElement("input"));
  clip.type = "text"; clip.placeholder = "none"; clip.id = "clip";
  clip.onchange = () => change({ clip_plane: numbers(clip.value, 6) });
  const save = document.createElement("button");  // the converged frame's camera, for `clipvol render --camera`
  save.textContent = "camera file";
  save.id = "save-camera";
  save.title = "download the shown view's camera (clipvol render --camera FILE.json draws it again)";
  save.onclick = () => {
    if (!info.lastFullMessage || !info.lastFullMessage.camera) return;
    const a = document.createElement("a");
    a.href = URL.createObjectURL(new Blob([JSON.stringify(info.lastFullMessage.camera, null, 1)], { type: "application/json" }));
    a.download = "camera.json";
    a.click();
    setTimeout(() => URL.revokeObjectURL(a.href), 1000);
  };
  box.append(save);
  window.rendered = true;
}

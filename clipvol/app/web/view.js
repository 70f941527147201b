// The browser half of a live view: an image, the tf / mode menus, the HUD and error lines, drag to
// orbit, wheel to zoom, click to probe (Shift+click: a ruler end). It talks to a `model` (get / set /
// on / save_changes): anywidget's in a notebook (clipvol.show), the WebSocket stand-in of
// `clipvol serve`'s page (web/page.js) in a browser. One file, loaded by both (clipvol.app.live_view).
function render({ model, el }) {
  const root = document.createElement("div");
  root.style.display = "inline-block";
  const img = document.createElement("img");
  img.draggable = false;
  img.style.cursor = "grab";
  img.style.touchAction = "none";
  img.style.background = "#000";
  const bar = document.createElement("div");
  const tfSel = document.createElement("select");
  for (const n of model.get("tf_names")) {
    const o = document.createElement("option"); o.value = n; o.textContent = n; tfSel.appendChild(o);
  }
  const modeSel = document.createElement("select");
  for (const n of model.get("mode_names")) {
    const o = document.createElement("option"); o.value = n; o.textContent = n; modeSel.appendChild(o);
  }
  const hud = document.createElement("pre");
  hud.style.margin = "2px 0"; hud.style.fontSize = "11px";
  const err = document.createElement("pre");
  err.setAttribute("role", "alert");
  err.style.margin = "2px 0"; err.style.fontSize = "11px"; err.style.color = "#c00";
  err.style.whiteSpace = "pre-wrap";
  bar.append("tf ", tfSel, " mode ", modeSel);
  root.append(img, bar, hud, err);
  el.appendChild(root);
  let decodeError = "";
  const sync = () => {
    const src = model.get("image");
    if (img.getAttribute("src") !== src) { decodeError = ""; img.src = src; }
    hud.textContent = model.get("hud");
    tfSel.value = model.get("tf");
    modeSel.value = model.get("mode");
    const text = model.get("error") || decodeError;
    err.textContent = text ? "error: " + text : "";
    err.style.display = text ? "block" : "none";
    img.style.opacity = text ? "0.4" : "1";  // a frame the error concerns is not shown as if right
  };
  img.onerror = () => { if (img.getAttribute("src")) { decodeError = "the frame sent by the kernel could not be decoded"; sync(); } };
  sync();
  for (const n of ["image", "hud", "tf", "mode", "error"]) model.on("change:" + n, sync);
  tfSel.onchange = () => { model.set("tf", tfSel.value); model.save_changes(); };
  modeSel.onchange = () => { model.set("mode", modeSel.value); model.save_changes(); };
  // One camera change in flight: the kernel draws every change it gets, and a drag makes far more
  // pointer moves than it can draw; the moves made meanwhile wait, and only the newest is sent
  // once the kernel has handled the last (its `handled` count changes). From a kernel that does
  // not answer within 10 s, the next move is sent anyway.
  let want = null, inflight = false, sentAt = 0;
  const cur = (k) => (want && k in want ? want[k] : model.get(k));
  const sendCamera = () => {
    if (!want || (inflight && performance.now() - sentAt < 10000)) return;
    const changed = Object.keys(want).filter((k) => model.get(k) !== want[k]);
    for (const k of changed) model.set(k, want[k]);
    want = null;
    if (!changed.length) return;
    inflight = true; sentAt = performance.now();
    model.save_changes();
  };
  const setCamera = (values) => { want = Object.assign(want || {}, values); sendCamera(); };
  model.on("change:handled", () => { inflight = false; sendCamera(); });
  let drag = null;
  img.addEventListener("pointerdown", (e) => {
    drag = { x: e.clientX, y: e.clientY, az: cur("azimuth"), el: cur("elevation"),
             px: e.offsetX * img.naturalWidth / Math.max(1, img.clientWidth),
             py: e.offsetY * img.naturalHeight / Math.max(1, img.clientHeight), shift: e.shiftKey };
    img.setPointerCapture(e.pointerId); img.style.cursor = "grabbing";
  });
  img.addEventListener("pointermove", (e) => {
    if (!drag) return;
    setCamera({ azimuth: drag.az - (e.clientX - drag.x) * 0.5,
                elevation: Math.max(-89, Math.min(89, drag.el + (e.clientY - drag.y) * 0.5)) });
  });
  const end = () => { drag = null; img.style.cursor = "grab"; };
  img.addEventListener("pointerup", (e) => {
    if (drag && Math.abs(e.clientX - drag.x) + Math.abs(e.clientY - drag.y) < 3) {  // a click: probe there
      model.set("pick", [drag.px, drag.py, drag.shift ? 1 : 0, (model.get("pick")[3] || 0) + 1]);
      model.save_changes();
    }
    end();
  });
  img.addEventListener("pointercancel", end);
  img.addEventListener("wheel", (e) => {
    e.preventDefault();
    setCamera({ zoom: Math.max(0.2, Math.min(20, cur("zoom") * Math.exp(-e.deltaY * 0.001))) });
  }, { passive: false });
}
export default { render };

// zab gui: pan and zoom of the fleet map. A view is {cx, cy, scale}: the world point (m) at
// the map's centre and pixels per metre. The map follows the automatic fit of all vehicles
// until the user pans or zooms; from then on the user's view stays put (new positions do not
// move it) until "fit", a double-click / double-tap or the 0 key returns to the automatic fit.
"use strict";

const MIN_SPAN_M = 5;            // zoom in until the map's short side shows this many metres
const MAX_SPAN_M = 200000;       // zoom out until it shows this many
const DRAG_PX = 4;               // a press that moves less than this is a click or a tap
const DOUBLE_TAP_MS = 350;
const STEP_ZOOM = 1.5;           // the + and - keys and buttons
const KEY_PAN_PX = 60;

class MapView {
  constructor(svg, onChange) {
    this.svg = svg;
    this.onChange = onChange;
    this.auto = null;            // the latest automatic fit
    this.user = null;            // the user's view, or null to follow the automatic fit
    this.width = 1;
    this.height = 1;
    this.pointers = new Map();   // pointerId -> {x, y} in map pixels
    this.dragging = false;
    this.lastTap = null;
    svg.addEventListener("wheel", (e) => this.onWheel(e), { passive: false });
    svg.addEventListener("pointerdown", (e) => this.onPointerDown(e));
    svg.addEventListener("pointermove", (e) => this.onPointerMove(e));
    for (const type of ["pointerup", "pointercancel"]) {
      svg.addEventListener(type, (e) => this.onPointerUp(e));
    }
    svg.addEventListener("dblclick", (e) => { e.preventDefault(); this.fit(); });
    svg.addEventListener("keydown", (e) => this.onKey(e));
  }

  // The view to draw with: the user's, else `auto` (the fit of everything, for this size).
  view(auto, width, height) {
    this.auto = auto;
    this.width = width;
    this.height = height;
    this.svg.dataset.view = this.user ? "user" : "auto";
    return this.user || auto;
  }

  fit() {
    this.user = null;
    this.onChange();
  }

  set(view) {
    this.user = view;
    this.onChange();
  }

  // Zoom by `factor` about the map pixel (px, py): the world point there stays there.
  zoomAt(px, py, factor) {
    const v = this.user || this.auto;
    if (!v) return;
    const short = Math.min(this.width, this.height);
    const scale = Math.min(Math.max(v.scale * factor, short / MAX_SPAN_M), short / MIN_SPAN_M);
    const dx = px - this.width / 2, dy = py - this.height / 2;
    const wx = v.cx + dx / v.scale, wy = v.cy - dy / v.scale;
    this.set({ cx: wx - dx / scale, cy: wy + dy / scale, scale });
  }

  zoomIn() { this.zoomAt(this.width / 2, this.height / 2, STEP_ZOOM); }

  zoomOut() { this.zoomAt(this.width / 2, this.height / 2, 1 / STEP_ZOOM); }

  // Move the map's content by (dx, dy) pixels.
  panBy(dx, dy) {
    const v = this.user || this.auto;
    if (!v) return;
    this.set({ cx: v.cx - dx / v.scale, cy: v.cy + dy / v.scale, scale: v.scale });
  }

  local(e) {
    const box = this.svg.getBoundingClientRect();
    return { x: e.clientX - box.left, y: e.clientY - box.top };
  }

  onWheel(e) {
    e.preventDefault();
    const lines = e.deltaMode === 1 ? 16 : e.deltaMode === 2 ? this.height : 1;
    // a trackpad pinch comes as a wheel with ctrlKey and small deltas
    const rate = e.ctrlKey ? 0.01 : 0.002;
    const p = this.local(e);
    this.zoomAt(p.x, p.y, Math.exp(-e.deltaY * lines * rate));
  }

  onPointerDown(e) {
    if (e.pointerType === "mouse" && e.button !== 0) return;
    this.svg.setPointerCapture(e.pointerId);
    const p = this.local(e);
    this.pointers.set(e.pointerId, { x: p.x, y: p.y, x0: p.x, y0: p.y });
    if (this.pointers.size > 1) this.dragging = true;   // a pinch is never a tap
  }

  onPointerMove(e) {
    const p = this.pointers.get(e.pointerId);
    if (!p) return;
    const q = this.local(e);
    if (!this.dragging && Math.hypot(q.x - p.x0, q.y - p.y0) < DRAG_PX) return;
    this.dragging = true;
    const others = [...this.pointers.entries()].filter(([id]) => id !== e.pointerId);
    if (others.length === 0) {
      this.panBy(q.x - p.x, q.y - p.y);
    } else {
      // pinch: the world point under the fingers' midpoint follows it, the scale follows
      // their spread
      const o = others[0][1];
      const before = Math.hypot(p.x - o.x, p.y - o.y);
      const after = Math.hypot(q.x - o.x, q.y - o.y);
      this.panBy((q.x - p.x) / 2, (q.y - p.y) / 2);
      if (before > 0 && after > 0) this.zoomAt((q.x + o.x) / 2, (q.y + o.y) / 2, after / before);
    }
    p.x = q.x;
    p.y = q.y;
  }

  onPointerUp(e) {
    if (!this.pointers.delete(e.pointerId)) return;
    if (e.type === "pointerup" && e.pointerType === "touch" && !this.dragging) {
      const tap = { t: e.timeStamp, ...this.local(e) };
      const last = this.lastTap;
      const near = last && Math.hypot(tap.x - last.x, tap.y - last.y) < 30;
      if (near && tap.t - last.t < DOUBLE_TAP_MS) {
        this.lastTap = null;
        this.fit();
      } else {
        this.lastTap = tap;
      }
    }
    if (this.pointers.size === 0) this.dragging = false;
  }

  onKey(e) {
    if (e.ctrlKey || e.metaKey || e.altKey) return;
    const actions = {
      "+": () => this.zoomIn(), "=": () => this.zoomIn(),
      "-": () => this.zoomOut(), "_": () => this.zoomOut(), "0": () => this.fit(),
      ArrowLeft: () => this.panBy(KEY_PAN_PX, 0), ArrowRight: () => this.panBy(-KEY_PAN_PX, 0),
      ArrowUp: () => this.panBy(0, KEY_PAN_PX), ArrowDown: () => this.panBy(0, -KEY_PAN_PX),
    };
    const action = actions[e.key];
    if (!action) return;
    e.preventDefault();
    action();
  }
}

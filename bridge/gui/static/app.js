// zab gui: the fleet as one node sees it, live over a websocket. Plain JS, no build step.
// The server sends "hello" (mission + snapshot items), then "patch" messages of items;
// apply() folds each item into `state`, and render() draws the page from `state`.
"use strict";

const RENDER_MS = 500;          // ages tick at this pace even without news
const MIN_RENDER_MS = 100;      // news is drawn at most this often
const RANGE_FADE_S = 60;        // range circles older than this are not drawn
const ELLIPSE_95 = Math.sqrt(5.991);  // 1-σ ellipse to the 95 % one (χ², two degrees)
const STALE_S = 60;             // a position older than this is drawn hollow
const MAX_EVENTS = 300;
const SVG = "http://www.w3.org/2000/svg";

let state = emptyState();
let socket = null;
let retryMs = 500;
let requestId = 0;
let dirty = true;
let mapDirty = false;           // the user moved the map: redraw it on the next frame
const mapView = new MapView(document.getElementById("map"), () => { mapDirty = true; });

function emptyState() {
  return {
    mission: null, offset: 0, connection: null, nodes: {}, ranges: {}, stats: {},
    links: {}, events: [], commands: {}, transfers: {}, hops: {}, routes: {},
  };
}

function vehicle(name) {
  if (!state.nodes[name]) {
    state.nodes[name] = { name, role: "submerged", position: {}, tracks: {}, channels: {},
                          heard: null, static: null, lost: null };
  }
  return state.nodes[name];
}

// ---- time ----------------------------------------------------------------------------------

function serverNow() { return Date.now() / 1000 + state.offset; }

function age(t) {
  if (t === null || t === undefined) return "—";
  const s = Math.max(0, serverNow() - t);
  if (s < 10) return s.toFixed(1) + " s";
  if (s < 120) return Math.round(s) + " s";
  if (s < 7200) return Math.floor(s / 60) + " min " + Math.round(s % 60) + " s";
  return (s / 3600).toFixed(1) + " h";
}

function duration(s) {
  if (s === null || s === undefined) return "—";
  return s < 10 ? s.toFixed(1) + " s" : Math.round(s) + " s";
}

function missionInterval(s) {
  // a channel's interval_s as the mission file says it: 20 -> "20 s", 0 -> "each turn"
  return s > 0 ? Number(s.toPrecision(3)) + " s" : "each turn";
}

function clockText(t) {
  const d = new Date((t - state.offset) * 1000);
  return d.toLocaleTimeString([], { hour12: false });
}

// ---- items ---------------------------------------------------------------------------------

function apply(item) {
  switch (item.kind) {
    case "position": {
      const v = vehicle(item.node);
      v.position[item.source] = item;
      const track = v.tracks[item.source] || (v.tracks[item.source] = []);
      const last = track[track.length - 1];
      if (!last || last[2] !== item.time) track.push([item.x, item.y, item.time]);
      const limit = state.mission ? state.mission.track_points : 600;
      if (track.length > limit) track.splice(0, track.length - limit);
      break;
    }
    case "lost": vehicle(item.node).lost = item; break;
    case "track": vehicle(item.node).tracks[item.source] = item.points.slice(); break;
    case "channel": vehicle(item.node).channels[item.channel + "/" + item.element] = item; break;
    case "heard": vehicle(item.node).heard = item.last_heard; break;
    case "link": state.links[item.observer + "/" + item.node] = item; break;
    case "range": state.ranges[item.observer + "/" + item.peer] = item; break;
    case "hop": state.hops[item.observer + "/" + item.link + "/" + item.peer] = item; break;
    case "route": state.routes[item.observer + "/" + item.peer] = item; break;
    case "stats": state.stats[item.node] = item; break;
    case "event":
      state.events.push(item);
      if (state.events.length > MAX_EVENTS) state.events.shift();
      break;
    case "command": state.commands[item.ref] = item; break;
    case "transfer": state.transfers[item.node + "/" + item.channel + "/" + item.id] = item; break;
    case "feed": state.connection = item; break;
    case "image": imageView.apply(item); break;
    default: break;
  }
  dirty = true;
}

function onMessage(event) {
  let message;
  try { message = JSON.parse(event.data); } catch (e) { return; }
  if (typeof message.time === "number") state.offset = message.time - Date.now() / 1000;
  if (message.type === "hello") {
    const offset = state.offset;
    state = emptyState();
    state.offset = offset;
    state.mission = message.mission;
    for (const node of message.mission.nodes) {
      const v = vehicle(node.name);
      v.role = node.role;
      v.static = node.position;
    }
    setupPage();
    imageView.reset(message.mission.images);
    message.items.forEach(apply);
  } else if (message.type === "patch") {
    message.items.forEach(apply);
  } else if (message.type === "reply" && message.request === "image_control") {
    imageView.onReply(message);
  } else if (message.type === "reply") {
    onReply(message);
  }
}

// ---- connection ----------------------------------------------------------------------------

function connect() {
  const scheme = location.protocol === "https:" ? "wss://" : "ws://";
  socket = new WebSocket(scheme + location.host + "/ws");
  socket.onopen = () => { retryMs = 500; dirty = true; };
  socket.onmessage = onMessage;
  socket.onclose = () => {
    socket = null;
    dirty = true;
    setTimeout(connect, retryMs);
    retryMs = Math.min(retryMs * 2, 5000);
  };
}

function renderConnection() {
  const badge = document.getElementById("connection");
  let text, stateName;
  if (!socket || socket.readyState !== WebSocket.OPEN) {
    text = "GUI server unreachable, retrying…"; stateName = "down";
  } else if (!state.connection || !state.connection.connected) {
    const node = state.mission ? state.mission.node : "node";
    text = "not connected to " + node + (state.connection && state.connection.error
      ? ": " + state.connection.error : ""); stateName = "down";
  } else {
    const node = state.mission.node;
    const stats = state.stats[node];
    const silent = stats ? serverNow() - stats.time : null;
    if (stats && silent < 5) { text = "connected to " + node; stateName = "up"; }
    else { text = "connected to " + node + ", its bridge is silent"; stateName = "degraded"; }
  }
  badge.textContent = text;
  badge.dataset.state = stateName;
  // a command needs the GUI's session to the node; the server would refuse it anyway
  document.getElementById("command-send").disabled = stateName === "down";
  document.getElementById("clock").textContent = clockText(serverNow());
}

// ---- map -----------------------------------------------------------------------------------

function el(name, attrs, parent) {
  const node = document.createElementNS(SVG, name);
  for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, v);
  if (parent) parent.appendChild(node);
  return node;
}

function linkOf(name) {
  const mission = state.mission;
  if (!mission) return null;
  if (name === mission.node) return null;
  return state.links[mission.node + "/" + name] || null;
}

function linkState(name) {
  // "down" before the peer was ever heard is the start of a mission, not a fault: unknown
  const link = linkOf(name);
  if (!link) return "unknown";
  const v = state.nodes[name];
  return link.state === "down" && v && !v.heard ? "unknown" : link.state;
}

function where(v) {
  // the newest live position (navigation or fix), else the mission's static one
  const live = [v.position.nav, v.position.fix].filter(Boolean)
    .sort((a, b) => b.time - a.time)[0];
  if (live) return { x: live.x, y: live.y, depth: live.depth, time: live.time, live: true };
  if (v.static && v.role === "surface") return { ...v.static, time: null, live: false };
  return null;
}

function niceStep(span) {
  const raw = span / 6;
  const p = Math.pow(10, Math.floor(Math.log10(raw)));
  for (const m of [1, 2, 5, 10]) if (m * p >= raw) return m * p;
  return 10 * p;
}

function renderMap() {
  const svg = document.getElementById("map");
  // one SVG unit per CSS pixel, fractions included: pointer positions map exactly
  const box = svg.getBoundingClientRect();
  const width = box.width || 600;
  const height = box.height || 400;
  svg.setAttribute("viewBox", `0 0 ${width} ${height}`);
  while (svg.firstChild) svg.removeChild(svg.firstChild);
  mapDirty = false;
  const now = serverNow();
  const points = [];
  const places = {};
  for (const v of Object.values(state.nodes)) {
    const p = where(v);
    if (p) { places[v.name] = p; points.push([p.x, p.y]); }
    for (const track of Object.values(v.tracks)) for (const q of track) points.push([q[0], q[1]]);
  }
  const ranges = Object.values(state.ranges).filter(
    (r) => now - r.time < RANGE_FADE_S && places[r.observer]);
  for (const r of ranges) {
    const c = places[r.observer];
    points.push([c.x - r.range_m, c.y - r.range_m], [c.x + r.range_m, c.y + r.range_m]);
  }
  if (!points.length) {
    const t = el("text", { x: width / 2, y: height / 2, "text-anchor": "middle",
                           class: "map-empty" }, svg);
    t.textContent = "no positions yet";
    return;
  }
  let [x0, y0] = points[0], [x1, y1] = points[0];
  for (const [x, y] of points) {
    x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y);
  }
  const span = Math.max(x1 - x0, y1 - y0, 20);
  const pad = 36;
  const fit = { cx: (x0 + x1) / 2, cy: (y0 + y1) / 2,
                scale: Math.min((width - 2 * pad) / Math.max(x1 - x0, span * 0.2),
                                (height - 2 * pad) / Math.max(y1 - y0, span * 0.2)) };
  const { cx, cy, scale } = mapView.view(fit, width, height);
  document.getElementById("map-fit").disabled = svg.dataset.view === "auto";
  const sx = (x) => width / 2 + (x - cx) * scale;
  const sy = (y) => height / 2 - (y - cy) * scale;

  // grid and scale bar
  const step = niceStep(Math.max(width, height) / scale);
  const grid = el("g", { class: "grid" }, svg);
  const gx0 = Math.floor((cx - width / 2 / scale) / step) * step;
  for (let gx = gx0; sx(gx) <= width; gx += step) {
    el("line", { x1: sx(gx), y1: 0, x2: sx(gx), y2: height }, grid);
  }
  const gy0 = Math.floor((cy - height / 2 / scale) / step) * step;
  for (let gy = gy0; sy(gy) >= 0; gy += step) {
    el("line", { x1: 0, y1: sy(gy), x2: width, y2: sy(gy) }, grid);
  }
  const bar = el("g", { class: "scale" }, svg);
  el("line", { x1: 12, y1: height - 14, x2: 12 + step * scale, y2: height - 14 }, bar);
  el("text", { x: 12, y: height - 20 }, bar).textContent = `${step} m`;
  el("text", { x: width - 12, y: 18, "text-anchor": "end", class: "north" }, svg)
    .textContent = "N ↑";

  // ranges, measured by an observer to a peer: the peer is somewhere on the circle. Each
  // label sits just outside its circle (never crossed by its dashes), preferably on the side
  // away from the peer (where the peer's own label is), at the first angle where it overlaps
  // no other label or vehicle and stays on the map, so concentric circles keep readable labels.
  const taken = Object.entries(places).map(([name, p]) => ({
    x0: sx(p.x) - 9, y0: sy(p.y) - 9, x1: sx(p.x) + 14 + 7 * (name.length + 7), y1: sy(p.y) + 9,
  }));
  const fan = {};  // per observer, its circles from the smallest out: the k-th is fanned by k
  for (const r of [...ranges].sort((a, b) => a.range_m - b.range_m)) {
    (fan[r.observer] ||= []).push(r);
  }
  const labels = [];
  ranges.forEach((r) => {
    const c = places[r.observer];
    const fade = 1 - (now - r.time) / RANGE_FADE_S;
    const opacity = (0.25 + 0.75 * fade).toFixed(2);
    const attrs = { "data-observer": r.observer, "data-peer": r.peer, opacity };
    const g = el("g", { class: "range", ...attrs }, svg);
    const radius = Math.max(1, r.range_m * scale);
    el("circle", { cx: sx(c.x), cy: sy(c.y), r: radius }, g);
    const peer = places[r.peer];
    const toward = peer ? Math.atan2(sy(peer.y) - sy(c.y), sx(peer.x) - sx(c.x)) : -Math.PI / 2;
    const siblings = fan[r.observer];
    const k = siblings.indexOf(r) - (siblings.length - 1) / 2;
    labels.push({ r, attrs, x: sx(c.x), y: sy(c.y), radius, preferred: toward + Math.PI + k * 0.7 });
  });
  for (const { r, attrs, x, y, radius, preferred } of labels) {  // above every circle
    const label = el("text", { "text-anchor": "middle" },
                     el("g", { class: "range label", ...attrs }, svg));
    label.textContent = `${r.peer} ${r.range_m.toFixed(1)} m`;
    const spot = labelSpot(x, y, radius, preferred,
                           label.getComputedTextLength() || 6.5 * label.textContent.length,
                           taken, width, height);
    label.setAttribute("x", spot.x.toFixed(1));
    label.setAttribute("y", (spot.y + 4).toFixed(1));
    taken.push(spot.box);
  }

  // issue 29: each link a peer is heard on, drawn by the link's kind (acoustic, rf, optical),
  // from this node's view of its own links and the others' (their status keys)
  const kinds = Object.fromEntries(((state.mission && state.mission.links) || [])
    .map((l) => [l.name, l.kind]));
  for (const hop of Object.values(state.hops)) {
    const a = places[hop.observer], b = places[hop.peer];
    if (!a || !b || hop.state === "down" || hop.observer > hop.peer
        && state.hops[hop.peer + "/" + hop.link + "/" + hop.observer]) continue;
    const line = el("line", { x1: sx(a.x), y1: sy(a.y), x2: sx(b.x), y2: sy(b.y),
                              class: `hop ${kinds[hop.link] || "acoustic"} ${hop.state}`,
                              "data-link": hop.link, "data-kind": kinds[hop.link] || "acoustic",
                              "data-nodes": [hop.observer, hop.peer].sort().join(" ") }, svg);
    el("title", {}, line).textContent = `${hop.link} (${kinds[hop.link]}): ${hop.observer} – `
      + `${hop.peer} ${hop.state}`;
  }

  // tracks
  for (const v of Object.values(state.nodes)) {
    for (const [source, track] of Object.entries(v.tracks)) {
      if (track.length < 2) continue;
      el("polyline", {
        class: "track " + source, "data-node": v.name,
        points: track.map((q) => `${sx(q[0]).toFixed(1)},${sy(q[1]).toFixed(1)}`).join(" "),
      }, svg);
    }
  }

  // fixes from the bridge's tracker: the 95 % uncertainty ellipse, and its state when it is
  // not tracking (coasting since..., or lost: then only the last fix, greyed, and why)
  for (const v of Object.values(state.nodes)) {
    const fix = v.position.fix;
    if (!fix) continue;
    const lost = v.lost && v.lost.time >= fix.time ? v.lost : null;
    const status = lost ? "lost" : (fix.state || "tracking");
    const g = el("g", { class: `fix ${status}`, "data-node": v.name, "data-state": status }, svg);
    const X = sx(fix.x), Y = sy(fix.y);
    const e = fix.ellipse;
    if (!lost && e) {
      el("ellipse", { cx: X, cy: Y, rx: Math.max(2, ELLIPSE_95 * e.major_m * scale),
                      ry: Math.max(2, ELLIPSE_95 * e.minor_m * scale),
                      transform: `rotate(${(-e.angle_deg).toFixed(1)} ${X.toFixed(1)} ${Y.toFixed(1)})`,
                      class: "uncertainty" }, g);
    } else if (!lost && fix.sigma_m) {
      el("circle", { cx: X, cy: Y, r: Math.max(2, fix.sigma_m * scale) }, g);
    }
    el("path", { d: `M${X - 6},${Y}h12M${X},${Y - 6}v12` }, g);
    if (status !== "tracking") {
      const text = lost ? `lost: ${String(lost.reason).replace(/_/g, " ")}`
        : `coasting ${age(fix.time - (fix.age_s || 0))}`;
      el("text", { x: X + 10, y: Y + 16, class: "fix-state" }, g).textContent = text;
    }
    el("title", {}, g).textContent = `${v.name} fix: x ${fix.x.toFixed(1)} m, y ${fix.y.toFixed(1)} m`
      + (e ? `, 95 % ellipse ${(ELLIPSE_95 * e.major_m).toFixed(2)} × ${(ELLIPSE_95 * e.minor_m).toFixed(2)} m` : "")
      + `, ${lost ? "lost: " + lost.reason : status}`;
  }

  // vehicles
  for (const [name, p] of Object.entries(places)) {
    const v = state.nodes[name];
    const stale = p.time !== null && now - p.time > STALE_S;
    const g = el("g", { class: `vehicle ${linkState(name)}${stale ? " stale" : ""}`,
                        "data-node": name, "data-state": linkState(name) }, svg);
    const X = sx(p.x), Y = sy(p.y);
    if (v.role === "surface") el("rect", { x: X - 7, y: Y - 7, width: 14, height: 14 }, g);
    else el("circle", { cx: X, cy: Y, r: 7 }, g);
    const label = el("text", { x: X + 10, y: Y + 4 }, g);
    label.textContent = name + (p.depth ? ` ${p.depth.toFixed(1)} m` : "");
    el("title", {}, g).textContent =
      `${name}: x ${p.x.toFixed(1)} m, y ${p.y.toFixed(1)} m, depth ${(p.depth || 0).toFixed(1)} m`
      + (p.time !== null ? `, ${age(p.time)} ago` : " (mission position)");
  }
}

const LABEL_STEPS = 48;  // candidate angles around a range circle for its label
const LABEL_GAP = 11;    // from a range circle to its label's centre line: half a line and some

function labelSpot(cx, cy, radius, preferred, textWidth, taken, width, height) {
  // The point of the circle nearest ``preferred`` (radians) where a label of ``textWidth``
  // overlaps none of ``taken`` and stays inside the map; the preferred point if none is free.
  const boxAt = (angle) => {  // the label's centre, far enough out that its box clears
    const out = radius + LABEL_GAP + Math.abs(Math.cos(angle)) * (textWidth / 2 + 4);
    const x = cx + out * Math.cos(angle), y = cy + out * Math.sin(angle);
    return { x, y, box: { x0: x - textWidth / 2 - 4, y0: y - 10, x1: x + textWidth / 2 + 4,
                          y1: y + 9 } };
  };
  const clear = (b) => b.x0 >= 0 && b.y0 >= 0 && b.x1 <= width && b.y1 <= height
    && !taken.some((t) => b.x0 < t.x1 && t.x0 < b.x1 && b.y0 < t.y1 && t.y0 < b.y1);
  for (let i = 0; i < LABEL_STEPS; i++) {  // 0, +1, -1, +2, -2 ... steps from the preferred
    const k = (i % 2 ? 1 : -1) * Math.ceil(i / 2);
    const spot = boxAt(preferred + k * 2 * Math.PI / LABEL_STEPS);
    if (clear(spot.box)) return spot;
  }
  return boxAt(preferred);
}

// ---- vehicles ------------------------------------------------------------------------------

function short(value) {
  // {x: 1.23456, vector: {y: 2}} -> "x 1.2346 · vector.y 2": easy to scan on a small screen
  const parts = [];
  const walk = (v, path) => {
    if (v && typeof v === "object" && !Array.isArray(v)) {
      for (const [k, x] of Object.entries(v)) walk(x, path ? path + "." + k : k);
      return;
    }
    let text;
    if (typeof v === "number" && !Number.isInteger(v)) text = String(Number(v.toPrecision(5)));
    else if (typeof v === "string") text = v;
    else text = JSON.stringify(v);
    parts.push(path ? path + " " + text : text);
  };
  walk(value, "");
  const text = parts.join(" · ");
  return text.length > 160 ? text.slice(0, 157) + "…" : text;
}

function make(tag, className, text, parent) {
  const node = document.createElement(tag);
  if (className) node.className = className;
  if (text !== undefined && text !== null) node.textContent = text;
  if (parent) parent.appendChild(node);
  return node;
}

function renderVehicles() {
  const box = document.getElementById("vehicles");
  const mission = state.mission;
  if (!mission) return;
  for (const node of mission.nodes) {
    const v = state.nodes[node.name];
    let card = box.querySelector(`.vehicle-card[data-node="${node.name}"]`);
    if (!card) {
      card = make("article", "vehicle-card", null, box);
      card.dataset.node = node.name;
      const head = make("header", null, null, card);
      make("h3", null, node.name, head);
      make("span", "role muted", node.role + " · address " + node.address, head);
      make("span", "badge link", "", head);
      make("span", "heard muted", "", head);
      make("div", "route muted", "", card);
      const table = make("table", null, null, card);
      const hr = make("tr", null, null, make("thead", null, null, table));
      for (const h of ["channel", "value", "age", "interval"]) make("th", null, h, hr);
      make("tbody", null, null, table);
    }
    const badge = card.querySelector(".link");
    if (node.name === mission.node) {
      const stats = state.stats[node.name];
      badge.textContent = stats ? "this node: bridge " + (serverNow() - stats.time < 5
        ? "running" : "silent") : "this node";
      badge.dataset.state = stats && serverNow() - stats.time < 5 ? "up" : "unknown";
    } else {
      const link = linkOf(node.name);
      const shown = linkState(node.name);
      badge.textContent = !link ? "link not known yet"
        : shown === "unknown" ? "not heard yet" : "link " + shown;
      badge.dataset.state = shown;
    }
    card.dataset.state = badge.dataset.state;
    renderZspace(card, node.name, mission.node);
    card.querySelector(".heard").textContent =
      node.name === mission.node ? "" : "last heard " + (v.heard ? age(v.heard) + " ago" : "never");
    card.querySelector(".route").textContent = routeText(node.name);
    const body = card.querySelector("tbody");
    const rows = Object.values(v.channels).sort((a, b) =>
      a.channel.localeCompare(b.channel) || a.element - b.element);
    if (!rows.length && !body.querySelector(".empty")) {
      const tr = make("tr", "empty", null, body);
      make("td", "muted", "nothing received yet", tr).colSpan = 4;
    }
    for (const item of rows) {
      const id = item.channel + "/" + item.element;
      let tr = body.querySelector(`tr[data-id="${CSS.escape(id)}"]`);
      if (!tr) {
        const empty = body.querySelector(".empty");
        if (empty) empty.remove();
        tr = make("tr", null, null, body);
        tr.dataset.id = id;
        tr.dataset.channel = item.channel;
        tr.dataset.element = item.element;
        const name = make("td", "channel", null, tr);
        item.channel.split("_").forEach((part, i) => {  // may wrap after "_", never mid-word
          if (i) { name.append("_"); make("wbr", null, null, name); }
          name.append(part);
        });
        make("div", "muted key", item.key, name);
        make("td", "value", "", tr);
        make("td", "age", "", tr);
        make("td", "interval", "", tr);
      }
      tr.querySelector(".value").textContent = short(item.value);
      tr.querySelector(".age").textContent = age(item.time);
      const cell = tr.querySelector(".interval");
      if (node.name === mission.node) {
        // this node's own inputs: how often the mission sends them, not how often a local
        // application happens to publish them
        const channel = mission.channels.find((c) => c.name === item.channel);
        cell.textContent = channel ? missionInterval(channel.interval_s) : "—";
        cell.title = "sent at most this often (mission); published here every "
          + duration(item.interval_s);
      } else {
        cell.textContent = duration(item.interval_s);
        cell.title = "time between the last two arrivals";
      }
      tr.dataset.count = item.count;
    }
  }
}

// Issue 29: the route this node's traffic to a peer takes (its hops, the link in use now),
// and a relay's load (the frames it carried on, those waiting per link).
function routeText(name) {
  const mission = state.mission;
  const parts = [];
  const route = mission.routes && mission.routes[name];
  const now = state.routes[mission.node + "/" + name];
  if (route && name !== mission.node) {
    // the link in use to its first hop: the policy's choice, or the one link they share
    const hop = route.path[1];
    const shared = (mission.links || []).filter(
      (l) => l.members.includes(mission.node) && l.members.includes(hop));
    const link = now && now.link ? now.link : shared.length === 1 ? shared[0].name : null;
    if (route.problem) parts.push("no route: " + route.problem);
    else if (route.path.length > 2 || link) {
      parts.push("route " + route.path.join(" → ") + (link ? ` over ${link}` : ""));
    }
  }
  const stats = state.stats[name];
  if (stats && (stats.relayed || Object.values(stats.carrying || {}).some((n) => n))) {
    const waiting = Object.entries(stats.carrying || {}).filter(([, n]) => n)
      .map(([link, n]) => `${n} waiting on ${link}`);
    parts.push(`relay: ${stats.relayed} frames carried` + (waiting.length ? ", " + waiting.join(", ") : ""));
  }
  return parts.join(" · ");
}

// Issue 15: what this node's applications want, its open queries, peers reached over IP.
function renderZspace(card, name, self) {
  const own = state.stats[self];
  let line = card.querySelector(".zspace");
  const parts = [];
  if (own && name === self) {
    if (own.wanted) parts.push("wants: " + (own.wanted.join(", ") || "nothing"));
    if (own.open_queries) parts.push("open queries: " + (own.open_queries.join(", ") || "none"));
    if (own.unmapped) parts.push("unmapped puts: " + own.unmapped.join(", "));
  } else if (own && own.ip_reachable && own.ip_reachable.includes(name)) {
    parts.push("surfaced: over IP, not bridged acoustically");
  }
  if (!parts.length) { if (line) line.remove(); return; }
  if (!line) line = make("p", "zspace muted", null, card.querySelector("header"));
  line.textContent = parts.join(" · ");
  line.dataset.surfaced = String(name !== self);
}

// ---- events --------------------------------------------------------------------------------

let shownEvents = 0;

function renderEvents() {
  const list = document.getElementById("events");
  if (shownEvents > state.events.length) { list.textContent = ""; shownEvents = 0; }
  for (const item of state.events.slice(shownEvents)) {
    const li = document.createElement("li");
    li.className = item.level;
    li.dataset.category = item.category;
    make("time", "muted", clockText(item.time), li);
    make("span", null, " " + item.text, li);
    list.insertBefore(li, list.firstChild);
  }
  shownEvents = state.events.length;
  while (list.children.length > MAX_EVENTS) list.removeChild(list.lastChild);
}

// ---- commands ------------------------------------------------------------------------------

function commandChannels(vehicleName) {
  return state.mission.commands.filter((c) => c.destinations.includes(vehicleName));
}

function setupPage() {
  const mission = state.mission;
  document.getElementById("mission").textContent = mission.mission + " from " + mission.node;
  document.title = "zab " + mission.mission;
  document.getElementById("vehicles").textContent = "";
  document.getElementById("events").textContent = "";
  document.getElementById("commands").textContent = "";
  shownEvents = 0;
  const vehicles = [];
  for (const c of mission.commands) {
    for (const d of c.destinations) if (!vehicles.includes(d)) vehicles.push(d);
  }
  const select = document.getElementById("command-vehicle");
  const chosen = select.value;
  select.textContent = "";
  for (const name of vehicles) make("option", null, name, select).value = name;
  if (vehicles.includes(chosen)) select.value = chosen;
  document.getElementById("command-form").hidden = !vehicles.length;
  if (!vehicles.length) {
    document.getElementById("command-note").textContent =
      mission.node + " sends no channel to other nodes: nothing to command.";
  }
  fillChannels();
}

function fillChannels() {
  const vehicleName = document.getElementById("command-vehicle").value;
  const select = document.getElementById("command-channel");
  const chosen = select.value;
  select.textContent = "";
  for (const c of commandChannels(vehicleName)) {
    make("option", null, c.channel + (c.reliable ? " (acknowledged)" : ""), select).value =
      c.channel;
  }
  if ([...select.options].some((o) => o.value === chosen)) select.value = chosen;
  fillFields();
}

function fieldInput(field) {
  let input;
  if (field.kind === "enum") {
    input = document.createElement("select");
    for (const value of field.values) make("option", null, value, input).value = value;
  } else if (field.kind === "boolean") {
    input = document.createElement("input");
    input.type = "checkbox";
  } else if (field.kind === "number" || field.kind === "integer") {
    input = document.createElement("input");
    input.type = "number";
    input.step = field.kind === "integer" ? "1" : "any";
    input.inputMode = field.kind === "integer" ? "numeric" : "decimal";
    if (field.minimum !== null) input.min = field.minimum;
    if (field.maximum !== null) input.max = field.maximum;
    input.required = true;
  } else if (field.kind === "string") {
    input = document.createElement("input");
    input.type = "text";
    if (field.max_length) input.maxLength = field.max_length;
  } else {
    input = document.createElement("textarea");
    input.rows = 2;
    input.placeholder = "JSON";
  }
  input.dataset.path = field.path;
  input.dataset.kind = field.kind;
  input.name = field.path || "payload";
  return input;
}

function fillFields() {
  const box = document.getElementById("command-fields");
  box.textContent = "";
  const channel = currentChannel();
  const note = document.getElementById("command-note");
  if (!channel) { note.textContent = "no command channel reaches this vehicle"; return; }
  const others = channel.destinations.filter(
    (d) => d !== document.getElementById("command-vehicle").value);
  note.textContent = (channel.reliable ? "acknowledged: shows delivered or failed"
    : "best effort: shows sent; no delivery report")
    + (others.length ? " · also reaches " + others.join(", ") : "");
  channel.elements.forEach((element, index) => {
    const group = make("fieldset", null, null, box);
    group.dataset.element = index;
    make("legend", "muted", element.key, group);
    for (const field of element.fields) {
      const label = make("label", "field", null, group);
      make("span", "name", field.path || "(payload)", label);
      label.appendChild(fieldInput(field));
      const bounds = [];
      if (field.minimum !== null && field.maximum !== null) {
        bounds.push(`${field.minimum} … ${field.maximum}`);
      }
      if (field.units) bounds.push(field.units);
      if (bounds.length) make("span", "muted bounds", bounds.join(" "), label);
      if (field.description) label.title = field.description;
    }
  });
}

function currentChannel() {
  const name = document.getElementById("command-channel").value;
  return state.mission.commands.find((c) => c.channel === name) || null;
}

function readValue(input) {
  if (input.dataset.kind === "boolean") return input.checked;
  if (input.dataset.kind === "number" || input.dataset.kind === "integer") {
    return input.value === "" ? "" : Number(input.value);
  }
  return input.value;
}

function sendCommand(event) {
  event.preventDefault();
  const error = document.getElementById("command-error");
  error.textContent = "";
  const channel = currentChannel();
  if (!channel) return;
  const values = [];
  for (const group of document.querySelectorAll("#command-fields fieldset")) {
    const element = {};
    for (const input of group.querySelectorAll("[data-path]")) {
      if (!input.checkValidity()) {
        error.textContent = `${input.dataset.path || "payload"}: ${input.validationMessage}`;
        input.focus();
        return;
      }
      element[input.dataset.path] = readValue(input);
    }
    values.push(element);
  }
  if (!socket || socket.readyState !== WebSocket.OPEN) {
    error.textContent = "not connected to the GUI server";
    return;
  }
  requestId += 1;
  socket.send(JSON.stringify({
    type: "command", request: requestId, channel: channel.channel,
    vehicle: document.getElementById("command-vehicle").value, values,
  }));
}

function onReply(message) {
  if (!message.ok) {
    document.getElementById("command-error").textContent = message.error || "refused";
  }
}

function renderCommands() {
  const list = document.getElementById("commands");
  const commands = Object.values(state.commands).sort((a, b) => b.time - a.time).slice(0, 20);
  list.textContent = "";
  for (const c of commands) {
    const li = make("li", "command", null, list);
    li.dataset.ref = c.ref;
    li.dataset.state = c.state;
    li.dataset.channel = c.channel;
    li.dataset.vehicle = c.vehicle;
    make("time", "muted", clockText(c.time), li);
    make("span", null, ` ${c.channel} → ${c.vehicle} `, li);
    make("span", "badge state", c.state + (c.state === "pending" && c.detail
      ? " (" + c.detail + ")" : ""), li).dataset.state = c.state;
    const values = Array.isArray(c.values) && c.values.length === 1 ? c.values[0] : c.values;
    make("div", "muted", short(values) + (c.reason ? " · " + c.reason : "")
      + (Object.keys(c.others).length ? " · others: " + Object.entries(c.others)
        .map(([k, v]) => k + " " + v).join(", ") : ""), li);
  }
}

// ---- main loop -----------------------------------------------------------------------------

let lastRender = 0;

function frame(t) {
  const since = t - lastRender;
  if (state.mission && ((dirty && since > MIN_RENDER_MS) || since > RENDER_MS)) {
    dirty = false;
    lastRender = t;
    renderConnection();
    renderMap();
    renderVehicles();
    renderEvents();
    renderCommands();
    imageView.render();
  } else if (state.mission && mapDirty) {
    renderMap();
  } else if (!state.mission && since > RENDER_MS) {
    lastRender = t;
    renderConnection();
  }
  requestAnimationFrame(frame);
}

document.getElementById("command-vehicle").addEventListener("change", fillChannels);
document.getElementById("command-channel").addEventListener("change", fillFields);
document.getElementById("command-form").addEventListener("submit", sendCommand);
document.getElementById("map-fit").addEventListener("click", () => mapView.fit());
document.getElementById("map-zoom-in").addEventListener("click", () => mapView.zoomIn());
document.getElementById("map-zoom-out").addEventListener("click", () => mapView.zoomOut());
window.addEventListener("resize", () => { dirty = true; });
connect();
requestAnimationFrame(frame);

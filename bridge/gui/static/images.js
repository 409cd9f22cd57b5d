// Pictures of the image channels: the latest of each camera refining live, bytes against
// the budget, and the region of interest drawn with the mouse (or a finger) on the picture.
"use strict";

const imageView = {
  items: {},        // "channel/camera" -> latest image item
  cards: {},        // "channel/camera" -> its elements
  channels: [],     // from the hello: each channel's settings
  error: "",

  reset(channels) {
    this.items = {};
    this.cards = {};
    this.channels = channels || [];
    const panel = document.getElementById("images-panel");
    const box = document.getElementById("pictures");
    box.replaceChildren();
    panel.hidden = this.channels.length === 0;
    for (const ch of this.channels) {
      for (const cam of ch.cameras) this.card(ch, cam, box);
    }
  },

  apply(item) {
    this.items[item.channel + "/" + item.node] = item;
  },

  send(message) {
    if (!socket || socket.readyState !== WebSocket.OPEN) {
      this.error = "not connected";
      return;
    }
    this.error = "";
    socket.send(JSON.stringify({type: "image_control", ...message}));
  },

  onReply(message) {
    this.error = message.ok ? "" : (message.error || "refused");
  },

  card(ch, cam, box) {
    const figure = make("figure", "picture", null, box);
    figure.dataset.channel = ch.channel;
    figure.dataset.node = cam;
    const frameBox = make("div", "picture-frame", null, figure);
    const img = make("img", "", null, frameBox);
    img.alt = `${ch.channel} from ${cam}`;
    img.draggable = false;
    const roi = make("div", "roi", null, frameBox);
    const draft = make("div", "roi draft", null, frameBox);
    roi.hidden = draft.hidden = true;
    const caption = make("figcaption", "", `${cam} · ${ch.channel}: waiting for a picture`,
                         figure);
    const bar = make("div", "picture-bytes", null, figure);
    const fill = make("span", "", null, bar);
    const tools = make("div", "row", null, figure);
    const now = make("button", "", "Request now", tools);
    now.type = "button";
    const send = (message) => this.send({channel: ch.channel, camera: cam, ...message});
    now.addEventListener("click", () => send({request: "now"}));
    const cancel = make("button", "", "Cancel", tools);
    cancel.type = "button";
    cancel.addEventListener("click", () => send({request: "cancel"}));
    const clear = make("button", "", "Clear ROI", tools);
    clear.type = "button";
    clear.addEventListener("click", () => send({roi: null}));
    const budget = make("input", "budget", null, tools);
    budget.type = "number";
    budget.min = String(ch.min_budget_bytes);
    budget.max = String(ch.max_budget_bytes);
    budget.value = String(ch.budget_bytes);
    budget.title = "bytes per picture";
    make("span", "unit", "B", tools);
    const side = (name, value) => {
      const input = make("input", "side " + name, null, tools);
      input.type = "number";
      input.min = "8";
      input.max = "2048";
      input.value = String(value);
      input.title = name + " in pixels";
      return input;
    };
    const width = side("width", ch.width);
    make("span", "", "×", tools);
    const height = side("height", ch.height);
    const apply = make("button", "", "Apply", tools);
    apply.type = "button";
    apply.title = "send the budget and size for the next picture";
    apply.addEventListener("click", () => send(
      {budget_bytes: parseInt(budget.value, 10), width: parseInt(width.value, 10),
       height: parseInt(height.value, 10)}));
    const error = make("span", "error", "", tools);
    error.setAttribute("role", "alert");
    const card = {figure, frameBox, img, roi, draft, caption, fill, error, camera: cam, shown: 0,
                  pending: null};
    this.cards[ch.channel + "/" + cam] = card;
    this.drawing(ch, card);
  },

  drawing(ch, card) {
    let start = null;
    const at = (event) => {
      const r = card.img.getBoundingClientRect();
      const p = event.touches ? event.touches[0] : event;
      return [Math.min(1, Math.max(0, (p.clientX - r.left) / r.width)),
              Math.min(1, Math.max(0, (p.clientY - r.top) / r.height))];
    };
    const rect = (a, b) => [Math.min(a[0], b[0]), Math.min(a[1], b[1]),
                            Math.max(a[0], b[0]), Math.max(a[1], b[1])];
    const down = (event) => {
      if (!card.img.naturalWidth) return;
      event.preventDefault();
      start = at(event);
      this.place(card.draft, [...start, ...start]);
      card.draft.hidden = false;
    };
    const move = (event) => {
      if (!start) return;
      event.preventDefault();
      this.place(card.draft, rect(start, at(event)));
    };
    const up = (event) => {
      if (!start) return;
      const r = rect(start, event.changedTouches ? at({touches: event.changedTouches}) : at(event));
      start = null;
      if (r[2] - r[0] < 0.03 || r[3] - r[1] < 0.03) {  // a click, not a rectangle
        card.draft.hidden = true;
        return;
      }
      card.pending = r;
      this.place(card.draft, r);
      this.send({channel: ch.channel, camera: card.camera,
                 roi: r.map((v) => Math.round(v * 1000) / 1000)});
    };
    card.frameBox.addEventListener("mousedown", down);
    window.addEventListener("mousemove", move);
    window.addEventListener("mouseup", up);
    card.frameBox.addEventListener("touchstart", down, {passive: false});
    card.frameBox.addEventListener("touchmove", move, {passive: false});
    card.frameBox.addEventListener("touchend", up);
  },

  place(box, r) {
    box.style.left = (r[0] * 100) + "%";
    box.style.top = (r[1] * 100) + "%";
    box.style.width = ((r[2] - r[0]) * 100) + "%";
    box.style.height = ((r[3] - r[1]) * 100) + "%";
  },

  render() {
    for (const [name, card] of Object.entries(this.cards)) {
      const item = this.items[name];
      card.error.textContent = this.error;
      if (!item) continue;
      if (card.shown !== item.version) {
        card.shown = item.version;
        card.img.src = item.url;
      }
      const m = item.meta || {};
      const budget = m.budget || 0;
      card.figure.dataset.bytes = String(m.bytes || 0);
      card.figure.dataset.final = String(!!m.final);
      card.figure.dataset.size = `${m.width}x${m.height}`;
      card.caption.textContent = `${item.node} · ${item.channel}` +
        (m.whole ? ` · the camera's own picture, over IP: ${m.bytes} B`
          : ` #${m.sequence}: ${m.bytes} / ${budget} B` + (m.final ? " · complete" : "")) +
        (typeof m.psnr_estimate === "number" ? ` · ≈${m.psnr_estimate.toFixed(1)} dB` : "") +
        ` · ${m.width}×${m.height}` + ` · ${age(item.time)}`;
      card.fill.style.width = budget ? Math.min(100, 100 * m.bytes / budget) + "%" : "0";
      if (m.roi) {
        this.place(card.roi, m.roi);
        card.roi.hidden = false;
        card.figure.dataset.roi = m.roi.join(",");
      } else {
        card.roi.hidden = true;
        delete card.figure.dataset.roi;
      }
      if (card.pending && m.roi && m.roi.every((v, i) => Math.abs(v - card.pending[i]) < 0.02)) {
        card.pending = null;  // the camera sends with the drawn ROI now
        card.draft.hidden = true;
      }
    }
  },
};

// The results page (recon/page/build.py): cards from .recon-page/data.js; 3D models loaded as
// scripts (.recon-page/models/<id>.js call RECON_MODEL) when their viewer scrolls into view,
// dropped when it scrolls far away, so a page of thousands of results stays light.
(function () {
  "use strict";
  const D = window.RECON_PAGE;
  const urls = {};      // model id -> blob URL
  const waiting = {};   // model id -> callbacks
  const state = window.RECON_STATE = { loaded: 0, viewers: 0, errors: [] };

  window.RECON_MODEL = function (id, b64) {
    const bin = atob(b64);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    urls[id] = URL.createObjectURL(new Blob([bytes], { type: "model/gltf-binary" }));
    (waiting[id] || []).forEach((f) => f(urls[id]));
    delete waiting[id];
  };

  function model(id, done) {
    if (urls[id]) return done(urls[id]);
    if (waiting[id]) return waiting[id].push(done);
    waiting[id] = [done];
    const s = document.createElement("script");
    s.src = D.dir + "/models/" + id + ".js";
    s.onerror = () => state.errors.push("model " + id + " is missing");
    document.head.appendChild(s);
  }

  function el(tag, attrs, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === "text") e.textContent = v; else e.setAttribute(k, v);
    }
    for (const c of children) if (c) e.appendChild(c);
    return e;
  }

  function numbers(rows) {
    const t = el("table");
    for (const [k, v] of rows) t.appendChild(el("tr", {}, el("td", { text: k }), el("td", { text: String(v) })));
    return t;
  }

  // A viewer slot: shows views[current] while on screen (IntersectionObserver below).
  function viewer(views) {
    const box = el("div", { class: "viewer" });
    box.views = views;
    box.current = 0;
    if (!D.viewer) {
      box.appendChild(el("div", { class: "note", text: "3D view: the viewer is not installed (bash scripts/setup.sh)" }));
      return box;
    }
    box.appendChild(el("div", { class: "note", text: "3D view loads when shown" }));
    observer.observe(box);
    return box;
  }

  function show(box) {
    if (box.mv) return;
    const v = box.views[box.current];
    const mv = el("model-viewer", { "camera-controls": "", "interaction-prompt": "none", "shadow-intensity": "0.6",
      "exposure": "1.0", "alt": v.label + " (" + v.file + ")" });
    if (v.animated) mv.setAttribute("autoplay", "");
    mv.addEventListener("load", () => { state.loaded++; box.dataset.loaded = "1"; box.firstChild.hidden = true; });
    mv.addEventListener("error", (e) => state.errors.push("viewer: " + v.file + ": " + (e.detail && e.detail.type)));
    box.mv = mv;
    box.appendChild(mv);
    state.viewers++;
    model(v.id, (url) => { if (box.mv === mv) mv.src = url; });
  }

  function hide(box) {
    if (!box.mv) return;
    box.mv.remove();
    box.mv = null;
    delete box.dataset.loaded;
    box.firstChild.hidden = false;
    state.viewers--;
  }

  const observer = "IntersectionObserver" in window ? new IntersectionObserver((entries) => {
    for (const e of entries) (e.isIntersecting ? show : hide)(e.target);
  }, { rootMargin: "300px 0px" }) : { observe: show };

  function controls(box, views) {
    const bar = el("div", { class: "controls" });
    const buttons = views.map((v, i) => {
      const b = el("button", { type: "button", text: v.label, class: i === 0 ? "on" : "" });
      b.onclick = () => {
        box.current = i;
        buttons.forEach((x, j) => x.className = j === i ? "on" : "");
        if (box.mv) { hide(box); show(box); }
      };
      return b;
    });
    if (views.length > 1) buttons.forEach((b) => bar.appendChild(b));
    if (views.some((v) => v.animated)) {
      const p = el("button", { type: "button", text: "pause" });
      p.onclick = () => {
        if (!box.mv) return;
        if (box.mv.paused) { box.mv.play(); p.textContent = "pause"; } else { box.mv.pause(); p.textContent = "play"; }
      };
      bar.appendChild(p);
      bar.appendChild(el("span", { text: " preview: in place, the cloth follows the skeleton (the .glb has the path and the cloth's motion) " }));
    }
    for (const v of views) bar.appendChild(el("a", { href: v.file, text: v.file.split("/").pop() }));
    return bar;
  }

  function person(p) {
    const d = el("div", { class: "person" }, el("h3", { text: p.label }));
    if (p.views.length) {
      const box = viewer(p.views);
      d.appendChild(controls(box, p.views));
      d.appendChild(box);
    }
    if (p.numbers.length) d.appendChild(numbers(p.numbers));
    const files = el("div", { class: "files" });
    for (const f of p.files) files.appendChild(el("a", { href: f.href, text: f.label }));
    d.appendChild(files);
    return d;
  }

  function card(item) {
    const c = el("article", { class: "card", "data-key": item.key.toLowerCase() }, el("h2", { text: item.key }));
    if (item.images.length) {
      const imgs = el("div", { class: "images" });
      for (const im of item.images) {
        imgs.appendChild(el("figure", {}, el("a", { href: im.src }, el("img", { src: im.src, loading: "lazy",
          alt: im.label, decoding: "async" })), el("figcaption", { text: im.label })));
      }
      c.appendChild(imgs);
    }
    for (const p of item.people) c.appendChild(person(p));
    return c;
  }

  function render() {
    const summary = document.getElementById("summary");
    for (const [k, v] of D.summary) summary.appendChild(el("span", {}, document.createTextNode(k + ": "),
      el("b", { text: String(v) })));
    summary.appendChild(el("span", { text: "recon " + D.recon }));
    const links = document.getElementById("links");
    for (const l of D.links) links.appendChild(el("a", { href: l.href, text: l.label }));
    for (const v of D.videos || []) {
      links.after(el("figure", { class: "clip" }, el("video", { src: v.src, controls: "", muted: "", loop: "",
        playsinline: "", preload: "metadata" }), el("figcaption", { text: v.label })));
    }
    const main = document.getElementById("items");
    const frag = document.createDocumentFragment();
    for (const item of D.items) frag.appendChild(card(item));
    main.appendChild(frag);
    if (D.missing.length) {
      const sec = document.getElementById("missing");
      sec.appendChild(el("h2", { text: "Not reconstructed (" + D.missing.length + ")" }));
      const ul = el("ul");
      for (const m of D.missing) {
        ul.appendChild(el("li", { "data-key": m.key.toLowerCase() },
          m.image ? el("img", { src: m.image.src, loading: "lazy", alt: m.key }) : null,
          el("b", { text: m.key }), document.createTextNode(": " + m.why)));
      }
      sec.appendChild(ul);
    }
    const notes = document.getElementById("notes");
    for (const n of D.notes) notes.appendChild(el("div", { text: n }));
    document.getElementById("filter").addEventListener("input", (e) => {
      const q = e.target.value.toLowerCase();
      for (const c of document.querySelectorAll("[data-key]")) c.style.display = c.dataset.key.includes(q) ? "" : "none";
    });
    state.cards = D.items.length;
    document.body.dataset.ready = "1";
  }

  render();
})();

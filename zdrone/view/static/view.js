// zdrone fleet view: the page's own script (no library, no outside request).
// It follows /api/stream (server-sent events): "init" (the fleet's geometry, the tracks so far), then
// "picture" (every drone, every GS's link, the authority feed). Without a stream every drone is shown
// stale: nothing on this page is shown as live unless a live stream says so. Any error of the page's
// own (a bug, a picture it cannot show) stops it and shows everything stale: a page that may be wrong
// never says "live". Names (drones, GSs) are data: they key Maps, never an object's properties.
"use strict";
(function () {
  const SVG = "http://www.w3.org/2000/svg";
  const PALETTE = ["#1565c0", "#e65100", "#6a1b9a", "#00897b", "#c2185b", "#5d4037", "#7cb342", "#455a64"];
  const NOBODY = "#888";
  const W = 1000, H = 600;
  const state = { geo: null, proj: null, colours: new Map(), tracks: new Map(), rows: new Map(), marks: new Map(),
                  connected: false, broken: null, last: null, source: null };
  const $ = (id) => document.getElementById(id);

  // ------------------------------------------------------------------ a page that may be wrong is not live
  function fail(what) {
    if (state.broken) return;
    state.broken = String(what || "error").slice(0, 200);
    state.connected = false;
    if (state.source) state.source.close();
    const c = $("conn");
    if (c) {
      c.className = "conn down";
      c.dataset.state = "error";
      c.textContent = "page error — nothing shown is live (" + state.broken + "); reload the page";
    }
    for (const r of state.rows.values()) {
      r.tr.classList.add("stale");
      r.tr.dataset.stale = "true";
      r.cells.age.textContent = "STALE (page error)";
      r.text.age = null;
    }
    for (const m of state.marks.values()) m.dot.classList.add("stale");
  }
  function guard(fn) {
    return function (ev) {
      if (state.broken) return;
      try { fn(ev); } catch (e) { fail(e && e.message ? e.message : e); }
    };
  }
  window.addEventListener("error", (ev) => fail(ev.message || "script error"));
  window.addEventListener("unhandledrejection", (ev) => fail(ev.reason && ev.reason.message ? ev.reason.message : "rejected promise"));

  function el(tag, attrs, parent) {
    const e = document.createElementNS(SVG, tag);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
    if (parent) parent.appendChild(e);
    return e;
  }
  function colour(owner) { return owner && state.colours.has(owner) ? state.colours.get(owner) : NOBODY; }
  function metres(lat, lon) {
    const h = state.geo.home || state.geo.stations[0] || { lat: lat, lon: lon };
    return [(lon - h.lon) * 111320 * Math.cos(h.lat * Math.PI / 180), (lat - h.lat) * 110574];
  }

  function setGeometry(geo) {
    state.geo = geo;
    geo.stations.forEach((s, i) => { state.colours.set(s.name, PALETTE[i % PALETTE.length]); });
    let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
    for (const s of geo.stations) {
      const [x, y] = metres(s.lat, s.lon);
      x0 = Math.min(x0, x - s.radius_m); x1 = Math.max(x1, x + s.radius_m);
      y0 = Math.min(y0, y - s.radius_m); y1 = Math.max(y1, y + s.radius_m);
    }
    if (!isFinite(x0)) { x0 = -500; x1 = 500; y0 = -300; y1 = 300; }
    const pad = 0.06 * Math.max(x1 - x0, y1 - y0);
    x0 -= pad; x1 += pad; y0 -= pad; y1 += pad;
    const k = Math.min(W / (x1 - x0), H / (y1 - y0));
    const ox = (W - k * (x1 - x0)) / 2, oy = (H - k * (y1 - y0)) / 2;
    state.proj = (lat, lon) => { const [x, y] = metres(lat, lon); return [ox + k * (x - x0), H - (oy + k * (y - y0))]; };
    state.k = k;
    const cov = $("coverage");
    cov.replaceChildren();
    const legend = $("legend");
    legend.replaceChildren();
    for (const s of geo.stations) {
      const [cx, cy] = state.proj(s.lat, s.lon);
      const c = colour(s.name);
      el("circle", { cx: cx, cy: cy, r: s.radius_m * k, class: "cov", fill: c, stroke: c }, cov);
      el("rect", { x: cx - 5, y: cy - 5, width: 10, height: 10, fill: c }, cov);
      const t = el("text", { x: cx + 8, y: cy - 8, class: "gs-label", fill: c }, cov);
      t.textContent = "GS " + s.name;
      const item = document.createElement("span");
      item.style.color = c;
      item.textContent = "■ " + s.name + " (" + Math.round(s.radius_m) + " m)";
      legend.appendChild(item);
    }
    const note = document.createElement("span");
    note.textContent = "overlap: where the circles cross — track colour: the GS holding authority";
    legend.appendChild(note);
  }

  function addPoint(drone, lat, lon, owner) {
    if (!state.proj) return;
    const [x, y] = state.proj(lat, lon);
    let segs = state.tracks.get(drone);
    if (!segs) { segs = []; state.tracks.set(drone, segs); }
    let seg = segs[segs.length - 1];
    if (!seg || seg.owner !== owner) {
      const start = seg ? [seg.pts[seg.pts.length - 1]] : [];
      seg = { owner: owner, pts: start, line: el("polyline", { class: "track", stroke: colour(owner), "data-drone": drone, "data-owner": owner || "" }, $("tracks")) };
      segs.push(seg);
    } else {
      const [px, py] = seg.pts[seg.pts.length - 1];
      if (Math.abs(px - x) + Math.abs(py - y) < 1) return;
    }
    seg.pts.push([x, y]);
    seg.line.setAttribute("points", seg.pts.map((p) => p[0].toFixed(1) + "," + p[1].toFixed(1)).join(" "));
  }

  const COLS = ["drone", "owner", "epoch", "authority", "links", "mode", "alt", "armed", "mission", "fc", "requests", "failsafe", "age"];
  function row(drone) {
    let r = state.rows.get(drone);
    if (r) return r;
    const tr = document.createElement("tr");
    tr.dataset.drone = drone;
    const cells = {};
    for (const c of COLS) {
      const td = document.createElement("td");
      td.className = c;
      tr.appendChild(td);
      cells[c] = td;
    }
    const rows = $("rows");
    const after = Array.from(rows.children).find((x) => x.dataset.drone.localeCompare(drone, undefined, { numeric: true }) > 0);
    rows.insertBefore(tr, after || null);
    r = { tr: tr, cells: cells, text: {} };
    state.rows.set(drone, r);
    return r;
  }
  function put(r, col, text) {
    if (r.text[col] === text) return;
    r.text[col] = text;
    r.cells[col].textContent = text;
  }
  function age(a) { return a === null || a === undefined ? "never" : a.toFixed(1) + " s"; }

  function showDrone(d) {
    const r = row(d.drone);
    const stale = d.stale || !state.connected || !!state.broken;
    r.tr.classList.toggle("stale", stale);
    r.tr.classList.toggle("failsafe", !!d.failsafe);
    r.tr.dataset.owner = d.owner || "";
    r.tr.dataset.epoch = String(d.epoch);
    r.tr.dataset.verified = String(!!d.verified);
    r.tr.dataset.stale = String(stale);
    r.tr.dataset.failsafe = String(!!d.failsafe);
    put(r, "drone", d.drone);
    const o = r.cells.owner;
    // the owner as the drone itself signed it, recently (✓), else as it last signed it or as a GS says it
    // (unverified); claims the drone's word does not back are listed apart and never shown as the owner
    const claims = d.unverified.map((c) => c.gs + " says " + (c.owner || "nobody") + " @" + c.epoch).join(", ");
    const signedOld = !d.verified && d.attested_age !== null && d.attested_age !== undefined;
    const ownerText = (d.owner || "nobody") + (d.verified ? " ✓" : signedOld ? " (signed " + d.attested_age.toFixed(1) + " s ago)" : " (unverified)")
      + (d.disputed.length ? " (disputed: " + d.disputed.join(" vs ") + ")" : "") + (claims ? " · unverified: " + claims : "");
    if (r.text.owner !== ownerText) {
      r.text.owner = ownerText;
      o.replaceChildren();
      const sw = document.createElement("span");
      sw.className = "swatch";
      sw.style.background = colour(d.owner);
      o.appendChild(sw);
      o.appendChild(document.createTextNode((d.owner || "nobody") + (d.verified ? " ✓" : "")));
      if (signedOld) o.appendChild(Object.assign(document.createElement("span"), { className: "unverified", textContent: " (signed " + d.attested_age.toFixed(1) + " s ago)", title: "the drone's newest signed word is not recent" }));
      else if (!d.verified) o.appendChild(Object.assign(document.createElement("span"), { className: "unverified", textContent: " (unverified)", title: "no valid signature of the drone: a GS's word only" }));
      if (d.disputed.length) o.appendChild(document.createTextNode(" (disputed: " + d.disputed.join(" vs ") + ")"));
      if (claims) o.appendChild(Object.assign(document.createElement("span"), { className: "unverified claims", textContent: " · unverified: " + claims, title: "claims the drone's signed word does not back" }));
      o.title = d.verified ? "signed by the drone, recently" : "";
      o.classList.toggle("disputed", d.disputed.length > 0);
    }
    put(r, "epoch", String(d.epoch));
    put(r, "authority", d.state + (d.pending_to ? " → " + d.pending_to : ""));
    const links = Object.entries(d.links).map(([g, l]) =>
      g + " " + (l.silent ? "GS silent" : l.link) + (l.age !== null ? " " + l.age.toFixed(1) + "s" : "") + (l.holds ? " ★" : "")).join(" · ");
    put(r, "links", links);
    put(r, "mode", d.mode || "");
    put(r, "alt", d.position ? d.position[2].toFixed(1) : "–");
    put(r, "armed", d.armed ? "ARMED" : "disarmed");
    put(r, "mission", (d.mission_seq === null ? "–" : "item " + d.mission_seq) + (d.stage ? " · " + d.stage : ""));
    put(r, "fc", d.fc_signed === null ? "?" : (d.fc_signed ? "signed" : "UNSIGNED"));
    put(r, "requests", d.requests.map((q) => q.requester + "→" + q.to + " " + q.consent + " (GS " + q.at + "'s report, " + q.age_s.toFixed(0) + "/" + q.timeout_s.toFixed(0) + " s)").join("; ")
      + (d.takeover ? " takeover allowed" + (d.takeover_to ? " for " + d.takeover_to : "") : ""));
    const reports = (d.reports_failsafe || []).filter((g) => !d.failsafe);
    put(r, "failsafe", d.failsafe ? "FAILSAFE" : (reports.length ? "reported by " + reports.join(", ") + " (unverified)" : ""));
    put(r, "age", (stale ? "STALE " : "live ") + (state.broken ? "(page error)" : state.connected ? age(d.age) : "(no stream)"));
    if (d.position) {
      addPoint(d.drone, d.position[0], d.position[1], d.owner);
      const [x, y] = state.proj ? state.proj(d.position[0], d.position[1]) : [0, 0];
      let m = state.marks.get(d.drone);
      if (!m) {
        m = { dot: el("circle", { r: 7, class: "drone", "data-drone": d.drone }, $("drones")),
              label: el("text", { class: "drone-label" }, $("drones")) };
        m.label.textContent = d.drone;
        state.marks.set(d.drone, m);
      }
      m.dot.setAttribute("cx", x.toFixed(1)); m.dot.setAttribute("cy", y.toFixed(1));
      m.dot.setAttribute("fill", colour(d.owner));
      m.dot.dataset.from = d.position_from || "";
      // where it is, as a GS reported it: named when that GS is not the owner the drone signed
      const label = d.drone + (d.position_from && d.position_from !== d.owner ? " (per " + d.position_from + ")" : "");
      if (m.label.textContent !== label) m.label.textContent = label;
      m.dot.classList.toggle("stale", stale);
      m.label.setAttribute("x", (x + 9).toFixed(1)); m.label.setAttribute("y", (y - 9).toFixed(1));
    } else {
      const m = state.marks.get(d.drone);
      if (m) m.dot.classList.toggle("stale", true);  // where it was last heard, never shown as live
    }
  }

  function showFeed(feed) {
    const ol = $("feed");
    const items = feed.slice(0, 80).map((e) => {
      const li = document.createElement("li");
      const t = new Date(e.t * 1000);
      li.textContent = t.toTimeString().slice(0, 8) + "." + String(t.getMilliseconds()).padStart(3, "0") +
        "  " + e.gs + " | " + e.drone + " " + e.kind + ": " + e.text;
      li.dataset.kind = e.kind;
      return li;
    });
    ol.replaceChildren(...items);
  }

  function showPicture(p) {
    state.last = p;
    for (const d of p.drones) showDrone(d);
    showFeed(p.feed);
    $("report").hidden = !p.report;
    const drops = Object.entries(p.drops || {}).map(([k, v]) => k + " " + v).join(", ");
    $("drops").textContent = "parts opened " + p.opened + (drops ? "; dropped: " + drops : "; nothing dropped") +
      "; GSs heard: " + Object.entries(p.stations).map(([g, s]) => g + (s.silent ? " (silent " + s.age.toFixed(1) + " s)" : "")).join(", ") +
      (p.revision ? "; fleet revision " + p.revision : "");
    $("clock").textContent = new Date(p.server_time * 1000).toTimeString().slice(0, 8);
  }

  function setConnected(up) {
    if (state.broken) return;
    state.connected = up;
    const c = $("conn");
    c.className = "conn " + (up ? "up" : "down");
    c.dataset.state = up ? "live" : "disconnected";
    c.textContent = up ? "live" : "no stream — reconnecting; everything shown is stale";
    if (!up && state.last) for (const d of state.last.drones) showDrone(d);
  }

  function connect() {
    const es = new EventSource("/api/stream");
    state.source = es;
    es.addEventListener("init", guard((ev) => {
      const init = JSON.parse(ev.data);
      if (!state.geo) {
        setGeometry(init.geometry);
        for (const [drone, pts] of Object.entries(init.tracks)) for (const [lat, lon, owner] of pts) addPoint(drone, lat, lon, owner);
      }
      setConnected(true);
    }));
    es.addEventListener("picture", guard((ev) => { if (!state.connected) setConnected(true); showPicture(JSON.parse(ev.data)); }));
    es.onerror = guard(() => setConnected(false));  // EventSource reconnects by itself (the stream's retry)
  }
  // the token, if it came in the address, leaves it (and the history): the cookie carries it from here
  if (new URLSearchParams(location.search).has("token")) history.replaceState(null, "", location.pathname);
  connect();
})();

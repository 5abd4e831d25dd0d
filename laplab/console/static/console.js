/* laplab console: page logic over the JSON API (no framework, no CDN). */
"use strict";
const Console = (() => {
  const $ = (sel, root = document) => root.querySelector(sel);
  const el = (tag, attrs = {}, ...children) => {
    const node = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs)) {
      if (k === "class") node.className = v; else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
      else if (v !== undefined && v !== null && v !== false) node.setAttribute(k, v === true ? "" : v);
    }
    for (const c of children.flat()) node.append(c instanceof Node ? c : document.createTextNode(c ?? ""));
    return node;
  };
  const csrf = () => $('meta[name="csrf-token"]')?.content || "";
  class ApiError extends Error { constructor(status, detail) { super(typeof detail === "string" ? detail : detail?.message || `HTTP ${status}`); this.status = status; this.detail = detail; } }
  async function api(method, url, body) {
    const opts = {method, headers: {"X-CSRF-Token": csrf()}, credentials: "same-origin"};
    if (body instanceof FormData) opts.body = body;
    else if (body !== undefined) { opts.body = JSON.stringify(body); opts.headers["Content-Type"] = "application/json"; }
    const res = await fetch(url, opts);
    const data = res.headers.get("content-type")?.includes("json") ? await res.json() : await res.text();
    if (!res.ok) throw new ApiError(res.status, data?.detail ?? data);
    return data;
  }
  // a link styled as a disabled button does nothing (its title says why)
  document.addEventListener("click", e => { if (e.target.closest?.("a.button.disabled")) e.preventDefault(); }, true);
  function toast(text) { const t = $("#toast"); t.textContent = text; t.hidden = false; clearTimeout(toast.timer); toast.timer = setTimeout(() => t.hidden = true, 4000); }
  const fmt = (v, d = 2) => v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(d);
  const lap = v => v === null || v === undefined ? "–" : `${Number(v).toFixed(3)} s`;
  const when = iso => iso ? new Date(iso).toLocaleString() : "–";
  const duration = s => { if (s === null || s === undefined) return "–"; s = Math.max(0, Math.round(s)); const m = Math.floor(s / 60); return m ? `${m} min ${s % 60} s` : `${s} s`; };
  const badge = status => el("span", {class: `status ${status}`, "data-status": status}, status);

  document.addEventListener("submit", async ev => {  // the sign-out form posts with the CSRF header
    if (!ev.target.matches("[data-csrf-form]")) return;
    ev.preventDefault(); await fetch(ev.target.action, {method: "POST", headers: {"X-CSRF-Token": csrf()}}); location.href = "/login";
  });

  // ---- Models ------------------------------------------------------------------------------
  async function modelsPage() {
    const body = $("#models tbody"), filter = $("#filter");
    let models = [];
    const render = () => {
      const q = filter.value.trim().toLowerCase();
      const shown = models.filter(m => !q || [m.name, m.track, m.status, m.owner].join(" ").toLowerCase().includes(q));
      body.replaceChildren(...shown.map(m => el("tr", {"data-model": m.name},
        el("td", {}, el("a", {href: `/models/${m.name}`}, m.name)), el("td", {}, badge(m.status)),
        el("td", {}, m.track || "–"), el("td", {}, (m.sensor || []).join(", ")), el("td", {}, m.algorithm || "–"),
        el("td", {}, when(m.created)), el("td", {class: "num"}, lap(m.best_lap_time)), el("td", {}, m.owner || "–"),
        el("td", {}, el("button", {class: "button small danger", "data-delete": m.name,
          disabled: ["training", "queued", "stopping"].includes(m.status),
          title: ["training", "queued", "stopping"].includes(m.status) ? "stop the training first" : "delete",
          onclick: () => remove(m.name)}, "Delete")))));
      $("#empty").hidden = models.length > 0; $("#count").textContent = `${shown.length} of ${models.length}`;
    };
    const load = async () => { models = await api("GET", "/api/models"); render(); };
    async function remove(name) {
      if (!confirm(`Delete model ${name}? Its folder, checkpoints, logs and evaluations are removed for good.`)) return;
      try { await api("DELETE", `/api/models/${name}`); toast(`deleted ${name}`); load(); } catch (e) { toast(e.message); }
    }
    filter.addEventListener("input", render);
    $("#import-form").addEventListener("submit", async ev => {
      ev.preventDefault(); $("#import-error").textContent = "";
      try { const m = await api("POST", "/api/models/import", new FormData(ev.target)); toast(`imported ${m.name}`); ev.target.reset(); load(); }
      catch (e) { $("#import-error").textContent = e.message; }
    });
    await load(); setInterval(load, 3000);
  }

  // ---- Python highlighting (a small tokenizer: keywords, strings, numbers, comments) ----------
  const KW = new Set("False None True and as assert async await break class continue def del elif else except finally for from global if import in is lambda nonlocal not or pass raise return try while with yield".split(" "));
  const BI = new Set("abs all any bool dict enumerate float int len list max min print range round set sorted str sum tuple zip math params".split(" "));
  const esc = s => s.replace(/&/g, "&amp;").replace(/</g, "&lt;").replace(/>/g, "&gt;");
  function highlight(src) {
    const re = /(#[^\n]*)|("""[\s\S]*?(?:"""|$)|'''[\s\S]*?(?:'''|$)|"(?:\\.|[^"\\\n])*"?|'(?:\\.|[^'\\\n])*'?)|\b(\d+\.?\d*(?:e[+-]?\d+)?)\b|\b([A-Za-z_]\w*)\b(\s*\()?/g;
    let out = "", last = 0, m, prevDef = false;
    while ((m = re.exec(src))) {
      out += esc(src.slice(last, m.index)); last = re.lastIndex;
      if (m[1]) out += `<span class="tok-com">${esc(m[1])}</span>`;
      else if (m[2]) out += `<span class="tok-str">${esc(m[2])}</span>`;
      else if (m[3]) out += `<span class="tok-num">${m[3]}</span>`;
      else if (m[4]) {
        const w = m[4], cls = KW.has(w) ? "tok-kw" : prevDef || m[5] ? (BI.has(w) ? "tok-bi" : "tok-fn") : BI.has(w) ? "tok-bi" : "";
        out += cls ? `<span class="${cls}">${w}</span>` : w; if (m[5]) out += esc(m[5]); prevDef = w === "def";
        continue;
      }
      prevDef = false;
    }
    return out + esc(src.slice(last)) + "\n";
  }

  // ---- Action picture: each action a ray (angle = steering, length = speed) ------------------
  function drawActions(canvas, actions, continuous) {
    const c = canvas.getContext("2d"), w = canvas.width, h = canvas.height, ox = w / 2, oy = h - 18, scale = (h - 40) / 4;
    c.clearRect(0, 0, w, h); c.fillStyle = "#f7f9fa"; c.fillRect(0, 0, w, h);
    c.strokeStyle = "#d5dbdb"; c.fillStyle = "#687078"; c.font = "11px sans-serif";
    for (let v = 1; v <= 4; v++) { c.beginPath(); c.arc(ox, oy, v * scale, Math.PI, 2 * Math.PI); c.stroke(); c.fillText(`${v} m/s`, ox + v * scale - 14, oy + 13); }
    if (continuous) {
      const a0 = -Math.PI / 2 - continuous.steer[1] * Math.PI / 180, a1 = -Math.PI / 2 - continuous.steer[0] * Math.PI / 180;
      c.fillStyle = "rgba(255,153,0,.35)"; c.beginPath(); c.arc(ox, oy, continuous.speed[1] * scale, a0, a1);
      c.arc(ox, oy, continuous.speed[0] * scale, a1, a0, true); c.closePath(); c.fill(); return;
    }
    actions.forEach((a, i) => {
      const ang = -Math.PI / 2 - (a.steering_angle * Math.PI / 180), r = a.speed * scale;
      const x = ox + r * Math.cos(ang), y = oy + r * Math.sin(ang);
      c.strokeStyle = "#0073bb"; c.lineWidth = 2; c.beginPath(); c.moveTo(ox, oy); c.lineTo(x, y); c.stroke();
      c.fillStyle = "#ff9900"; c.beginPath(); c.arc(x, y, 4, 0, 2 * Math.PI); c.fill();
      c.fillStyle = "#16191f"; c.fillText(String(i), x + 5, y - 4);
    });
    c.fillStyle = "#232f3e"; c.fillRect(ox - 6, oy - 4, 12, 12);
  }

  // ---- Create / clone ------------------------------------------------------------------------
  const HP = [
    ["batch_size", "Gradient descent batch size", {options: [32, 64, 128, 256, 512]}],
    ["num_epochs", "Number of epochs", {min: 3, max: 10, step: 1}],
    ["lr", "Learning rate", {min: 0.00001, max: 0.001, step: 0.00001}],
    ["beta_entropy", "Entropy", {min: 0.0001, max: 0.01, step: 0.0001}],
    ["discount_factor", "Discount factor", {min: 0, max: 1, step: 0.001}],
    ["loss_type", "Loss type", {options: ["huber", "mean squared error"]}],
    ["num_episodes_between_training", "Episodes between each policy update", {min: 1, max: 1000, step: 1}],
    ["sac_alpha", "SAC alpha (SAC only)", {min: 0, max: 1, step: 0.01}],
  ];
  async function createPage() {
    const defaults = JSON.parse($("#defaults").textContent), source = JSON.parse($("#source").textContent);
    const config = source?.config;
    let actions = (config?.model_metadata || defaults.metadata).action_space;
    let trackName = config?.track || "classic_2018";
    const reward = $("#reward"), hl = $("#highlight"), gutter = $("#gutter");
    let errorLine = null;
    const renderCode = () => {
      hl.innerHTML = highlight(reward.value);
      const n = reward.value.split("\n").length;
      gutter.innerHTML = Array.from({length: n}, (_, i) => i + 1 === errorLine ? `<span class="err" data-error-line="${i + 1}">${i + 1}</span>` : String(i + 1)).join("\n");
      reward.style.height = `${Math.max(320, n * 20 + 24)}px`;
    };
    reward.addEventListener("input", () => { errorLine = null; renderCode(); });
    reward.addEventListener("keydown", ev => { if (ev.key === "Tab") { ev.preventDefault(); const s = reward.selectionStart; reward.setRangeText("    ", s, reward.selectionEnd, "end"); renderCode(); } });
    const examples = await api("GET", "/api/reward/examples");
    for (const ex of examples) $("#examples").append(el("option", {value: ex.name}, ex.name));
    $("#examples").addEventListener("change", ev => { const ex = examples.find(e => e.name === ev.target.value); if (ex) { reward.value = ex.source; errorLine = null; renderCode(); } });
    reward.value = source?.reward || (examples.find(e => e.name === "lap_pace") || examples[0]).source; renderCode();

    const tracks = await api("GET", "/api/tracks");
    const grid = $("#tracks");
    const renderTracks = () => grid.replaceChildren(...tracks.map(t => el("button", {type: "button", role: "radio", "aria-checked": String(t.name === trackName),
      class: `track${t.name === trackName ? " selected" : ""}`, "data-track": t.name, onclick: () => { trackName = t.name; renderTracks(); }},
      el("img", {src: t.picture, alt: t.name, loading: "lazy"}), el("b", {}, t.display_name || t.name),
      el("span", {}, `${t.length_m.toFixed(1)} m long · ${t.width_m.toFixed(2)} m wide · ${t.source}`))));
    renderTracks();

    const meta = config?.model_metadata || defaults.metadata;
    $("#sensor").value = meta.sensor.join("+"); $("#network").value = meta.neural_network; $("#algorithm").value = meta.training_algorithm;
    const randomize = $("#domain-randomization"), hasCamera = () => $("#sensor").value.includes("CAMERA");
    randomize.checked = !!config?.domain_randomization;
    const renderRandomize = () => { randomize.disabled = !!source || !hasCamera(); if (!source && !hasCamera()) randomize.checked = false; };
    $("#sensor").addEventListener("change", renderRandomize); renderRandomize();
    const tbody = $("#actions tbody");
    const picture = () => drawActions($("#action-picture"), actions, continuous() ? {steer: [+$("#steer-low").value, +$("#steer-high").value], speed: [+$("#speed-low").value, +$("#speed-high").value]} : null);
    const continuous = () => document.querySelector('input[name="astype"]:checked').value === "continuous";
    const renderActions = () => {
      tbody.replaceChildren(...actions.map((a, i) => el("tr", {},
        el("td", {}, String(i)),
        el("td", {}, el("input", {type: "number", min: -30, max: 30, step: 1, value: a.steering_angle, "aria-label": `steering ${i}`, oninput: ev => { a.steering_angle = +ev.target.value; picture(); }})),
        el("td", {}, el("input", {type: "number", min: 0.1, max: 4, step: 0.01, value: a.speed, "aria-label": `speed ${i}`, oninput: ev => { a.speed = +ev.target.value; picture(); }})),
        el("td", {}, el("button", {type: "button", class: "button small", disabled: actions.length <= 2 || !!source, onclick: () => { actions.splice(i, 1); renderActions(); }}, "Remove")))));
      picture();
    };
    $("#add-action").addEventListener("click", () => { actions.push({steering_angle: 0, speed: 1}); renderActions(); });
    for (const r of document.querySelectorAll('input[name="astype"]')) r.addEventListener("change", () => { $("#discrete-editor").hidden = continuous(); $("#continuous-editor").hidden = !continuous(); picture(); });
    for (const id of ["#steer-low", "#steer-high", "#speed-low", "#speed-high"]) $(id).addEventListener("input", picture);
    if (meta.action_space_type === "continuous") {
      document.querySelector('input[value="continuous"]').checked = true; $("#discrete-editor").hidden = true; $("#continuous-editor").hidden = false;
      $("#steer-low").value = meta.action_space.steering_angle.low; $("#steer-high").value = meta.action_space.steering_angle.high;
      $("#speed-low").value = meta.action_space.speed.low; $("#speed-high").value = meta.action_space.speed.high; actions = [];
    }
    renderActions();
    if (source) { for (const n of document.querySelectorAll("#vehicle-card input, #vehicle-card select, #vehicle-card button, #physics")) n.disabled = true; }
    if (config?.vehicle && {"deepracer-v4": "4", "deepracer-v5": "5", "deepracer-v6": "6"}[config.vehicle]) $("#physics").value = {"deepracer-v4": "4", "deepracer-v5": "5", "deepracer-v6": "6"}[config.vehicle];

    const hp = {...defaults.hyperparameters, ...(config?.hyperparameters || {})};
    $("#hyperparameters").replaceChildren(...HP.map(([key, label, spec]) => el("div", {},
      el("label", {for: `hp-${key}`}, label),
      spec.options ? el("select", {id: `hp-${key}`, "data-hp": key}, ...spec.options.map(o => el("option", {value: o, selected: String(o) === String(hp[key])}, String(o))))
        : el("input", {id: `hp-${key}`, "data-hp": key, type: "number", min: spec.min, max: spec.max, step: spec.step, value: hp[key]}),
      spec.options ? "" : el("div", {class: "hint"}, `${spec.min} to ${spec.max} · default ${defaults.hyperparameters[key]}`))));
    if (config) $("#max-time").value = (config.max_time_s / 60).toFixed(1);

    const metadata = () => continuous()
      ? {...meta, sensor: $("#sensor").value.split("+"), neural_network: $("#network").value, training_algorithm: $("#algorithm").value, action_space_type: "continuous",
         action_space: {steering_angle: {low: +$("#steer-low").value, high: +$("#steer-high").value}, speed: {low: +$("#speed-low").value, high: +$("#speed-high").value}}}
      : {...meta, sensor: $("#sensor").value.split("+"), neural_network: $("#network").value, training_algorithm: $("#algorithm").value, action_space_type: "discrete", action_space: actions};
    const hyper = () => { const out = {...hp}; for (const n of document.querySelectorAll("[data-hp]")) out[n.dataset.hp] = n.tagName === "SELECT" && n.dataset.hp === "batch_size" ? +n.value : n.type === "number" ? +n.value : n.value; return out; };
    const showErrors = e => {
      for (const n of document.querySelectorAll(".field-error")) n.textContent = "";
      const field = e.detail?.field?.split(".")[0];
      const target = field && document.querySelector(`.field-error[data-field="${field}"]`);
      (target || $("#form-error")).textContent = e.message;
      if (e.detail?.line) { errorLine = e.detail.line; renderCode(); }
      (target || $("#form-error")).scrollIntoView({block: "center"});
    };
    $("#validate").addEventListener("click", async () => {
      const out = $("#validate-result"); out.className = ""; out.textContent = "validating…"; $("#reward-error").textContent = "";
      try {
        const r = await api("POST", "/api/reward/validate", {source: reward.value, track: trackName, model_metadata: metadata(), race_type: source ? null : raceType()});
        if (r.ok) { out.className = "ok"; out.textContent = `Passed: ${r.calls} states, reward ${fmt(r.minimum, 3)} to ${fmt(r.maximum, 3)}`; errorLine = null; }
        else { out.className = "bad"; out.textContent = r.errors[0].line ? `Failed on line ${r.errors[0].line}` : "Failed";
               $("#reward-error").textContent = r.errors.map(e => (e.line ? `line ${e.line}: ` : "") + e.message).join("\n"); errorLine = r.errors[0].line; }
        renderCode();
      } catch (e) { out.className = "bad"; out.textContent = e.message; }
    });
    const raceKind = () => document.querySelector('input[name="race"]:checked')?.value || "time_trial";
    for (const r of document.querySelectorAll('input[name="race"]')) r.addEventListener("change", () => {
      $("#race-objects").hidden = raceKind() !== "object_avoidance"; $("#race-bots").hidden = raceKind() !== "head_to_bot"; });
    const raceType = () => {
      const kind = raceKind();
      if (kind === "object_avoidance") return {kind, objects: +$("#race-objects-count").value, randomize_objects: $("#race-randomize").checked};
      if (kind === "head_to_bot") return {kind, bots: +$("#race-bots-count").value, bot_speed: +$("#race-bot-speed").value, lane_change: $("#race-lane-change").checked};
      return null;
    };
    $("#create-form").addEventListener("submit", async ev => {
      ev.preventDefault(); $("#submit").disabled = true;
      const body = {name: $("#name").value.trim(), description: $("#description").value, track: trackName, reward_function: reward.value,
                    hyperparameters: hyper(), max_time_s: +$("#max-time").value * 60};
      if (!source) { body.model_metadata = metadata(); body.physics = $("#physics").value; body.race_type = raceType();
                     body.domain_randomization = randomize.checked; }
      try { const m = await api("POST", source ? `/api/models/${source.name}/clone` : "/api/models", body); location.href = `/models/${m.name}`; }
      catch (e) { showErrors(e); $("#submit").disabled = false; }
    });
  }

  // ---- Training page -------------------------------------------------------------------------
  function drawChart(canvas, rows) {
    const c = canvas.getContext("2d"), w = canvas.width, h = canvas.height, pad = {l: 46, r: 46, t: 10, b: 28};
    c.clearRect(0, 0, w, h);
    const pw = w - pad.l - pad.r, ph = h - pad.t - pad.b;
    c.strokeStyle = "#eaeded"; c.fillStyle = "#687078"; c.font = "11px sans-serif"; c.lineWidth = 1;
    for (let i = 0; i <= 4; i++) { const y = pad.t + ph * i / 4; c.beginPath(); c.moveTo(pad.l, y); c.lineTo(w - pad.r, y); c.stroke(); c.fillText(`${100 - 25 * i}%`, w - pad.r + 6, y + 4); }
    if (!rows.length) { c.fillText("Waiting for the first iteration…", pad.l + 10, pad.t + 20); return; }
    const n = rows.length, xs = i => pad.l + (n === 1 ? pw / 2 : pw * i / (n - 1));
    const rewards = rows.map(r => r.mean_reward), lo = Math.min(0, ...rewards), hi = Math.max(...rewards, lo + 1e-9);
    for (let i = 0; i <= 4; i++) c.fillText((hi - (hi - lo) * i / 4).toPrecision(3), 4, pad.t + ph * i / 4 + 4);
    c.fillText("iteration", w / 2 - 20, h - 6); c.fillText("1", pad.l, h - 14); c.fillText(String(rows[n - 1].iteration), w - pad.r - 10, h - 14);
    // a missing value (an iteration cut short by the time limit has no evaluation laps) breaks the line
    const has = v => v !== null && v !== undefined && !Number.isNaN(v);
    const line = (vals, color, y) => { c.strokeStyle = color; c.fillStyle = color; c.lineWidth = 2; c.beginPath();
      let pen = false;
      vals.forEach((v, i) => { if (!has(v)) { pen = false; return; } const p = [xs(i), y(v)]; pen ? c.lineTo(...p) : c.moveTo(...p); pen = true; }); c.stroke();
      vals.forEach((v, i) => { if (has(v)) { c.beginPath(); c.arc(xs(i), y(v), 2.5, 0, 2 * Math.PI); c.fill(); } }); };
    line(rewards, "#0073bb", v => pad.t + ph * (1 - (v - lo) / (hi - lo)));
    line(rows.map(r => r.mean_progress), "#ff9900", v => pad.t + ph * (1 - v / 100));
    line(rows.map(r => r.eval_progress), "#1d8102", v => pad.t + ph * (1 - v / 100));
  }
  function liveView(canvas) {
    const c = canvas.getContext("2d"); let outline = null, box = null, cars = [], evaluation = false, boxes = [], objects = [];
    const fit = () => { const pts = outline.outer.concat(outline.inner); const xs = pts.map(p => p[0]), ys = pts.map(p => p[1]);
      const minx = Math.min(...xs), maxx = Math.max(...xs), miny = Math.min(...ys), maxy = Math.max(...ys);
      const s = Math.min((canvas.width - 30) / (maxx - minx), (canvas.height - 30) / (maxy - miny));
      box = {s, ox: (canvas.width - s * (maxx - minx)) / 2 - s * minx, oy: (canvas.height + s * (maxy - miny)) / 2 + s * miny}; };
    const P = p => [box.ox + box.s * p[0], box.oy - box.s * p[1]];
    const draw = () => {
      c.fillStyle = "#0f1720"; c.fillRect(0, 0, canvas.width, canvas.height);
      if (!outline) return;
      c.fillStyle = "#3b4654"; c.beginPath(); outline.outer.forEach((p, i) => i ? c.lineTo(...P(p)) : c.moveTo(...P(p)));
      c.closePath(); outline.inner.slice().reverse().forEach((p, i) => i ? c.lineTo(...P(p)) : c.moveTo(...P(p))); c.closePath(); c.fill("evenodd");
      c.strokeStyle = "#fff"; c.lineWidth = 1.5;
      for (const b of [outline.outer, outline.inner]) { c.beginPath(); b.forEach((p, i) => i ? c.lineTo(...P(p)) : c.moveTo(...P(p))); c.closePath(); c.stroke(); }
      c.setLineDash([6, 6]); c.strokeStyle = "#ffd36b"; c.beginPath(); outline.center.forEach((p, i) => i ? c.lineTo(...P(p)) : c.moveTo(...P(p))); c.stroke(); c.setLineDash([]);
      // a race's obstacles as their footprints: boxes brown (#7b614f), bot cars grey-blue, other models' cars
      // violet; a driving one is outlined in the colour of the car whose episode it drives in
      const obstacle = ([x, y, yaw, hl, hw, kind], outline) => { const [px, py] = P([x, y]); c.save(); c.translate(px, py); c.rotate(-yaw);
        c.fillStyle = {1: "#7b614f", 2: "#5a6e8c", 3: "#8c50aa"}[kind] || "#7b614f"; c.fillRect(-hl * box.s, -hw * box.s, 2 * hl * box.s, 2 * hw * box.s);
        if (outline) { c.strokeStyle = outline; c.lineWidth = 1.5; c.strokeRect(-hl * box.s, -hw * box.s, 2 * hl * box.s, 2 * hw * box.s); }
        c.restore(); };
      boxes.forEach(b => obstacle(b, null));
      objects.forEach(([car, ...o]) => obstacle(o, evaluation ? "#1d8102" : ["#ff9900", "#7cc6fe", "#f25f5c", "#c792ea"][car % 4]));
      cars.forEach(([x, y, yaw], i) => { const [px, py] = P([x, y]); c.save(); c.translate(px, py); c.rotate(-yaw);
        c.fillStyle = evaluation ? "#1d8102" : ["#ff9900", "#7cc6fe", "#f25f5c", "#c792ea"][i % 4]; c.fillRect(-9, -5, 18, 10);
        c.fillStyle = "#16191f"; c.fillRect(5, -4, 4, 8); c.restore(); });
    };
    return {
      async setTrack(name) { try { outline = await api("GET", `/api/tracks/${encodeURIComponent(name.replace("@reversed", ""))}/outline`); fit(); } catch (e) { outline = null; } draw(); },
      setObstacles(doc) { boxes = doc.boxes || []; canvas.dataset.boxes = String(boxes.length); draw(); },
      update(doc) { cars = doc.cars; evaluation = doc.evaluation; objects = doc.objects || []; canvas.dataset.frames = String(+(canvas.dataset.frames || 0) + 1);
        const note = $("#live-note");  // what the cars are
        if (note) note.textContent = doc.evaluation
          ? `Evaluation laps (green): ${cars.length === 1 ? "the car" : `${cars.length} cars`} driving the model's greedy policy${doc.trial ? `, trial ${doc.trial}` : ""}.`
          : `${cars.length} cars, each its own training episode of this iteration, driven together in one simulator (they do not meet).`;
        canvas.dataset.lastCar = JSON.stringify(cars[0] || null); draw(); },
      draw,
    };
  }
  async function modelPage(name) {
    let model = await api("GET", `/api/models/${name}`);
    let rows = model.iterations || [];
    const chart = $("#chart"), live = liveView($("#live"));
    const setStatus = (status, progress) => {
      const s = $("#status"); s.className = `status ${status}`; s.dataset.status = status; s.textContent = status;
      const active = ["training", "queued", "stopping"].includes(status);
      $("#stop").hidden = !["training", "queued"].includes(status); $("#resume").hidden = status !== "interrupted";
      for (const id of ["#evaluate", "#clone", "#download-tar", "#download-onnx", "#export-car", "#export-console"]) { const n = $(id); n.classList.toggle("disabled", active); if (n.tagName === "BUTTON") n.disabled = active; }
      if (progress !== undefined) $("#stat-progress").textContent = `${fmt(progress, 0)} %`;
      if (!active) $("#stat-phase").textContent = "–";  // no job runs: no phase to show
    };
    const renderRows = () => {
      drawChart(chart, rows); chart.dataset.points = String(rows.length);
      const last = rows[rows.length - 1];
      if (last) { $("#stat-iteration").textContent = last.iteration; $("#stat-best").textContent = lap(rows.reduce((b, r) => r.best_lap_time ?? b, null));
        $("#stat-eta").textContent = ["training"].includes($("#status").dataset.status) ? duration(last.time_left_s) : "–"; $("#stat-sps").textContent = fmt(last.steps_per_second, 0); }
      $("#iterations tbody").replaceChildren(...rows.slice().reverse().map(r => el("tr", {},
        el("td", {class: "num"}, r.iteration), el("td", {class: "num"}, r.episodes), el("td", {class: "num"}, fmt(r.mean_reward, 3)),
        el("td", {class: "num"}, fmt(r.mean_progress, 1)), el("td", {class: "num"}, fmt(r.eval_progress, 1)), el("td", {class: "num"}, lap(r.best_lap_time)),
        el("td", {class: "num"}, fmt(r.steps_per_second, 0)), el("td", {class: "num"}, duration(r.elapsed_s)))));
    };
    const renderModel = () => {
      setStatus(model.status, model.progress);
      $("#stat-best-evaluated").textContent = lap(model.best_lap_time);  // evaluated, standard rules
      if (model.status === "queued" && model.queue_position) $("#status").textContent = `queued: ${model.queue_position === 1 ? "next to start" : `number ${model.queue_position} in line`}`;
      $("#model-error").textContent = model.status === "failed" || model.status === "interrupted" ? (model.error || model.job?.error || "") : "";
      const cfg = model.config || {}; const meta = cfg.model_metadata || {};
      $("#config").replaceChildren(...[["Track", model.track], ["Race type", model.race_type || "time trial"], ["Sensor", (model.sensor || []).join(", ")], ["Algorithm", model.algorithm],
        ["Action space", meta.action_space_type === "continuous" ? "continuous" : `${(meta.action_space || []).length} discrete actions`],
        ["Car", cfg.vehicle || "–"], ["Domain randomisation", cfg.domain_randomization ? "on" : "off"], ["Max time", duration(cfg.max_time_s)], ["Created", when(model.created)], ["Owner", model.owner], ["Description", model.description || "–"]]
        .concat(cfg.cloned_from ? [["Cloned from", cfg.cloned_from]] : [])
        .map(([k, v]) => el("div", {}, el("span", {}, k), v ?? "–")));
      $("#reward-source").textContent = model.reward_function || "";
      renderBlocked();
      renderWorkers();
    };
    const renderBlocked = () => {  // a download that cannot work is disabled, with the reason on it and below
      const blocked = model.downloads_blocked || {}; const reasons = [];
      for (const [id, key] of [["#download-tar", "tar"], ["#download-onnx", "onnx"], ["#export-car", "car"], ["#export-console", "console"]]) {
        const n = $(id); if (!n || !(key in blocked)) continue; const why = blocked[key];
        n.classList.toggle("disabled", !!why); if (n.tagName === "BUTTON") n.disabled = !!why;
        if (n.dataset.title === undefined) n.dataset.title = n.title;  // the button's own hint, kept
        n.title = why || n.dataset.title;
        if (why && !["training", "queued", "stopping"].includes(model.status) && !reasons.includes(why)) reasons.push(`${n.textContent.trim()}: ${why}`);
      }
      const box = $("#downloads-blocked"); if (box) box.textContent = reasons.join(" · ");
    };
    const renderWorkers = () => {  // the Ray rollout workers of the last session (none: no table)
      const workers = model.workers || [];
      $("#workers-card").hidden = !workers.length;
      $("#workers tbody").replaceChildren(...workers.map(w => el("tr", {"data-worker": w.index, "data-state": w.state},
        el("td", {class: "num"}, w.index), el("td", {}, w.track || "–"),
        el("td", {title: w.node_id || ""}, [w.host, w.node_ip].filter(Boolean).join(" · ") || "–"),
        el("td", {class: "num"}, w.pid ?? "–"), el("td", {class: "mono", title: w.actor_id || ""}, w.actor_id ? w.actor_id.slice(0, 12) : "–"),
        el("td", {class: "num", title: w.cause || ""}, w.restarts ?? 0), el("td", {class: "num"}, w.episodes ?? 0),
        el("td", {class: "num"}, w.iteration ?? "–"), el("td", {}, badge(w.state)))));
    };
    renderModel(); renderRows(); await live.setTrack(model.track || "classic_2018");
    if ((model.sensor || []).some(s => s.includes("CAMERA"))) {
      $("#camera-box").hidden = false;
      // the job writes its first frame with its first poses: asking before them only meets 404s
      const driving = () => ["training", "stopping"].includes(model.status) && +($("#live").dataset.frames || 0) > 0;
      const frame = () => { if (driving() || !$("#camera").src) $("#camera").src = `/api/models/${name}/camera.png?t=${Date.now()}`; };
      $("#camera").addEventListener("load", () => $("#camera-box").hidden = false);
      $("#camera").addEventListener("error", () => $("#camera-box").hidden = model.status !== "training");
      frame(); setInterval(frame, 1000);
    }
    const tracks = await api("GET", "/api/tracks");
    $("#eval-track").replaceChildren(...tracks.map(t => el("option", {value: t.name, selected: t.name === model.track}, t.display_name || t.name)));
    const refresh = async () => { model = await api("GET", `/api/models/${name}`); rows = model.iterations || []; renderModel(); renderRows(); };
    const events = new EventSource(`/api/models/${name}/events`);
    events.addEventListener("iteration", ev => { const r = JSON.parse(ev.data); if (!rows.length || rows[rows.length - 1].iteration < r.iteration) rows.push(r); $("#stat-progress").textContent = `${fmt(r.progress, 0)} %`; renderRows();
      if ((model.workers || []).length || model.rollout_workers) api("GET", `/api/models/${name}`).then(m => { model.workers = m.workers; renderWorkers(); }).catch(() => {}); });
    events.addEventListener("status", ev => { const s = JSON.parse(ev.data); if (s.status) setStatus(["queued", "training", "stopping", "ready", "failed", "interrupted", "stopped"].includes(s.status) && !["evaluate", "export", "duel"].includes(s.kind) ? (s.status === "stopped" ? model.status : s.status) : model.status); refresh(); loadEvaluations(); });
    events.addEventListener("poses", ev => live.update(JSON.parse(ev.data)));
    events.addEventListener("obstacles", ev => live.setObstacles(JSON.parse(ev.data)));
    const phases = {collect: ["collecting", "episodes"], learn: ["learning", "gradient steps"], evaluate: ["evaluating", "laps"]};
    events.addEventListener("phase", ev => { const p = JSON.parse(ev.data), [verb, unit] = phases[p.phase] || [p.phase, ""];
      if (!["training", "queued", "stopping"].includes($("#status").dataset.status)) return;  // late news of an ended job
      $("#stat-phase").textContent = `iteration ${p.iteration}: ${verb}` + (p.total ? ` ${p.done}/${p.total} ${unit}` : ""); });
    $("#stop").addEventListener("click", async () => { try { await api("POST", `/api/models/${name}/stop`); toast("stopping: the model keeps its last checkpoint"); refresh(); } catch (e) { toast(e.message); } });
    $("#resume").addEventListener("click", async () => { try { await api("POST", `/api/models/${name}/resume`, {}); toast("resumed"); refresh(); } catch (e) { toast(e.message); } });
    // The league's figure when 3 trials in a row finished, else the best lap, else the completion.
    const evaluationHeadline = s => (!s ? "" : s.average_3 != null ? ` · average of 3 laps ${lap(s.average_3)}`
      : s.best_lap != null ? ` · best lap ${lap(s.best_lap)} (${s.completed} of ${s.trials} trials completed)`
      : ` · no lap completed (${fmt(s.average_completion, 1)} % on average)`)
      + (s && s.identical_trials ? ` · the ${s.trials} trials were identical (a greedy policy from the same start)` : "");
    async function loadEvaluations() {
      const list = await api("GET", `/api/models/${name}/evaluations`);
      $("#evaluations").replaceChildren(...list.slice().reverse().map(ev => el("div", {class: "evaluation", "data-evaluation": ev.id},
        el("h3", {}, `Evaluation ${ev.id} `, badge(ev.status), ev.track ? ` on ${ev.track}` : "", ev.settings?.domain_randomization ? " · domain randomisation" : "", evaluationHeadline(ev.summary)),
        ev.error ? el("p", {class: "field-error"}, ev.error) : "",
        ev.trials.length ? el("table", {class: "grid compact"}, el("thead", {}, el("tr", {}, ...["Trial", "Time", "Progress %", "Status", "Off-track", "Gap to optimal"].map(h => el("th", {class: h === "Status" || h === "Trial" ? "" : "num"}, h)))),
          el("tbody", {}, ...ev.trials.map((t, i) => el("tr", {}, el("td", {}, i + 1), el("td", {class: "num"}, lap(t.lap_time)), el("td", {class: "num"}, fmt(t.progress, 1)),
            el("td", {}, t.status), el("td", {class: "num"}, t.off_track_count ?? "–"),
            el("td", {class: "num"}, t.lap_time && ev.summary?.optimal_lap_time ? `+${fmt(100 * (t.lap_time / ev.summary.optimal_lap_time - 1), 1)} %` : "–"))))) : "",
        ev.video && ev.stamp ? el("a", {href: `/api/models/${name}/video/${ev.stamp}`, target: "_blank"}, "Watch the first trial") : "")));
      if (list.some(e => ["queued", "running"].includes(e.status))) setTimeout(loadEvaluations, 2000);
    }
    $("#evaluate-form").addEventListener("submit", async ev => {
      ev.preventDefault(); $("#eval-error").textContent = "";
      const resets = $("#eval-resets").value.trim();
      try { await api("POST", `/api/models/${name}/evaluations`, {track: $("#eval-track").value, trials: +$("#eval-trials").value,
              off_track_penalty: +$("#eval-penalty").value, resets: resets === "" ? null : +resets, video: $("#eval-video").checked,
              domain_randomization: $("#eval-randomize").checked});
            toast("evaluation queued"); loadEvaluations(); }
      catch (e) { $("#eval-error").textContent = e.message; }
    });
    loadEvaluations();
    const formats = {car: "Car (model.pb tar.gz)", console: "DeepRacer console format (tar.gz)"};
    async function loadExports() {
      const list = await api("GET", `/api/models/${name}/exports`);
      $("#exports").replaceChildren(...list.slice().reverse().map(x => el("div", {class: "export row", "data-export": x.id, "data-status": x.status},
        el("span", {}, `${formats[x.format] || x.format} · ${x.checkpoint || "best"} `), badge(x.status),
        x.url ? el("a", {class: "button primary", href: x.url, download: ""}, `Download${x.size ? ` (${fmt(x.size / 1e6, 1)} MB)` : ""}`) : "",
        x.error ? el("span", {class: "field-error"}, x.error) : "")));
      if (list.some(x => ["queued", "running"].includes(x.status))) setTimeout(loadExports, 1500);
    }
    const startExport = async format => {
      try { await api("POST", `/api/models/${name}/exports`, {format}); toast(`building the ${formats[format]}…`); $("#exports-card").scrollIntoView({behavior: "smooth"}); loadExports(); }
      catch (e) { toast(e.message); $("#exports").prepend(el("p", {class: "field-error"}, e.message)); }
    };
    $("#export-car").addEventListener("click", () => startExport("car"));
    $("#export-console").addEventListener("click", () => startExport("console"));
    loadExports();
    const log = async () => { try { $("#job-log").textContent = (await api("GET", `/api/models/${name}/log`)).log; } catch (e) {} };
    log(); setInterval(() => { log(); if (!model.config || ["training", "queued", "stopping"].includes(model.status)) refresh(); }, 5000);
  }

  // ---- Leaderboard ---------------------------------------------------------------------------
  async function leaderboardPage() {
    const select = $("#track-filter");
    const load = async () => {
      const boards = await api("GET", `/api/leaderboard${select.value ? `?track=${encodeURIComponent(select.value)}` : ""}`);
      if (!select.options.length || select.options.length === 1) for (const b of boards) select.append(el("option", {value: b.track}, b.track));
      $("#boards").replaceChildren(...(boards.length ? boards.map(b => el("section", {class: "card", "data-board": b.track}, el("h2", {}, b.track),
        el("table", {class: "grid"}, el("thead", {}, el("tr", {}, ...["Rank", "Racer", "Model", "Average of 3 laps", "Best lap", "Completion", "Off-track", "Gap to optimal"].map((h, i) => el("th", {class: i > 2 ? "num" : ""}, h)))),
          el("tbody", {}, ...b.entries.map(e => el("tr", {}, el("td", {}, e.rank), el("td", {}, e.alias ? el("span", {class: "avatar", style: `background:${e.colour};width:24px;height:24px;font-size:10px`, title: e.alias}, e.initials) : "", " ", e.alias || "–"), el("td", {}, e.model ?? "–"), el("td", {class: "num"}, lap(e.average_3)),
            el("td", {class: "num"}, lap(e.best_lap)), el("td", {class: "num"}, `${fmt(e.completion, 1)} %`), el("td", {class: "num"}, e.off_track_count),
            el("td", {class: "num"}, e.gap_to_optimal ? `${e.gap_to_optimal >= 1 ? "+" : ""}${fmt(100 * (e.gap_to_optimal - 1), 1)} %` : "–"))))))) : [el("p", {class: "card empty"}, "No evaluations yet: evaluate a model to enter the leaderboard.")]));
    };
    select.addEventListener("change", load); load();
  }

  return {api, modelsPage, createPage, modelPage, leaderboardPage, highlight};
})();

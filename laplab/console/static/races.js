/* laplab console: races, the live race board, invitations, profile, usage (over the JSON API). */
"use strict";
const Races = (() => {
  const $ = (sel, root = document) => root.querySelector(sel);
  const el = (tag, attrs = {}, ...children) => {
    const node = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs)) {
      if (k === "class") node.className = v; else if (k === "style") node.style.cssText = v;
      else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
      else if (v !== undefined && v !== null && v !== false) node.setAttribute(k, v === true ? "" : v);
    }
    for (const c of children.flat()) node.append(c instanceof Node ? c : document.createTextNode(c ?? ""));
    return node;
  };
  const api = (...a) => Console.api(...a);
  const secs = v => v === null || v === undefined ? "–" : `${Number(v).toFixed(3)} s`;
  const when = t => t ? new Date(t * 1000).toLocaleString() : "–";
  const RANKING = {average_consecutive: "average of N consecutive laps", best_lap: "best lap", total_time: "total time"};
  const say = (node, text, bad = true) => { node.textContent = text; node.className = bad ? "field-error" : "ok"; };
  const avatar = (r, size = 28) => el("span", {class: "avatar", style: `background:${r.colour};width:${size}px;height:${size}px;font-size:${size * 0.42}px`, title: r.alias}, r.initials);
  const flag = cc => cc ? el("span", {class: "country", title: cc}, cc) : "";
  const lapsText = laps => laps.map(l => l.time === null ? `✗ ${l.status}` : l.time.toFixed(2)).join(" · ");

  // ---- list ------------------------------------------------------------------------------------
  async function racesPage() {
    const body = $("#races tbody");
    const load = async () => {
      const races = await api("GET", "/api/races");
      body.replaceChildren(...races.map(r => el("tr", {"data-race": r.id},
        el("td", {}, el("a", {href: `/races/${r.id}`}, r.name)), el("td", {}, r.track, r.direction === "clockwise" ? " ↻" : ""),
        el("td", {}, r.race_type.replace("_", " ")), el("td", {}, RANKING[r.ranking]),
        el("td", {}, r.private ? "private" : "public"),
        el("td", {}, el("span", {class: `status ${r.open_now ? "running" : "done"}`}, r.open_now ? "open" : (r.closed ? "closed" : "not open"))),
        el("td", {}, r.owner_name), el("td", {}, el("a", {class: "button small", href: `/races/${r.id}/board`}, "Board")))));
      $("#empty").hidden = races.length > 0;
    };
    $("#join-form").addEventListener("submit", async ev => {
      ev.preventDefault();
      try { const r = await api("POST", "/api/races/join", {code: $("#join-code").value.trim()}); location.href = `/races/${r.id}`; }
      catch (e) { say($("#join-error"), e.message); }
    });
    load();
  }

  // ---- create / edit ---------------------------------------------------------------------------
  const FIELDS = ["name", "description", "track", "direction", "race_type", "ranking", "consecutive_laps", "laps",
    "off_track_penalty", "collision_penalty", "max_resets", "max_submissions", "physics"];
  const NUMBERS = ["consecutive_laps", "laps", "max_submissions", "max_resets"];
  const FLOATS = ["off_track_penalty", "collision_penalty"];
  const local = t => t ? new Date(t * 1000 - new Date().getTimezoneOffset() * 60000).toISOString().slice(0, 16) : "";
  async function raceEditPage(raceId) {
    const tracks = await api("GET", "/api/tracks");
    $("#track").replaceChildren(...tracks.map(t => el("option", {value: t.name}, `${t.display_name || t.name} (${t.length_m} m)`)));
    // the race type's own settings (RaceType's names), shown for that race type only
    const OPTIONS = {object_avoidance: ["objects", "randomize_objects"], head_to_bot: ["bots", "bot_speed", "lane_change"]};
    const showOptions = () => { $("#oa-options").hidden = $("#race_type").value !== "object_avoidance";
      $("#h2b-options").hidden = $("#race_type").value !== "head_to_bot"; };
    $("#race_type").addEventListener("change", showOptions);
    const options = () => Object.fromEntries((OPTIONS[$("#race_type").value] || []).map(k => { const n = $(`#opt-${k}`);
      return [k, n.type === "checkbox" ? n.checked : k === "bot_speed" ? parseFloat(n.value) : parseInt(n.value, 10)]; }));
    if (raceId) {
      const r = await api("GET", `/api/races/${raceId}`);
      for (const f of FIELDS) if ($(`#${f}`)) $(`#${f}`).value = r[f] ?? "";
      for (const [k, v] of Object.entries(r.options || {})) { const n = $(`#opt-${k}`); if (n) { if (n.type === "checkbox") n.checked = !!v; else n.value = v; } }
      $("#private").checked = r.private; $("#opens").value = local(r.opens); $("#closes").value = local(r.closes);
      $("#sensors").value = (r.sensors || []).join(",");
    }
    showOptions();
    $("#race-form").addEventListener("submit", async ev => {
      ev.preventDefault();
      const body = {};
      for (const f of FIELDS) {
        const v = $(`#${f}`).value.trim();
        body[f] = NUMBERS.includes(f) ? (v === "" ? null : parseInt(v, 10)) : FLOATS.includes(f) ? parseFloat(v) : v;
      }
      body.physics = body.physics || null; body.private = $("#private").checked;
      body.opens = $("#opens").value ? new Date($("#opens").value).getTime() / 1000 : null;
      body.closes = $("#closes").value ? new Date($("#closes").value).getTime() / 1000 : null;
      body.sensors = $("#sensors").value.split(",").map(s => s.trim()).filter(Boolean);
      body.options = options();
      try {
        const r = await api(raceId ? "PUT" : "POST", raceId ? `/api/races/${raceId}` : "/api/races", body);
        const re = r.rescored;  // an edit re-ranks the submissions from their recorded laps: say how on the race's page
        if (re && re.changed.length) sessionStorage.setItem(`rescored-${r.id}`, `Re-ranked under the new rules: ${re.ranked} of ${re.submissions} submissions rank, ` +
          `${re.changed.length} changed (${re.changed.map(c => `${c.alias}: ${c.rank_before ? "#" + c.rank_before : "unranked"} → ${c.rank ? "#" + c.rank : "unranked"}`).join(", ")}).`);
        location.href = `/races/${r.id}`;
      } catch (e) { say($("#form-error"), e.message); if (e.detail?.field && $(`#${e.detail.field}`)) $(`#${e.detail.field}`).focus(); }
    });
  }

  // ---- one race --------------------------------------------------------------------------------
  function lapCells(laps, n) {
    const out = [];
    for (let i = 0; i < n; i++) {
      const l = laps[i];
      out.push(el("td", {class: "num", title: l ? `${l.off_track} off-track, ${l.resets} resets` : ""},
        !l ? "–" : l.time === null ? el("span", {class: "bad"}, l.status) : `${l.time.toFixed(3)}`,
        l && l.off_track ? el("sup", {class: "muted"}, ` ${l.off_track}✗`) : ""));
    }
    return out;
  }
  async function racePage(raceId, manages) {
    const race = await api("GET", `/api/races/${raceId}`);
    $("#race-facts").replaceChildren(...[
      ["Track", `${race.track} · ${race.direction}`], ["Race type", race.race_summary || race.race_type.replace("_", " ")],
      ["Ranking", race.ranking === "average_consecutive" ? `average of ${race.consecutive_laps} consecutive laps` : RANKING[race.ranking]],
      ["Laps", race.laps], ["Off-track penalty", `${race.off_track_penalty} s`], ["Collision penalty", `${race.collision_penalty} s`],
      ["Resets per lap", race.max_resets ?? "unlimited"], ["Submissions per racer", race.max_submissions],
      ["Car", race.physics ?? "each model's own"], ["Opens", when(race.opens)], ["Closes", when(race.closes)],
      ["Access", race.private ? "private (join code)" : "public"], ["Owner", race.owner_name],
    ].map(([k, v]) => el("div", {}, el("span", {}, k), String(v))));
    $("#race-description").textContent = race.description || "";
    const head = $("#board-head"), last = head.lastElementChild;
    for (let i = 1; i <= race.laps; i++) head.insertBefore(el("th", {class: "num"}, `Lap ${i}`), last);
    $("#race-state").replaceChildren(el("span", {class: `status ${race.open_now ? "running" : "done"}`}, race.open_now ? "open for submissions" : race.closed ? "closed" : "not open now"));
    const rescored = sessionStorage.getItem(`rescored-${raceId}`);
    if (rescored) { sessionStorage.removeItem(`rescored-${raceId}`); $("#race-state").after(el("p", {class: "ok", id: "rescored"}, rescored)); }
    if (race.code) { $("#code-box").hidden = false; $("#race-code").textContent = race.code; $("#race-link").textContent = `${location.origin}/races/join/${race.code}`; }
    const models = await api("GET", "/api/models");
    $("#model").replaceChildren(...models.filter(m => m.status === "ready" || m.status === "interrupted").map(m => el("option", {value: m.name}, m.name)));
    $("#submit-form").addEventListener("submit", async ev => {
      ev.preventDefault();
      try { const s = await api("POST", `/api/races/${raceId}/submissions`, {model: $("#model").value}); say($("#submit-result"), `submitted: evaluation ${s.job} queued`, false); load(); }
      catch (e) { say($("#submit-result"), e.message); }
    });
    for (const [id, method, path, confirmText] of [["#close", "POST", "close"], ["#reopen", "POST", "reopen"],
      ["#clone", "POST", "clone"], ["#delete", "DELETE", "", "Delete this race and its submissions' records?"]]) {
      const b = $(id); if (!b) continue;
      b.addEventListener("click", async () => {
        if (confirmText && !confirm(confirmText)) return;
        try { const r = await api(method, `/api/races/${raceId}${path ? "/" + path : ""}`); location.href = id === "#delete" ? "/races" : `/races/${r.id}`; }
        catch (e) { alert(e.message); }
      });
    }
    async function load() {
      const [board, subs] = await Promise.all([api("GET", `/api/races/${raceId}/leaderboard`), api("GET", `/api/races/${raceId}/submissions`)]);
      $("#board tbody").replaceChildren(...board.entries.map(r => el("tr", {"data-rank": r.rank},
        el("td", {class: "num"}, r.rank), el("td", {}, avatar(r), " ", r.alias, " ", flag(r.country)),
        el("td", {class: "num"}, el("b", {}, secs(r.score))), ...lapCells(r.laps, race.laps), el("td", {}, when(r.created)))));
      $("#board-empty").hidden = board.entries.length > 0;
      $("#subs tbody").replaceChildren(...subs.reverse().map(s => el("tr", {"data-submission": s.id, "data-state": s.state},
        el("td", {}, when(s.created)), el("td", {}, manages ? `${s.alias} · ` : "", s.model), el("td", {}, el("span", {class: `status ${s.state}`}, s.state)),
        el("td", {class: "num"}, secs(s.score)), el("td", {}, lapsText(s.laps)), el("td", {class: "reason"}, s.score === null ? s.reason || "" : "ranked", s.rules_note ? el("div", {class: "muted"}, s.rules_note) : ""),
        el("td", {}, s.video ? el("a", {href: `/api/races/${raceId}/submissions/${s.id}/video`, target: "_blank"}, "video") : ""))));
      $("#subs-empty").hidden = subs.length > 0;
    }
    load(); setInterval(load, 3000);
  }

  // ---- the live board --------------------------------------------------------------------------
  async function boardPage(raceId) {
    let outline = null, replayOf = null, replay = null, frame = 0;
    const canvas = $("#replay"), ctx = canvas.getContext("2d");
    async function tick() {
      try {
        const board = await api("GET", `/api/races/${raceId}/leaderboard`);
        const race = board.race;
        $("#board-title").textContent = race.name;
        $("#board-sub").textContent = `${race.track} · ${race.direction} · ${race.ranking === "average_consecutive" ? `average of ${race.consecutive_laps} consecutive laps` : RANKING[race.ranking]} · ${race.laps} laps`;
        $("#board-rows").replaceChildren(...board.entries.map(r => el("div", {class: `board-row${r.rank <= 3 ? " top top" + r.rank : ""}`, "data-rank": r.rank},
          el("div", {class: "rank"}, r.rank), avatar(r, 54), el("div", {class: "racer"}, r.alias, " ", flag(r.country)),
          el("div", {class: "laps"}, lapsText(r.laps)), el("div", {class: "score"}, secs(r.score)))));
        $("#board-empty").hidden = board.entries.length > 0;
        if (+$("#board-rows").dataset.count !== board.entries.length) $("#board-rows").dataset.changedAt = Date.now();
        $("#board-rows").dataset.count = board.entries.length;
        $("#updated").textContent = `updated ${new Date().toLocaleTimeString()}`;
        if (!outline) outline = await api("GET", `/api/tracks/${encodeURIComponent(race.track)}/outline`);
        if (board.latest !== replayOf) {
          const r = await api("GET", `/api/races/${raceId}/replay`);
          replayOf = board.latest; replay = r.laps.length ? r : null; frame = 0;
          $("#replay-who").textContent = replay ? `latest: ${r.alias} · ${secs(r.score)}` : "waiting for the first result";
        }
      } catch (e) { $("#updated").textContent = e.message; }
    }
    function draw() {
      requestAnimationFrame(draw);
      if (!outline) return;
      const all = outline.outer.concat(outline.inner), xs = all.map(p => p[0]), ys = all.map(p => p[1]);
      const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
      const s = Math.min((canvas.width - 40) / (x1 - x0), (canvas.height - 40) / (y1 - y0));
      const P = p => [20 + (p[0] - x0) * s, canvas.height - 20 - (p[1] - y0) * s];
      ctx.fillStyle = "#0f1b2a"; ctx.fillRect(0, 0, canvas.width, canvas.height);
      const ring = (pts, fill) => { ctx.beginPath(); pts.forEach((p, i) => i ? ctx.lineTo(...P(p)) : ctx.moveTo(...P(p))); ctx.closePath(); ctx.fillStyle = fill; ctx.fill(); };
      ring(outline.outer, "#3b4a5c"); ring(outline.inner, "#0f1b2a");
      ctx.setLineDash([6, 8]); ctx.strokeStyle = "#ffffff55"; ctx.beginPath(); outline.center.forEach((p, i) => i ? ctx.lineTo(...P(p)) : ctx.moveTo(...P(p))); ctx.stroke(); ctx.setLineDash([]);
      if (!replay) return;
      const path = replay.laps.flat(); frame = (frame + 1) % (path.length + 60);
      const upto = Math.min(frame, path.length - 1);
      ctx.strokeStyle = replay.colour; ctx.lineWidth = 3; ctx.beginPath();
      for (let i = Math.max(0, upto - 120); i <= upto; i++) {  // a reset puts the car back: no line across the jump
        const jump = i === Math.max(0, upto - 120) || Math.hypot(path[i][0] - path[i - 1][0], path[i][1] - path[i - 1][1]) > 0.4;
        jump ? ctx.moveTo(...P(path[i])) : ctx.lineTo(...P(path[i]));
      }
      ctx.stroke(); ctx.lineWidth = 1;
      const [cx, cy] = P(path[upto]); ctx.fillStyle = replay.colour; ctx.beginPath(); ctx.arc(cx, cy, 9, 0, 7); ctx.fill();
      canvas.dataset.frames = (+canvas.dataset.frames || 0) + 1;
    }
    await tick(); setInterval(tick, 1000); draw();
  }

  // ---- people ----------------------------------------------------------------------------------
  async function invitesPage() {
    const load = async () => {
      const rows = await api("GET", "/api/invites");
      $("#invites tbody").replaceChildren(...rows.map(i => el("tr", {"data-invite": i.id}, el("td", {}, i.id), el("td", {}, i.role),
        el("td", {}, i.status), el("td", {}, when(i.expires)),
        el("td", {}, i.status === "open" ? el("button", {class: "button small danger", onclick: async () => { await api("DELETE", `/api/invites/${i.id}`); load(); }}, "Revoke") : ""))));
    };
    $("#invite-form").addEventListener("submit", async ev => {
      ev.preventDefault();
      try {
        const i = await api("POST", "/api/invites", {role: $("#invite-role").value, expires_in_h: parseFloat($("#invite-hours").value)});
        $("#invite-link").hidden = false; $("#invite-link-text").value = i.link; load();
      } catch (e) { say($("#invite-error"), e.message); }
    });
    load();
  }
  async function profilePage() {
    const show = p => { $("#avatar-preview").replaceChildren(avatar(p, 64)); $("#alias").value = p.alias; $("#country").value = p.country; $("#colour").value = p.colour; };
    show(await api("GET", "/api/me/profile"));
    $("#profile-form").addEventListener("submit", async ev => {
      ev.preventDefault();
      try { show(await api("PUT", "/api/me/profile", {alias: $("#alias").value, country: $("#country").value, colour: $("#colour").value})); say($("#profile-result"), "saved", false); }
      catch (e) { say($("#profile-result"), e.message); }
    });
    $("#password-form").addEventListener("submit", async ev => {
      ev.preventDefault();
      try { await api("POST", "/api/me/password", {old_password: $("#old-password").value || null, new_password: $("#new-password").value}); say($("#password-result"), "password changed", false); ev.target.reset(); }
      catch (e) { say($("#password-result"), e.message); }
    });
  }
  const mib = b => `${(b / 1048576).toFixed(1)} MiB`;
  const limit = (v, unit = "") => v === null || v === undefined ? "unlimited" : `${v}${unit}`;
  async function usagePage(isAdmin) {
    const u = await api("GET", "/api/usage");
    $("#my-usage").replaceChildren(...[["Minutes used", u.minutes_used], ["Minutes reserved (queued, running)", u.minutes_queued],
      ["Minutes left", limit(u.minutes_left)], ["Minutes quota", limit(u.minutes_limit)], ["Models", `${u.models} of ${limit(u.models_limit)}`],
      ["Storage", mib(u.storage_bytes)]].map(([k, v]) => el("div", {}, el("span", {}, k), String(v))));
    if (!isAdmin) return;
    $("#admin-usage").hidden = false;
    $("#all-usage tbody").replaceChildren(...u.users.map(r => el("tr", {"data-user": r.user}, el("td", {}, r.user), el("td", {}, r.role),
      el("td", {class: "num"}, r.minutes_used), el("td", {class: "num"}, r.minutes_queued), el("td", {class: "num"}, limit(r.minutes_limit)),
      el("td", {class: "num"}, `${r.models} / ${limit(r.models_limit)}`), el("td", {class: "num"}, mib(r.storage_bytes)))));
    const q = await api("GET", "/api/quotas");
    for (const k of Object.keys(q)) if ($(`#q-${k}`)) $(`#q-${k}`).value = q[k] ?? "";
    $("#quota-form").addEventListener("submit", async ev => {
      ev.preventDefault();
      const body = {}; for (const k of Object.keys(q)) { const v = $(`#q-${k}`).value.trim(); body[k] = v === "" ? null : Number(v); }
      try { await api("PUT", "/api/quotas", body); say($("#quota-result"), "saved", false); } catch (e) { say($("#quota-result"), e.message); }
    });
    $("#user-quota-form").addEventListener("submit", async ev => {
      ev.preventDefault();
      const num = id => $(id).value.trim() === "" ? null : Number($(id).value);
      try { await api("PUT", `/api/users/${encodeURIComponent($("#uq-name").value)}/quota`, {minutes: num("#uq-minutes"), models: num("#uq-models")}); say($("#uq-result"), "saved", false); }
      catch (e) { say($("#uq-result"), e.message); }
    });
  }
  return {racesPage, raceEditPage, racePage, boardPage, invitesPage, profilePage, usagePage};
})();

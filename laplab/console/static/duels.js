/* laplab console: "Race another model" on a model's page (head-to-model races, over /api/models/NAME/duels). */
"use strict";
const Duels = (() => {
  const $ = (sel, root = document) => root.querySelector(sel);
  const el = (tag, attrs = {}, ...children) => {
    const node = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs)) {
      if (k === "class") node.className = v; else if (k === "style") node.style.cssText = v;
      else if (v !== undefined && v !== null && v !== false) node.setAttribute(k, v === true ? "" : v);
    }
    for (const c of children.flat()) node.append(c instanceof Node ? c : document.createTextNode(c ?? ""));
    return node;
  };
  const api = (...a) => Console.api(...a);
  const secs = v => v === null || v === undefined ? "–" : `${Number(v).toFixed(3)} s`;

  async function modelPage(name) {
    const base = `/api/models/${encodeURIComponent(name)}`;
    const form = $("#duel-form"), error = $("#duel-error"), select = $("#duel-opponent");
    if (!form) return;
    let choices = {opponents: []};
    const showRefusal = () => {  // an opponent that cannot race says why next to the field
      const pick = choices.opponents.find(o => o.name === select.value);
      error.textContent = pick && pick.refused ? `${pick.name}: ${pick.refused}` : "";
      $("#duel-start").disabled = !pick || !!pick.refused;
    };
    try {
      const [opponents, tracks] = await Promise.all([api("GET", `${base}/opponents`), api("GET", "/api/tracks")]);
      choices = opponents;
      select.replaceChildren(...opponents.opponents.map(o => el("option", {value: o.name, "data-ready": o.ready ? "1" : "0"},
        `${o.name}${o.owner ? ` (${o.owner})` : ""}${o.ready ? "" : " – cannot race"}`)));
      const ready = opponents.opponents.find(o => o.ready); if (ready) select.value = ready.name;
      $("#duel-track").replaceChildren(...tracks.flatMap(t => [t.name, `${t.name}@reversed`]).map(v => el("option",
        {value: v, selected: v === opponents.track}, v.endsWith("@reversed") ? `${v.replace("@reversed", "")} (reversed)` : v)));
      $("#duel-laps").value = opponents.laps; $("#duel-max-time").value = opponents.max_time_s;
      if (opponents.rule) $("#duel-rule").textContent += ` ${opponents.rule}.`;
      if (!opponents.opponents.length) error.textContent = "no other model to race: train or clone another one first";
      else showRefusal();
    } catch (e) { error.textContent = e.message; }
    select.addEventListener("change", showRefusal);
    form.addEventListener("submit", async ev => {
      ev.preventDefault(); error.textContent = "";
      try {
        await api("POST", `${base}/duels`, {opponent: select.value, track: $("#duel-track").value || null,
          laps: +$("#duel-laps").value, max_time_s: +$("#duel-max-time").value, video: $("#duel-video").checked});
        load();
      } catch (e) { error.textContent = e.message; }
    });
    async function load() {
      const list = await api("GET", `${base}/duels`);
      $("#duels").replaceChildren(...list.slice().reverse().map(race => el("div", {class: "evaluation duel", "data-duel": race.id, "data-status": race.status},
        el("h3", {}, `Race ${race.id}: `, ...race.models.map((m, i) => el("span", {style: `color:${race.colours[i]}`}, i ? ` vs ${m}` : m)),
          ` · ${race.stopped ? `stopped${race.duration !== null ? ` after ${secs(race.duration)}` : ""}` : race.status}`, race.track ? ` · ${race.track}` : "", race.laps ? ` · ${race.laps} lap${race.laps > 1 ? "s" : ""}` : ""),
        race.error ? el("p", {class: "field-error"}, race.error) : "",
        race.racers.length ? el("table", {class: "grid compact"},
          el("thead", {}, el("tr", {}, ...["Position", "Model", "Laps", "Finish time", "Lap times", "Crashes", "Off-track", "Penalty"].map((h, i) => el("th", {class: i > 1 ? "num" : ""}, h)))),
          el("tbody", {}, ...race.racers.map(r => el("tr", {},
            el("td", {}, r.position), el("td", {style: r.car !== null ? `color:${race.colours[r.car]}` : ""}, r.name), el("td", {class: "num"}, r.laps),
            el("td", {class: "num"}, r.finish_time === null ? `did not finish (${Number(r.progress).toFixed(1)} %)` : secs(r.finish_time)),
            el("td", {class: "num"}, r.lap_times.map(secs).join(", ") || "–"), el("td", {class: "num"}, r.crash_count),
            el("td", {class: "num"}, r.off_track_count), el("td", {class: "num"}, `${r.penalty_time} s`))))) : "",
        race.picture ? el("img", {src: race.picture, alt: `race ${race.id} from above`, class: "duel-picture", width: 480}) : "",
        race.video ? el("p", {}, el("a", {href: race.video, target: "_blank"}, "Watch the race")) : "")));
      if (list.some(r => ["queued", "running"].includes(r.status))) setTimeout(load, 1500);
    }
    load();
  }
  return {modelPage};
})();

// The Now page refreshes itself: /now.json once a second, its facts written into the page as text
// (textContent only: nothing from the journal or the status file is ever parsed as HTML).
"use strict";
(function () {
  const PERIOD_MS = 1000;
  const byId = (id) => document.getElementById(id);
  const text = (id, value) => { const el = byId(id); if (el) { el.textContent = value == null ? "" : String(value); } };
  const when = (s) => (s == null ? "-" : new Date(s * 1000).toLocaleString());

  function show(f) {
    const s = f.service, j = f.journal;
    const box = byId("state-box");
    box.className = "state-box state-" + (s.state || "none");
    text("state", s.state || "no status");
    text("liveness", s.reason);
    text("in-state", s.since ? "since " + when(s.since) + " (" + s.in_state_s + " s)" : "");
    text("status-age", s.status_age_s == null ? "-" : s.status_age_s);
    const table = byId("devices");
    table.replaceChildren();
    for (const [name, d] of Object.entries(s.devices || {})) {
      const row = table.insertRow();
      row.dataset.device = name;
      const th = document.createElement("th"); th.textContent = name; row.appendChild(th);
      const c = row.insertCell(); c.textContent = d.connected ? "connected" : "NOT connected"; c.className = d.connected ? "ok" : "bad";
      row.insertCell().textContent = d.last_error ? d.last_error.code + ": " + d.last_error.message : "";
    }
    const plc = s.plc, registers = byId("plc-registers");
    if (registers) {
      registers.textContent = plc ? "PLC control " + (plc.control.join(" ") || "-") + ", job " + plc.job + ", part tag " +
        plc.part_tag + ", PLC heartbeat " + plc.plc_heartbeat + "; status " + (plc.status.join(" ") || "-") +
        ", heartbeat " + (plc.heartbeat == null ? "-" : plc.heartbeat) : "PLC registers: not connected";
    }
    byId("fault-panel").hidden = !s.fault;
    text("fault-code", s.fault ? s.fault.code : ""); text("fault-plc", s.fault ? s.fault.plc_code : "");
    text("fault-message", s.fault ? s.fault.message : ""); text("fault-meaning", s.fault ? s.fault.meaning : "");
    const last = j.last, result = byId("last-result");
    result.replaceChildren();
    if (last) {
      const a = document.createElement("a"); a.id = "last-link"; a.href = "/cycles/" + last.number; a.textContent = "cycle " + last.number;
      const st = document.createElement("span"); st.id = "last-status"; st.className = last.status === "ok" ? "ok" : "bad";
      st.textContent = last.status === "ok" ? "ok" : (last.error_code || "no error code") + " (" + (last.plc_code == null ? "-" : last.plc_code) + ")";
      let rest = " finished " + when(last.finished_at);
      if (last.job != null) { rest += ", job " + last.job; }
      if (last.part_tag != null) { rest += ", part tag " + last.part_tag; }
      result.append(a, " ", st, rest);
    } else { result.textContent = "no cycle yet"; }
    text("last-message", last && last.error_message ? last.error_message : "");
    text("last-meaning", last && last.meaning ? last.meaning : "");
    text("last-offset", last && last.offset ? "base offset x y z mm, a b c deg: " + last.offset.map((v) => v.toFixed(2)).join(" ") +
      "; RMS " + (last.rms_px == null ? "-" : last.rms_px.toFixed(3)) + " px" : "");
    text("last-unreadable", last && last.unreadable && last.unreadable.length ? "not shown: " + last.unreadable.join("; ") : "");
    text("counter", j.cycle_counter == null ? "-" : j.cycle_counter);
    const health = byId("health");
    if (health && f.health) { health.className = "health-" + (f.health.level || "none"); text("health", f.health.summary); }
    text("journal-state", j.error ? j.error.code + " " + j.error.message : "readable");
    text("refreshed", "last " + new Date().toLocaleTimeString());
  }

  async function poll() {
    try {
      const answer = await fetch("/now.json", { cache: "no-store", credentials: "same-origin" });
      if (answer.ok) { show(await answer.json()); } else { text("refreshed", "the page's server answered " + answer.status); }
    } catch (e) {
      text("refreshed", "the page's server does not answer (" + new Date().toLocaleTimeString() + ")");
    }
    setTimeout(poll, PERIOD_MS);
  }
  setTimeout(poll, PERIOD_MS);
})();

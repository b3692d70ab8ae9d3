// The dashboard: signs the browser in with an API key (POST /v1/session sets an HttpOnly cookie), then
// polls the jobs (If-None-Match, so an unchanged list costs a 304) and lists orchards, rows and trees with
// their latest H, W and D and links to each measurement's report. All through the service's own API.
const POLL_MS = 2000;
let jobsEtag = null, lastJobs = [], succeeded = null; // ids of the jobs seen succeeded

const $ = (selector) => document.querySelector(selector);

function element(tag, attributes = {}, ...children) {
  const node = document.createElement(tag);
  for (const [name, value] of Object.entries(attributes)) {
    if (name === "class") node.className = value; else node.setAttribute(name, value);
  }
  for (const child of children) node.append(child instanceof Node ? child : document.createTextNode(String(child ?? "")));
  return node;
}

// The session ended (signed out here or elsewhere, or expired) while a request was on its way: the sign-in
// form is shown, and whatever was loading stops.
class SignedOut extends Error {}

async function api(path, options = {}) {
  const response = await fetch(path, { credentials: "same-origin", cache: "no-store", ...options });
  if (response.status === 401) { showSignIn("Signed out: sign in again."); throw new SignedOut("signed out"); }
  return response;
}

function showSignIn(message = "") {
  $("#sign-in").hidden = false; $("#signed-in").hidden = true; $("#sign-out").hidden = true;
  $("#who").textContent = ""; $("#message").textContent = message;
}

async function showSignedIn(key) {
  $("#sign-in").hidden = true; $("#signed-in").hidden = false; $("#sign-out").hidden = false;
  $("#who").textContent = `${key.name} (${key.prefix}, ${key.scopes.join(" ")})`;
  try {
    await Promise.all([pollJobs(), loadFarm()]);
  } catch (error) {
    if (!(error instanceof SignedOut)) throw error;  // signed out while the lists loaded: nothing to show
  }
}

function metres(value) { return `${value.toFixed(2)} m`; }

function jobRow(job) {
  const state = element("span", { class: `state ${job.state}` }, job.state);
  const stage = job.state === "running"
    ? element("span", {}, `${job.stage ?? ""} `, element("progress", { max: "1", value: String(job.progress) }))
    : (job.stage ?? "");
  let result = "";
  if (job.measurement_id != null) {
    result = element("a", { href: `/v1/measurements/${job.measurement_id}/report` }, "report");
  } else if (job.error) {
    const where = [job.error.view, job.error.color && `${job.error.color} ball`, job.error.file].filter(Boolean).join(", ");
    result = element("div", { class: "error" }, `${job.error.code}${where ? ` (${where})` : ""}: ${job.error.message}`);
    if (job.error.hint) result.append(element("div", { class: "hint" }, job.error.hint));
  }
  return element("tr", { "data-job": String(job.id), "data-state": job.state },
    element("td", {}, job.id), element("td", {}, `${job.orchard} / ${job.row} / ${job.tree}`),
    element("td", {}, state), element("td", {}, stage), element("td", { class: "wide" }, job.attempts),
    element("td", { class: "wide" }, new Date(job.created_at).toLocaleString()), element("td", {}, result));
}

async function pollJobs() {
  const headers = jobsEtag ? { "If-None-Match": jobsEtag } : {};
  const response = await api("/v1/jobs?limit=25", { headers });
  if (response.status === 200) {
    jobsEtag = response.headers.get("ETag");
    lastJobs = (await response.json()).items;
    $("#jobs tbody").replaceChildren(...lastJobs.map(jobRow));
    const done = lastJobs.filter((job) => job.state === "succeeded").map((job) => job.id);
    if (succeeded !== null && done.some((id) => !succeeded.has(id))) loadFarm(); // new measurements
    succeeded = new Set(done);
  }
  $("#jobs-updated").textContent = `${lastJobs.length} recent jobs · checked ${new Date().toLocaleTimeString()}`;
}

async function items(path) { return (await (await api(path)).json()).items; }

async function loadFarm() {
  const farm = $("#farm");
  const orchards = await items("/v1/orchards");
  if (!orchards.length) { farm.replaceChildren(element("p", { class: "muted" }, "No capture yet.")); return; }
  const blocks = [];
  for (const orchard of orchards) {
    const block = element("details", { open: "" }, element("summary", {}, orchard.name));
    for (const row of await items(`/v1/orchards/${orchard.id}/rows`)) {
      const table = element("table", {}, element("thead", {}, element("tr", {},
        ...["tree", "H", "W", "D", "captured", ""].map((h) => element("th", {}, h)))));
      const body = element("tbody");
      for (const tree of await items(`/v1/rows/${row.id}/trees`)) {
        const latest = tree.latest_measurement;
        body.append(element("tr", { "data-tree": String(tree.id) }, element("td", {}, tree.name),
          ...(latest
            ? [metres(latest.height_m), metres(latest.width_m), metres(latest.thickness_m), new Date(latest.captured_at).toLocaleDateString()].map((v) => element("td", {}, v))
            : [element("td", { colspan: "4", class: "muted" }, "not measured yet")]),
          element("td", {}, latest ? element("a", { href: `/v1/measurements/${latest.id}/report` }, "report") : "",
            latest ? " · " : "", latest ? element("a", { href: `/v1/trees/${tree.id}/history.png` }, "growth") : "")));
      }
      table.append(body);
      block.append(element("details", { open: "" }, element("summary", {}, `Row ${row.name}`), element("div", { class: "scroll" }, table)));
    }
    blocks.push(block);
  }
  farm.replaceChildren(...blocks);
}

$("#sign-in-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  const response = await fetch("/v1/session", { method: "POST", headers: { Authorization: `Bearer ${$("#key").value.trim()}` } });
  if (!response.ok) { $("#message").textContent = (await response.json()).detail ?? "Sign-in failed."; return; }
  $("#key").value = "";
  await showSignedIn((await response.json()).key);
});

$("#sign-out").addEventListener("click", async () => {
  await fetch("/v1/session", { method: "DELETE" });
  showSignIn("Signed out.");
});

async function start() {
  const response = await fetch("/v1/keys/current", { cache: "no-store" });
  if (response.ok) await showSignedIn((await response.json()).key); else showSignIn();
  setInterval(() => { if (!$("#signed-in").hidden) pollJobs().catch(() => {}); }, POLL_MS);
}

start();

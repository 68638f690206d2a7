// The dashboard's shell: the token gate, the navigation and the hash routes
//   #/jobs[?kind=&state=&pick=] · #/submit · #/jobs/<id> · #/jobs/<id>/files · #/jobs/<id>/report
//   · #/jobs/<id>/compare · #/compare/<id>/<id>

import { token } from "./api.js";
import { fill, h } from "./dom.js";
import { closeAll } from "./events.js";
import { compareView } from "./views/compare.js";
import { jobView } from "./views/job.js";
import { jobsView } from "./views/jobs.js";
import { loginView } from "./views/login.js";
import { submitView } from "./views/submit.js";

const main = document.getElementById("view");
const nav = document.getElementById("nav");
let current = null;

function navigate(hash) {
  if (location.hash === hash) route();
  else location.hash = hash;
}

function signOut(reason) {
  token.clear();
  closeAll();
  show(loginView(route, reason));
}

function show(view) {
  current?.dispose();
  current = view;
  fill(main, view.element);
  fill(nav, token.get() ? [
    h("a", { href: "#/jobs" }, "Jobs"),
    h("a", { href: "#/submit" }, "Submit"),
    h("button", { type: "button", id: "sign-out", class: "link", onclick: () => signOut() }, "Sign out"),
  ] : null);
}

function route() {
  if (!token.get()) {
    show(loginView(route));
    return;
  }
  const [path, query = ""] = location.hash.replace(/^#\/?/, "").split("?");
  const parts = path.split("/").map(decodeURIComponent);
  if (parts[0] === "submit") show(submitView(navigate));
  else if (parts[0] === "compare" && parts[2]) show(compareView(parts[1], parts[2]));
  else if (parts[0] === "jobs" && parts[1]) show(jobView(parts[1], parts[2] || "overview"));
  else show(jobsView(new URLSearchParams(query), navigate));
}

window.addEventListener("hashchange", route);
window.addEventListener("nbake:unauthorized", (event) => signOut(`The server refused the token: ${event.detail}`));
route();

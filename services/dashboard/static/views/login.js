// The token form: asked once per browser tab, checked against the API before anything is shown.

import { getJson, paths, token } from "../api.js";
import { h } from "../dom.js";
import { problemBox } from "../components.js";

export function loginView(onSignedIn, reason) {
  const input = h("input", {
    type: "password", name: "token", id: "token", autocomplete: "off", required: true, placeholder: "bearer token",
  });
  const status = h("div", {}, reason ? problemBox(reason) : null);
  const form = h("form", { class: "login", id: "login-form" },
    h("h2", {}, "Sign in"),
    h("p", {}, "Paste a token of NBAKE_TOKENS (read, submit or admin) or the server's generated ",
      h("code", {}, "<data-dir>/admin-token"), ". It is kept in this tab's session storage only."),
    h("label", { for: "token" }, "Token"), input,
    h("button", { type: "submit" }, "Sign in"), status);
  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    token.set(input.value.trim());
    try {
      await getJson(paths.jobs("?limit=1"));
      onSignedIn();
    } catch (error) {
      token.clear();
      status.replaceChildren(problemBox(error));
    }
  });
  queueMicrotask(() => input.focus());
  return { element: form, dispose() {} };
}

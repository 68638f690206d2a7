// The REST API with the user's bearer token, kept in sessionStorage (this tab only, gone when it closes).
// Every error is the server's problem+json document; a 401 forgets the token and asks for it again.

const TOKEN_KEY = "nbake.token";

export const token = {
  get: () => sessionStorage.getItem(TOKEN_KEY),
  set: (value) => sessionStorage.setItem(TOKEN_KEY, value),
  clear: () => sessionStorage.removeItem(TOKEN_KEY),
};

export class ApiError extends Error {
  constructor(status, problem) {
    const where = problem.field ? `${problem.field}: ` : "";
    super(`${problem.title || "Error"} (${status}): ${where}${problem.detail || ""}`.trim());
    this.status = status;
    this.problem = problem;
  }
}

async function errorOf(response) {
  let problem;
  try {
    problem = await response.json();
  } catch {
    problem = { title: response.statusText || "Error", detail: `HTTP ${response.status}` };
  }
  if (response.status === 401) {
    token.clear();
    window.dispatchEvent(new CustomEvent("nbake:unauthorized", { detail: problem.detail }));
  }
  return new ApiError(response.status, problem);
}

/** fetch(path) with the token; throws ApiError for any status that is not 2xx. */
export async function request(path, { method = "GET", body, signal, accept = "application/json" } = {}) {
  const bearer = token.get();
  if (!bearer) throw new ApiError(401, { title: "Unauthorized", detail: "no token given" });
  const headers = { Authorization: `Bearer ${bearer}`, Accept: accept };
  const init = { method, headers, signal, cache: "no-store" };
  if (body !== undefined) {
    init.body = JSON.stringify(body);
    headers["Content-Type"] = "application/json";
  }
  const response = await fetch(path, init);
  if (!response.ok) throw await errorOf(response);
  return response;
}

export const getJson = async (path, options) => (await request(path, options)).json();
export const postJson = async (path, body) => (await request(path, { method: "POST", body })).json();

// The API is the dashboard's parent folder (`/ui/` -> `/v1/...`), so a proxy that mounts the server
// under a prefix serves both.
const API = `${new URL("..", location.href).pathname}v1`;

export const paths = {
  jobs: (query = "") => `${API}/jobs${query}`,
  job: (id) => `${API}/jobs/${encodeURIComponent(id)}`,
  cancel: (id) => `${API}/jobs/${encodeURIComponent(id)}:cancel`,
  events: (id, after) => `${API}/jobs/${encodeURIComponent(id)}/events?after=${after}`,
  artifact: (id) => `${API}/artifacts/${encodeURIComponent(id)}`,
  file: (id, name) => `${API}/artifacts/${encodeURIComponent(id)}/files/${name.split("/").map(encodeURIComponent).join("/")}`,
  kinds: `${API}/kinds`,
  scenes: `${API}/scenes`,
};

// Artifacts are content-addressed, so a file fetched once is the same file for the page's lifetime.
const blobUrls = new Map();

/** An object URL of an artifact file (images need the token, which an <img src> cannot send). */
export async function fileUrl(artifactId, name) {
  const key = `${artifactId}/${name}`;
  if (!blobUrls.has(key)) {
    const pending = request(paths.file(artifactId, name), { accept: "*/*" })
      .then((response) => response.blob())
      .then((blob) => URL.createObjectURL(blob));
    pending.catch(() => blobUrls.delete(key));
    blobUrls.set(key, pending);
  }
  return blobUrls.get(key);
}

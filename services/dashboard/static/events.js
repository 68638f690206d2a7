// A job's Server-Sent Events read with fetch (an EventSource cannot send the Authorization header), one
// stream per job shared by every view that follows it, resumed after the last seen `seq` when it drops.

import { ApiError, paths, request } from "./api.js";

/** The messages of a text/event-stream body: {id, event, data}; comments and retry lines skipped. */
export async function* serverSentEvents(body) {
  const reader = body.pipeThrough(new TextDecoderStream()).getReader();
  let buffer = "";
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    buffer += value.replace(/\r\n?/g, "\n");
    let end;
    while ((end = buffer.indexOf("\n\n")) >= 0) {
      const block = buffer.slice(0, end);
      buffer = buffer.slice(end + 2);
      const message = { id: null, event: "message", data: [] };
      for (const line of block.split("\n")) {
        if (!line || line.startsWith(":")) continue;
        const colon = line.indexOf(":");
        const field = colon < 0 ? line : line.slice(0, colon);
        const value = colon < 0 ? "" : line.slice(colon + 1).replace(/^ /, "");
        if (field === "data") message.data.push(value);
        else if (field === "id") message.id = value;
        else if (field === "event") message.event = value;
      }
      if (message.data.length) yield { ...message, data: message.data.join("\n") };
    }
  }
}

const RETRY_MS = 1000;

class JobStream {
  constructor(jobId) {
    this.jobId = jobId;
    this.events = [];
    this.listeners = new Set();
    this.ended = false;
    this.users = 0;
    this.abort = new AbortController();
    this.run();
  }

  async run() {
    let after = 0;
    while (!this.ended && !this.abort.signal.aborted) {
      try {
        const response = await request(paths.events(this.jobId, after), {
          signal: this.abort.signal,
          accept: "text/event-stream",
        });
        for await (const message of serverSentEvents(response.body)) {
          const event = JSON.parse(message.data);
          after = event.seq;
          this.events.push(event);
          for (const listener of this.listeners) listener(event);
        }
        this.ended = true; // the server ends the stream after the final state
      } catch (error) {
        if (this.abort.signal.aborted || (error instanceof ApiError && error.status < 500)) break;
        await new Promise((resolve) => setTimeout(resolve, RETRY_MS));
      }
    }
    for (const listener of this.listeners) listener(null); // null: no more events
  }
}

const streams = new Map();

/** Call `listener` with each of the job's events (past ones first), then with null when the stream ends.
 *  Returns the function that stops following; the stream closes when nobody follows it. */
export function follow(jobId, listener) {
  let stream = streams.get(jobId);
  if (!stream || stream.abort.signal.aborted) {
    stream = new JobStream(jobId);
    streams.set(jobId, stream);
  }
  stream.users += 1;
  for (const event of stream.events) listener(event);
  if (stream.ended) listener(null);
  else stream.listeners.add(listener);
  return () => {
    stream.listeners.delete(listener);
    stream.users -= 1;
    if (stream.users === 0 && !stream.ended) {
      stream.abort.abort();
      streams.delete(jobId);
    }
  };
}

/** Stop every stream (on sign-out). */
export function closeAll() {
  for (const stream of streams.values()) stream.abort.abort();
  streams.clear();
}

"""The participant's page: a small local web server beside the Rerun web viewer.

It serves one page (``/``, its script ``/page.js``) that shows the session's instructions
and the current step, polls ``/api/state`` twice a second, and posts what the person does:
``/api/start`` (Start / Continue), ``/api/pause``, ``/api/resume`` and
``/api/answers`` (a questionnaire). The Rerun web viewer, when the session runs one, is
embedded beside the instructions.

It listens on loopback (127.0.0.1) only. A request is answered only when its ``Host`` is
that address (no other site's page can reach it by a DNS name), a post only with a JSON
body of at most :data:`MAX_BODY` bytes and ``Content-Type: application/json`` (which a form
on another site cannot send without the browser asking first, and this server answers no
such question). The page puts every text it shows with ``textContent``: what the protocol
or the daemon says is never markup. A refused request gets a JSON ``{"error": ...}`` line.
"""

from __future__ import annotations

import json
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from types import TracebackType
from typing import Any
from urllib.parse import urlsplit

from legws_daemon.errors import InputError
from legws_daemon.study.control import Control

#: Largest request body, bytes (a questionnaire's answers are well under 1 KiB).
MAX_BODY = 16 * 1024
HOST = "127.0.0.1"

PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>legws study</title>
<style>
body { font-family: system-ui, sans-serif; margin: 0; display: flex; height: 100vh; }
#side { width: 460px; padding: 20px; box-sizing: border-box; overflow-y: auto; }
#viewer { flex: 1; border: 0; }
h1 { font-size: 1.4em; margin: 0 0 0.4em; }
#message { font-size: 1.25em; margin: 0.6em 0; }
#progress, #live { color: #555; }
button { font-size: 1.1em; padding: 0.5em 1.2em; margin: 0.3em 0.3em 0.3em 0; }
.q { margin: 1em 0; }
.q .text { font-weight: 600; }
.q .ends { display: flex; justify-content: space-between; font-size: 0.85em; color: #555; }
.q input[type=range] { width: 100%; }
.q .value { font-size: 0.9em; }
.q.missing { outline: 2px solid #c33; }
#error { color: #c33; }
#paused { color: #b60; font-weight: 700; }
</style></head>
<body>
<div id="side">
  <h1 id="title">legws study</h1>
  <div id="progress"></div>
  <div id="paused" hidden>Paused</div>
  <div id="message">Connecting ...</div>
  <ol id="targets"></ol>
  <div id="live"></div>
  <form id="form" hidden></form>
  <div>
    <button id="start" type="button" hidden>Start</button>
    <button id="submit" type="button" hidden>Submit answers</button>
  </div>
  <div><button id="pause" type="button">Pause</button>
       <button id="resume" type="button" hidden>Resume</button></div>
  <div id="error"></div>
</div>
<iframe id="viewer" hidden title="Rerun viewer"></iframe>
<script src="/page.js"></script>
</body></html>
"""

SCRIPT = r"""
"use strict";
let shown = -1, formFor = null;
const $ = (id) => document.getElementById(id);
async function post(path, body) {
  const r = await fetch(path, {method: "POST", headers: {"Content-Type": "application/json"},
                               body: JSON.stringify(body || {})});
  const data = await r.json();
  $("error").textContent = r.ok ? "" : (data.error || "refused");
  return r.ok;
}
function question(f) {
  const box = document.createElement("div");
  box.className = "q"; box.dataset.name = f.name;
  const text = document.createElement("div");
  text.className = "text"; text.textContent = f.text; box.appendChild(text);
  if (f.kind === "tlx") {
    const input = document.createElement("input");
    input.type = "range"; input.min = f.low; input.max = f.high; input.step = f.step;
    input.name = f.name; input.value = String((f.low + f.high) / 2);
    input.dataset.touched = "";
    const value = document.createElement("div"); value.className = "value";
    value.textContent = "not answered yet";
    input.addEventListener("input", () => {
      input.dataset.touched = "1"; value.textContent = input.value;
      box.classList.remove("missing");
    });
    box.appendChild(input); box.appendChild(value);
  } else {
    const row = document.createElement("div");
    for (let v = f.low; v <= f.high; v++) {
      const label = document.createElement("label");
      const input = document.createElement("input");
      input.type = "radio"; input.name = f.name; input.value = String(v);
      input.addEventListener("change", () => box.classList.remove("missing"));
      label.appendChild(input); label.appendChild(document.createTextNode(" " + v + " "));
      row.appendChild(label);
    }
    box.appendChild(row);
  }
  const ends = document.createElement("div"); ends.className = "ends";
  const lo = document.createElement("span"); lo.textContent = f.low_label;
  const hi = document.createElement("span"); hi.textContent = f.high_label;
  ends.appendChild(lo); ends.appendChild(hi); box.appendChild(ends);
  return box;
}
function answers() {
  const out = {}; let missing = 0;
  for (const box of $("form").querySelectorAll(".q")) {
    const name = box.dataset.name;
    const range = box.querySelector("input[type=range]");
    let v = null;
    if (range) { if (range.dataset.touched) v = Number(range.value); }
    else { const c = box.querySelector("input:checked"); if (c) v = Number(c.value); }
    if (v === null) { box.classList.add("missing"); missing++; } else out[name] = v;
  }
  return missing ? null : out;
}
function render(s) {
  $("title").textContent = s.title || (s.phase === "done" ? "Done" : "legws study");
  $("message").textContent = s.message || "";
  $("paused").hidden = !s.paused;
  $("pause").hidden = s.paused || s.phase === "done";
  $("resume").hidden = !s.paused;
  const prog = [];
  if (s.participant) prog.push(s.participant);
  if (s.trials) prog.push("trials done: " + s.trials_done + " of " + s.trials);
  if (s.phase === "calibrating") prog.push("targets reached: " + s.reach + " of " + s.of);
  if (s.phase === "preparing") prog.push("layouts: " + s.done + " of " + s.of);
  $("progress").textContent = prog.join(" · ");
  const list = $("targets"); list.replaceChildren();
  for (const [i, t] of (s.targets || []).entries()) {
    const li = document.createElement("li");
    li.textContent = t.replaceAll("_", " ") + (s.choice > i ? " ✓" : "");
    list.appendChild(li);
  }
  $("live").textContent = s.phase === "running" && s.mode ? "robot: " + s.mode +
      (s.committed ? " → " + s.committed.replaceAll("_", " ") : "") : "";
  const waiting = s.phase === "ready" || s.phase === "break";
  $("start").hidden = !waiting || s.paused;
  $("start").textContent = s.phase === "break" ? "Continue" : "Start";
  const asking = s.phase === "questionnaire";
  $("form").hidden = !asking; $("submit").hidden = !asking;
  if (asking && formFor !== s.step) {
    formFor = s.step; $("form").replaceChildren(...(s.fields || []).map(question));
  }
  if (!asking) formFor = null;
  const v = $("viewer");
  if (s.viewer && v.getAttribute("src") !== s.viewer) { v.setAttribute("src", s.viewer); }
  v.hidden = !s.viewer;
  document.body.dataset.phase = s.phase;
}
async function poll() {
  try {
    const r = await fetch("/api/state", {cache: "no-store"});
    const s = await r.json();
    if (s.version !== shown) { shown = s.version; render(s); }
  } catch (e) { $("message").textContent = "The session is not running."; }
  setTimeout(poll, 500);
}
$("start").addEventListener("click", () => post("/api/start"));
$("pause").addEventListener("click", () => post("/api/pause"));
$("resume").addEventListener("click", () => post("/api/resume"));
$("submit").addEventListener("click", async () => {
  const a = answers();
  if (a === null) { $("error").textContent = "Please answer every question."; return; }
  await post("/api/answers", a);
});
poll();
"""


def _csp(viewer_origin: str | None) -> str:
    frame = f"frame-src {viewer_origin}; " if viewer_origin else "frame-src 'none'; "
    return (
        "default-src 'none'; script-src 'self'; connect-src 'self'; style-src 'unsafe-inline'; "
        + frame
        + "base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
    )


class StudyPage:
    """The page's server (a context manager; it serves from its own threads).

    Args:
        control: the session's shared state.
        port: the port on 127.0.0.1 (0: any free one; :attr:`port` says which).
        viewer: the Rerun web viewer's page URL shown beside the instructions (its origin
            is the only one the page may embed).
    """

    def __init__(self, control: Control, port: int = 0, viewer: str | None = None) -> None:
        origin = None
        if viewer is not None:
            parts = urlsplit(viewer)
            origin = f"{parts.scheme}://{parts.netloc}"
        handler = _handler(control, _csp(origin))
        try:
            self._server = ThreadingHTTPServer((HOST, port), handler)
        except OSError as err:
            raise InputError(f"cannot listen on {HOST}:{port}: {err.strerror}",
                             field="--page-port") from None  # fmt: skip
        self._server.daemon_threads = True
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True,
                                        name="study-page")  # fmt: skip

    @property
    def port(self) -> int:
        return int(self._server.server_address[1])

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.port}/"

    def __enter__(self) -> StudyPage:
        self._thread.start()
        return self

    def __exit__(
        self, t: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(5.0)


def _handler(control: Control, csp: str) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        server_version = "legws-study"
        sys_version = ""

        def log_message(self, format: str, *args: Any) -> None:
            pass  # the session's terminal is the participant's screen's neighbour: quiet

        def _send(self, code: int, body: bytes, kind: str) -> None:
            self.send_response(code)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.send_header("Content-Security-Policy", csp)
            self.end_headers()
            self.wfile.write(body)

        def _json(self, code: int, data: Any) -> None:
            self._send(code, (json.dumps(data) + "\n").encode(), "application/json")

        def _host_ok(self) -> bool:
            host = (self.headers.get("Host") or "").rsplit(":", 1)[0]
            if host in (HOST, "localhost"):
                return True
            self._json(HTTPStatus.FORBIDDEN, {"error": "only http://127.0.0.1 serves this"})
            return False

        def do_GET(self) -> None:
            if not self._host_ok():
                return
            path = urlsplit(self.path).path
            if path == "/":
                self._send(HTTPStatus.OK, PAGE.encode(), "text/html; charset=utf-8")
            elif path == "/page.js":
                self._send(HTTPStatus.OK, SCRIPT.encode(), "text/javascript; charset=utf-8")
            elif path == "/api/state":
                self._json(HTTPStatus.OK, control.view())
            else:
                self._json(HTTPStatus.NOT_FOUND, {"error": f"no page {path[:64]!r}"})

        def _body(self) -> Any:
            kind = (self.headers.get("Content-Type") or "").split(";")[0].strip()
            if kind != "application/json":
                raise InputError("expected Content-Type: application/json", field="request")
            try:
                size = int(self.headers.get("Content-Length") or "0")
            except ValueError:
                raise InputError("expected a Content-Length", field="request") from None
            if not 0 <= size <= MAX_BODY:
                raise InputError(f"expected a body of at most {MAX_BODY} bytes, got {size}",
                                 field="request")  # fmt: skip
            raw = self.rfile.read(size) if size else b"{}"
            try:
                return json.loads(raw)
            except ValueError:
                raise InputError("expected a JSON body", field="request") from None

        def do_POST(self) -> None:
            if not self._host_ok():
                return
            path = urlsplit(self.path).path
            try:
                data = self._body()
                if path == "/api/start":
                    control.start()
                elif path == "/api/pause":
                    control.pause()
                elif path == "/api/resume":
                    control.resume()
                elif path == "/api/answers":
                    control.submit(data)
                else:
                    self._json(HTTPStatus.NOT_FOUND, {"error": f"no action {path[:64]!r}"})
                    return
            except InputError as err:
                self._json(HTTPStatus.BAD_REQUEST, {"error": str(err)})
                return
            self._json(HTTPStatus.OK, {"ok": True})

    return Handler

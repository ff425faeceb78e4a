"""The participant's page server: what it serves, what it takes, what it refuses."""

from __future__ import annotations

import http.client
import json
import re
import urllib.request
from dataclasses import dataclass
from typing import Any

import pytest

from legws_daemon.errors import InputError
from legws_daemon.study.control import Control
from legws_daemon.study.web import MAX_BODY, PAGE, SCRIPT, StudyPage
from tests.study.person import ANSWERS, Q

JSON = {"Content-Type": "application/json"}


@dataclass(frozen=True)
class Reply:
    status: int
    headers: http.client.HTTPMessage
    body: bytes

    def json(self) -> Any:
        assert self.headers["Content-Type"] == "application/json"
        return json.loads(self.body)


def call(
    page: StudyPage,
    method: str,
    path: str,
    body: bytes | None = None,
    headers: dict[str, str] | None = None,
) -> Reply:
    """One request; the ``Host`` is the page's own unless ``headers`` says another."""
    conn = http.client.HTTPConnection("127.0.0.1", page.port, timeout=10)
    try:
        conn.request(method, path, body=body, headers=headers or {})
        r = conn.getresponse()
        return Reply(r.status, r.headers, r.read())
    finally:
        conn.close()


def post(page: StudyPage, path: str, data: Any = None) -> Reply:
    body = json.dumps({} if data is None else data).encode()
    return call(page, "POST", path, body, JSON)


def one_line_error(reply: Reply, status: int) -> str:
    assert reply.status == status, reply
    assert reply.body.endswith(b"\n") and reply.body.count(b"\n") == 1
    error = reply.json()["error"]
    assert isinstance(error, str) and error and "\n" not in error
    return error


@pytest.fixture
def control() -> Control:
    return Control(Q)


def test_the_page_and_its_script_have_their_types_and_a_strict_csp(control: Control) -> None:
    with StudyPage(control) as page:
        assert page.url == f"http://127.0.0.1:{page.port}/" and page.port > 0
        with urllib.request.urlopen(page.url, timeout=10) as r:
            assert r.status == 200
            assert r.headers["Content-Type"] == "text/html; charset=utf-8"
            assert r.read().decode() == PAGE
            csp = r.headers["Content-Security-Policy"]
            assert r.headers["X-Content-Type-Options"] == "nosniff"
            assert r.headers["Cache-Control"] == "no-store"
        js = call(page, "GET", "/page.js")
    assert js.status == 200 and js.body.decode() == SCRIPT
    assert js.headers["Content-Type"] == "text/javascript; charset=utf-8"
    directives = dict(d.strip().split(" ", 1) for d in csp.split(";"))
    assert directives["default-src"] == "'none'"
    assert directives["script-src"] == "'self'"
    assert directives["connect-src"] == "'self'"
    assert directives["frame-src"] == "'none'"  # no viewer: nothing may be embedded
    assert directives["frame-ancestors"] == "'none'"
    assert directives["form-action"] == "'none'"


def test_with_a_viewer_only_its_origin_may_be_embedded(control: Control) -> None:
    viewer = "http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9091%2Fproxy"
    with StudyPage(control, viewer=viewer) as page:
        csp = call(page, "GET", "/").headers["Content-Security-Policy"]
    assert "frame-src http://127.0.0.1:9090;" in csp
    assert "9091" not in csp and "'none'; frame-src 'none'" not in csp


def test_state_is_the_controls_view(control: Control) -> None:
    control.show(phase="ready", message="Press Start", participant="P07", targets=["mug"])
    with StudyPage(control) as page:
        state = call(page, "GET", "/api/state")
        assert state.status == 200
        assert state.json() == control.view()
        assert state.json()["targets"] == ["mug"] and state.json()["phase"] == "ready"
        assert call(page, "GET", "/api/state?t=1").json() == control.view()  # a query is ignored
        control.update(message="changed")
        assert call(page, "GET", "/api/state").json()["message"] == "changed"


def test_start_pause_and_resume_reach_the_control(control: Control) -> None:
    with StudyPage(control) as page:
        reply = post(page, "/api/start")
        assert reply.status == 200 and reply.json() == {"ok": True}
        assert control.wait_start(1.0)
        assert post(page, "/api/pause").status == 200
        assert control.pause_requested and call(page, "GET", "/api/state").json()["paused"]
        error = one_line_error(post(page, "/api/start"), 400)  # paused: refused
        assert "start" in error and "resume it first" in error
        assert post(page, "/api/resume").status == 200
        assert not control.pause_requested
        # an empty body is an empty object
        assert call(page, "POST", "/api/start", b"", JSON).status == 200
        assert control.wait_start(1.0)


def test_answers_are_taken_when_a_questionnaire_is_open_and_refused_otherwise(
    control: Control,
) -> None:
    with StudyPage(control) as page:
        error = one_line_error(post(page, "/api/answers", ANSWERS), 400)
        assert "no questionnaire is open" in error
        control.ask()
        error = one_line_error(post(page, "/api/answers", {**ANSWERS, "tlx_effort": 42}), 400)
        assert "tlx_effort" in error and "steps of 5" in error
        body = json.dumps({**ANSWERS, "likert_1": float("nan")}).encode()  # NaN is JSON here
        assert "likert_1" in one_line_error(call(page, "POST", "/api/answers", body, JSON), 400)
        assert control.wait_answers(0.02) is None  # nothing kept of the refused ones
        assert post(page, "/api/answers", ANSWERS).status == 200
        got = control.wait_answers(1.0)
    assert got is not None and got["likert_1"] == 4 and got["tlx_effort"] == 100.0


HOSTS = ["evil.example", "evil.example:80", "127.0.0.1.evil.example", "localhost.evil", ""]


def test_another_host_is_forbidden_and_localhost_served(control: Control) -> None:
    with StudyPage(control) as page:
        for host in HOSTS:
            for method, path, body in [("GET", "/", None), ("GET", "/api/state", None),
                                       ("POST", "/api/start", b"{}")]:  # fmt: skip
                reply = call(page, method, path, body, {**JSON, "Host": host})
                assert "127.0.0.1" in one_line_error(reply, 403), (host, path)
                assert b"<html" not in reply.body and b"version" not in reply.body
        assert not control.wait_start(0.02)  # the posts did nothing
        assert call(page, "GET", "/", headers={"Host": f"localhost:{page.port}"}).status == 200
        assert call(page, "GET", "/", headers={"Host": "127.0.0.1"}).status == 200


def test_a_post_that_is_not_json_is_refused(control: Control) -> None:
    with StudyPage(control) as page:
        for kind in ["text/plain", "application/x-www-form-urlencoded", "multipart/form-data"]:
            reply = call(page, "POST", "/api/start", b"{}", {"Content-Type": kind})
            assert "application/json" in one_line_error(reply, 400), kind
        reply = call(page, "POST", "/api/start", b"{}")  # no type at all
        assert "application/json" in one_line_error(reply, 400)
        assert not control.wait_start(0.02)
        # a parameter after the type is fine
        ok = call(page, "POST", "/api/start", b"{}", {"Content-Type": "application/json; x=1"})
        assert ok.status == 200 and control.wait_start(1.0)


def headers_only(page: StudyPage, path: str, length: str) -> Reply:
    """A JSON post that says its body is ``length`` bytes and never sends it."""
    conn = http.client.HTTPConnection("127.0.0.1", page.port, timeout=10)
    try:
        conn.putrequest("POST", path)
        conn.putheader("Content-Type", "application/json")
        conn.putheader("Content-Length", length)
        conn.endheaders()
        r = conn.getresponse()
        return Reply(r.status, r.headers, r.read())
    finally:
        conn.close()


def test_a_body_over_the_limit_is_refused_before_it_is_read(control: Control) -> None:
    control.ask()
    with StudyPage(control) as page:
        # the server answers without waiting for a body it will not take
        error = one_line_error(headers_only(page, "/api/answers", str(MAX_BODY + 1)), 400)
        assert f"at most {MAX_BODY} bytes, got {MAX_BODY + 1}" in error
        assert one_line_error(headers_only(page, "/api/start", "-1"), 400)
        assert "Content-Length" in one_line_error(headers_only(page, "/api/start", "many"), 400)
        assert control.wait_answers(0.02) is None and not control.wait_start(0.02)
        # at the limit is fine (the answers padded with spaces)
        body = json.dumps(ANSWERS).encode()
        body += b" " * (MAX_BODY - len(body))
        assert call(page, "POST", "/api/answers", body, JSON).status == 200
        assert control.wait_answers(1.0) is not None


def test_malformed_json_is_refused(control: Control) -> None:
    control.ask()
    with StudyPage(control) as page:
        for body in [b"{", b"not json", b'{"a": }', b"\xff\xfe"]:
            error = one_line_error(call(page, "POST", "/api/answers", body, JSON), 400)
            assert "expected a JSON body" in error, body
    assert control.wait_answers(0.02) is None


def test_unknown_paths_are_not_found(control: Control) -> None:
    with StudyPage(control) as page:
        assert "no page" in one_line_error(call(page, "GET", "/admin"), 404)
        assert one_line_error(call(page, "GET", "/api/state/"), 404)
        assert "no action" in one_line_error(post(page, "/api/shutdown"), 404)
        assert one_line_error(post(page, "/api/state"), 404)


def test_a_taken_port_is_one_line_naming_the_flag(control: Control) -> None:
    with StudyPage(control) as page, pytest.raises(InputError) as info:
        StudyPage(control, port=page.port)
    assert info.value.field == "--page-port" and str(page.port) in str(info.value)


def test_the_page_puts_every_text_as_text_never_as_markup() -> None:
    # names from the protocol (targets, questions, their labels) and the daemon's words
    # (mode, the committed object) reach the page only as text nodes
    for sink in ("innerHTML", "outerHTML", "insertAdjacentHTML", "document.write", "eval(",
                 "new Function", "srcdoc"):  # fmt: skip
        assert sink not in SCRIPT, sink
        assert sink not in PAGE, sink
    assert re.findall(r"<script\b[^>]*>", PAGE) == ['<script src="/page.js">']  # none inline
    assert "on" + "click=" not in PAGE.lower()  # no inline handlers either (CSP forbids them)
    for shown in ("f.text", "f.low_label", "f.high_label", "s.message", "s.mode"):
        assert re.search(rf"textContent = [^;]*{re.escape(shown)}", SCRIPT), shown
    assert "li.textContent = t.replaceAll" in SCRIPT  # the targets
